"""The plain bicubic baseline: Keys bicubic (a = -0.75, half-pixel centres) of each render
frame, on the device, in the PQ domain so that it rings as the pipeline's colour would.
It ignores the jitter, depth and motion: what a spatial upscaler without history gives."""
from __future__ import annotations

import numpy as np

from ...pipeline.contract import output_size, pq_decode, pq_encode
from ...pipeline.method import MethodSpec, MethodUpscaler


class Bicubic:
    """Plain bicubic of one frame to `out_hw` (H, W) on `dev`, in `precision` (fp16: half
    storage of the encoded colour, float arithmetic)."""

    def __init__(self, dev, out_hw, precision="fp32"):
        self.dev, self.out_hw, self.precision = dev, out_hw, precision

    def __call__(self, color):
        from ...ops.resize import resize
        x = self.dev.to_device(pq_encode(color).transpose(2, 0, 1)[None], self.precision)
        y = resize(self.dev, self.precision, x, out_hw=self.out_hw, mode="cubic")
        y = self.dev.to_host(y)
        return pq_decode(np.clip(y[0].transpose(1, 2, 0), 0, 1))


class BicubicUpscaler(MethodUpscaler):
    """The method "bicubic" behind clss.Upscaler: colour in, colour out; depth, motion and
    jitter are accepted (the contract's step) and not used."""

    def __init__(self, scale=2.0, device=None, precision="fp32", *, exposure=1.0,
                 sanitize=False, profile=False, **unused):
        self.spec = SPEC
        self._init_common(scale, device, precision, exposure=exposure, sanitize=sanitize,
                          profile=profile)
        self._hw = None
        self._up = None

    @property
    def render_size(self):
        return self._hw

    @property
    def output_size(self):
        return None if self._hw is None else output_size(*self._hw, self.scale)

    def step(self, color, depth=None, motion=None, jitter=(0.0, 0.0), reset=False,
             reactive=None, **gbuffers) -> np.ndarray:
        frame, (h, w) = self._color_frame(color, reset)
        if self._hw != (h, w):
            self._hw = (h, w)
            self._up = Bicubic(self.dev, output_size(h, w, self.scale), self.precision)
        self.last_report = frame["sanitized"]
        self._pending_reset = False
        self.frame_index += 1
        c = frame["color"]
        if self.exposure != 1.0:
            c = c * np.float32(1.0 / self.exposure)
        out = self._up(c)
        return out * np.float32(self.exposure) if self.exposure != 1.0 else out

    def step_device(self, color, depth=None, motion=None, jitter=(0.0, 0.0), reset=False,
                    reactive=None, out=None, **gbuffers):
        y = self.step(color.get(), reset=reset)
        if out is None:
            return self.dev.to_device(y)
        out.set(np.ascontiguousarray(y, np.float32))
        return out


SPEC = MethodSpec(
    "bicubic", "bicubic", "plain Keys bicubic of each frame, jitter-unaware, in the PQ domain",
    lambda **kw: BicubicUpscaler(**kw), inputs=("color",), precisions=("fp32", "fp16"),
    temporal=False, doc="docs/methods/baselines.md",
    twin="clss.methods.bicubic.oracle:OracleBicubic")
SPECS = {"bicubic": SPEC}
