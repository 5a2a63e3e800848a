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

from ... import selfcheck
from ...ops.conv import builtin_free, load_defines
from ...pipeline.contract import CANNOT, PQ_NITS, PQ_PEAK_NITS, output_size
from ...tolerance import Tolerance
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
        if fused(dev, self.prec):
            return self._run_fused(color, exposure, out)
        dev.launch(dev.kernel(KERNEL, "bicubic_encode", self.prec), (self.w, self.h),
                   (color.data, self.x.data, i32(self.h), i32(self.w), f(1.0 / exposure),
                    f(self.nits / PQ_PEAK_NITS)))
        resize(dev, self.prec, self.x, out_hw=(self.H, self.W), mode="cubic", out=self.y)
        ev = dev.launch(dev.kernel(KERNEL, "bicubic_decode", self.prec), (self.W, self.H),
                        (self.y.data, out.data, i32(self.H), i32(self.W),
                         f(PQ_PEAK_NITS / self.nits * exposure)))
        return out, ev

    def _run_fused(self, color, exposure, out):
        """The fast path bicubic.fused8: encode on float8, then the cubic and the decode
        in one pass (bicubic.cl; self.y is not written)."""
        from ...ops.resize import cubic_tables
        dev, i32, f = self.dev, np.int32, np.float32
        defines = {**load_defines(dev, self.prec, "bicubic"), "BICUBIC_FUSED": 1,
                   "SCALE2": int((self.H, self.W) == (2 * self.h, 2 * self.w))}
        _, idx, wt = cubic_tables(dev, self.prec, (self.h, self.w), (self.H, self.W))
        dev.launch(dev.kernel(KERNEL, "bicubic_encode8", self.prec, **defines), (-(-self.w // 8), self.h),
                   (color.data, self.x.data, i32(self.h), i32(self.w), f(1.0 / exposure),
                    f(self.nits / PQ_PEAK_NITS)))
        ev = dev.launch(dev.kernel(KERNEL, "bicubic_resize_decode8", self.prec, **defines),
                        (-(-self.W // 8), self.H),
                        (self.x.data, out.data, i32(self.h), i32(self.w), i32(self.H), i32(self.W),
                         f(PQ_PEAK_NITS / self.nits * exposure), idx.data, wt.data))
        return out, ev

    def device_bytes(self) -> int:
        return sum(int(a.nbytes) for a in (self.in_color, self.x, self.y, self.out))


# --- fast paths (clss/selfcheck.py) ------------------------------------------------

FUSED = "bicubic.fused8"


def fused(dev, prec) -> bool:
    """Whether the frame step takes the fast path bicubic.fused8 on dev in prec."""
    return selfcheck.enabled(dev, prec, FUSED)


def _selfcheck_frames(dev, prec) -> list:
    """Two frames at 2x and one at 1.5x and 3x, at render sizes whose rows end in partial
    vectors at both resolutions, colour up to 4x the PQ white (clipped) and an exposure."""
    from ...ops.base import rng
    g = rng("bicubic selfcheck")
    outs = []
    for (h, w), scale, exposure in (((6, 13), 2.0, 1.0), ((7, 9), 2.0, 2.0), ((5, 11), 1.5, 1.0),
                                    ((4, 7), 3.0, 1.0)):
        fs = BicubicFrame(dev, prec, (h, w), scale)
        c = dev.to_device(g.uniform(0, 40, (h, w, 3)).astype(np.float32))
        y, ev = fs.run(c, exposure=exposure)
        ev.wait()
        outs.append(dev.to_host(y))
    return outs


def _tolerance(prec):
    """The frame step's own bounds, those its twin tests hold it to against onnxruntime
    (tests/test_method_bicubic.py, tests/test_methods.py): |d| <= t * max|ref| + t * |ref|,
    t = 1e-4 in fp32, 1e-2 in fp16. The PQ encode's second power (x^78.8) turns an ulp of
    its base into 1e-5 of the code value, and the decode multiplies a code value's relative
    error by up to 9.5 near white: two float32 evaluations of the transfer that round
    differently (the library's vector and scalar exp2 and log2 alike) differ by up to 1e-4
    of a pixel, and in fp16 a code value that rounds to the neighbouring half moves the
    pixel by up to 5e-3. The default bounds (1e-5 * max|ref| in fp32, 1e-3 in fp16) leave
    no room for either (measured: 1.1 and 0.99 of them)."""
    t = 1e-4 if prec == "fp32" else 1e-2
    return Tolerance(t, t)


selfcheck.register(selfcheck.FastPath(
    FUSED, KERNEL, {"BICUBIC_FUSED": 1}, {"BICUBIC_FUSED": 0}, check=_selfcheck_frames,
    tolerance=_tolerance,
    what="the PQ encode on float8, then the cubic resize and the PQ decode in one pass, 8 pixels "
         "a work-item (bicubic_encode8, bicubic_resize_decode8) / encode, resize, decode per pixel",
    applies=lambda dev: dev.is_cpu, measured=True))
selfcheck.register(selfcheck.FastPath(
    "bicubic.builtin_free_loads", KERNEL, {"BICUBIC_FUSED": 1, "CLSS_CLANG_VECTORS": 1},
    {"BICUBIC_FUSED": 1, "CLSS_CLANG_VECTORS": 0}, check=_selfcheck_frames,
    tolerance=_tolerance,
    what="the fused kernels' loads and stores as clang vector accesses (PoCL)", applies=builtin_free))


class BicubicUpscaler(MethodUpscaler):
    """The method "bicubic" behind clss.Upscaler: colour in, colour out; depth, motion and
    jitter are accepted (the contract's step) and not used. contract: clss.Contract (the
    exposure and nits are honoured; LDR is not)."""

    def __init__(self, scale=2.0, device=None, precision="auto", *, contract=None,
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
    temporal=False, kernels=(KERNEL.name,), doc="docs/methods/baselines.md", fast_paths=__name__,
    twin="clss.methods.bicubic.oracle:OracleBicubic",
    conventions=conventions(
        hdr=(CANNOT, "its cubic runs on PQ-encoded colour; no LDR path")))
SPECS = {"bicubic": SPEC}
