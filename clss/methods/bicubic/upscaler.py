"""The plain bicubic baseline: Keys bicubic (a = -0.75, half-pixel centres) of each render
frame, on the device, in the PQ domain so that it rings as the pipeline's colour would.
It ignores the jitter, depth and motion: what a spatial upscaler without history gives.

The frame step (`BicubicFrame`): bicubic.cl (beside this file) encodes the colour to PQ planes, the
resize op (clss.ops.resize) upsamples them, bicubic.cl decodes to the caller's
image; the host `step` and `step_device` are MethodUpscaler's (no copy through the host on
the device path).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ...pipeline.contract import CANNOT, PQ_NITS, PQ_PEAK_NITS, output_size
from ...pipeline.method import MethodSpec, MethodUpscaler, conventions, input_buffers

KERNEL = Path(__file__).with_name("bicubic.cl")   # the frame kernels, beside this file


class BicubicFrame:
    """Device buffers and launches of one frame at render size (h, w) to `scale`, in
    `precision` (fp16: half storage of the encoded colour, float arithmetic)."""

    def __init__(self, dev, precision, render_size, scale, nits=PQ_NITS):
        self.dev, self.prec = dev, precision
        self.h, self.w = (int(v) for v in render_size)
        self.H, self.W = output_size(self.h, self.w, scale)
        self.nits = float(nits)
        e = dev.empty
        (self.in_color,) = input_buffers(dev, ("color",), (self.h, self.w))
        self.x = e((1, 3, self.h, self.w), precision)
        self.y = e((1, 3, self.H, self.W), precision)
        self.out = e((self.H, self.W, 3), dtype=np.float32)

    def run(self, color, exposure=1.0, out=None):
        """Enqueue one frame (colour h x w x 3 float32 on the device); returns the output
        array (`out` or the internal one) and the last event."""
        from ...ops.resize import resize
        dev, i32, f = self.dev, np.int32, np.float32
        out = self.out if out is None else out
        dev.launch(dev.kernel(KERNEL, "bicubic_encode", self.prec), (self.w, self.h),
                   (color.data, self.x.data, i32(self.h), i32(self.w), f(1.0 / exposure),
                    f(self.nits / PQ_PEAK_NITS)))
        resize(dev, self.prec, self.x, out_hw=(self.H, self.W), mode="cubic", out=self.y)
        ev = dev.launch(dev.kernel(KERNEL, "bicubic_decode", self.prec), (self.W, self.H),
                        (self.y.data, out.data, i32(self.H), i32(self.W),
                         f(PQ_PEAK_NITS / self.nits * exposure)))
        return out, ev

    def device_bytes(self) -> int:
        return sum(int(a.nbytes) for a in (self.in_color, self.x, self.y, self.out))


class BicubicUpscaler(MethodUpscaler):
    """The method "bicubic" behind clss.Upscaler: colour in, colour out; depth, motion and
    jitter are accepted (the contract's step) and not used. contract: clss.Contract (the
    exposure and nits are honoured; LDR is not)."""

    def __init__(self, scale=2.0, device=None, precision="fp32", *, contract=None,
                 sanitize=False, profile=False):
        self.spec = SPEC
        self._init_common(scale, device, precision, contract=contract, sanitize=sanitize,
                          profile=profile)

    def _build_frame_step(self, h, w):
        return BicubicFrame(self.dev, self.precision, (h, w), self.scale, nits=self.nits)

    def _enqueue(self, fs, arrays, jitter, out):
        return fs.run(arrays["color"], exposure=self.exposure, out=out)


SPEC = MethodSpec(
    "bicubic", "bicubic", "plain Keys bicubic of each frame, jitter-unaware, in the PQ domain",
    BicubicUpscaler, inputs=("color",), precisions=("fp32", "fp16"),
    temporal=False, kernels=(KERNEL.name,), doc="docs/methods/baselines.md",
    twin="clss.methods.bicubic.oracle:OracleBicubic",
    conventions=conventions(
        hdr=(CANNOT, "its cubic runs on PQ-encoded colour; no LDR path")))
SPECS = {"bicubic": SPEC}
