"""Zero-upsampling (NSRR) (kernels/zero_upsample.cl): bit-exact data movement.

Each render-resolution sample goes to the output pixel that contains the point it
was taken at; every other output pixel is 0. Without jitter the placement is
NSRR's: render pixel j -> output pixel j*s, the top-left of its s x s block (the
sample position of jitter -0.5). With a jitter (jy, jx) in render pixels, in
[-0.5, 0.5], the sample taken at j + 0.5 + jitter lands at floor((j + 0.5 +
jitter) * s), kept inside its own pixel's footprint.

The ONNX twin: integer scales are Unsqueeze -> Pad (the sample at its offset in
the s x s block) -> Reshape; other scales Concat a zero column and Gather with
the placement map (computed here in float32 exactly as the kernel does).
"""
from __future__ import annotations

import math

import numpy as np

from ..device import Device
from .base import check_storage

CPT = 4  # channels per work-item (the index search is shared by them)


def _pair(v, name):
    a, b = (v, v) if np.isscalar(v) else tuple(v)
    return float(a), float(b)


def output_size(h: int, w: int, scale) -> tuple[int, int]:
    """floor(size * scale) per axis, as ONNX Resize sizes its output."""
    sy, sx = _pair(scale, "scale")
    return int(math.floor(h * sy)), int(math.floor(w * sx))


def _axis(scale: float, jit: float):
    """(integer scale or 0, integer offset in the block) of one axis."""
    if float(scale).is_integer():
        s = int(scale)
        return s, min(int(math.floor((0.5 + jit) * s)), s - 1)
    return 0, 0


def placement(n: int, scale: float, jit: float, size: int) -> np.ndarray:
    """Output index of each render index along one axis (-1: outside the output),
    float32 operation for operation as kernels/zero_upsample.cl."""
    si, o = _axis(scale, jit)
    j = np.arange(n)
    if si:
        x = j * si + o
    else:
        f = np.float32
        p = ((j.astype(f) + f(0.5)) + f(jit)) * f(scale)
        x = np.minimum(np.floor(p), np.ceil((j + 1).astype(f) * f(scale)) - 1).astype(np.int64)
    return np.where((x >= 0) & (x < size), x, -1)


def zero_upsample(dev: Device, prec: str, x, scale, jitter=None, out_size=None, out=None):
    """[N,C,h,w] -> [N,C,Ho,Wo] (default floor(h*sy) x floor(w*sx)).
    scale: s or (sy, sx), each >= 1; jitter: None (NSRR placement) or (jy, jx)."""
    check_storage("x", x, prec)
    if x.ndim != 4:
        raise ValueError(f"zero_upsample: x must be [N, C, H, W], got shape {x.shape}")
    n, c, h, w = x.shape
    sy, sx = _pair(scale, "scale")
    if not (sy >= 1 and sx >= 1 and math.isfinite(sy) and math.isfinite(sx)):
        raise ValueError(f"zero_upsample: scales must be finite and >= 1, got {(sy, sx)}")
    jy, jx = (-0.5, -0.5) if jitter is None else _pair(jitter, "jitter")
    if not (-0.5 <= jy <= 0.5 and -0.5 <= jx <= 0.5):
        raise ValueError(f"zero_upsample: jitter must lie in [-0.5, 0.5] render pixels, got {(jy, jx)}")
    ho, wo = out_size if out_size is not None else output_size(h, w, (sy, sx))
    out = out if out is not None else dev.empty((n, c, ho, wo), prec)
    if out.shape != (n, c, ho, wo):
        raise ValueError(f"zero_upsample: out has shape {out.shape}, expected {(n, c, ho, wo)}")
    (siy, oy), (six, ox) = _axis(sy, jy), _axis(sx, jx)
    ncb = n * -(-c // CPT)
    if out.size == 0:
        return out
    k = dev.kernel("zero_upsample", "zero_upsample", prec, CPT=CPT)
    i32, f32 = np.int32, np.float32
    dev.launch(k, (wo, ho, ncb),
               (x.data, out.data, i32(c), i32(h), i32(w), i32(ho), i32(wo), i32(ncb),
                i32(siy), i32(six), i32(oy), i32(ox), f32(sy), f32(sx), f32(jy), f32(jx)))
    return out
