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
from onnx import helper

from ..device import Device
from .base import Case, check_storage, host_call, rng
from .twin import make_model

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


def twin(x: np.ndarray, scale, jitter=None, out_size=None):
    n, c, h, w = x.shape
    sy, sx = _pair(scale, "scale")
    jy, jx = (-0.5, -0.5) if jitter is None else _pair(jitter, "jitter")
    ho, wo = out_size if out_size is not None else output_size(h, w, (sy, sx))
    (siy, oy), (six, ox) = _axis(sy, jy), _axis(sx, jx)
    if siy and six and (ho, wo) == (h * siy, w * six):
        pads = np.array([0, 0, 0, oy, 0, ox, 0, 0, 0, siy - 1 - oy, 0, six - 1 - ox], np.int64)
        nodes = [helper.make_node("Unsqueeze", ["x", "ax"], ["t1"]),
                 helper.make_node("Pad", ["t1", "pads"], ["t2"]),
                 helper.make_node("Reshape", ["t2", "shape"], ["y0"])]
        inits = {"ax": np.array([3, 5], np.int64), "pads": pads,
                 "shape": np.array([n, c, ho, wo], np.int64)}
        return make_model(nodes, {"x": x}, ["y0"], initializers=inits)
    # General: output pixel -> flat render index, h*w (a zero column) where none lands.
    src = np.full((ho, wo), h * w, np.int64)
    ys, xs = placement(h, sy, jy, ho), placement(w, sx, jx, wo)
    for i, Y in enumerate(ys):
        if Y >= 0:
            ok = xs >= 0
            src[Y, xs[ok]] = i * w + np.arange(w)[ok]
    nodes = [helper.make_node("Reshape", ["x", "flat"], ["t1"]),
             helper.make_node("Concat", ["t1", "zero"], ["t2"], axis=2),
             helper.make_node("Gather", ["t2", "idx"], ["t3"], axis=2),
             helper.make_node("Reshape", ["t3", "shape"], ["y0"])]
    inits = {"flat": np.array([n, c, h * w], np.int64), "zero": np.zeros((n, c, 1), np.float32),
             "idx": src.reshape(-1), "shape": np.array([n, c, ho, wo], np.int64)}
    return make_model(nodes, {"x": x}, ["y0"], initializers=inits)


def case(n, c, h, w, scale, jitter=None, out_size=None):
    g = rng("zero_upsample", n, c, h, w, str(scale), str(jitter))
    x = g.standard_normal((n, c, h, w)).astype(np.float32)
    jt = "nsrr" if jitter is None else f"jitter {jitter[0]:+g},{jitter[1]:+g}"
    sc = f"x{scale}" if np.isscalar(scale) else f"x{scale[0]}x{scale[1]}"
    return Case("zero_upsample", f"{sc} {jt} {n}x{c}x{h}x{w}", {"x": x}, twin(x, scale, jitter, out_size),
                host_call(lambda dev, p, x: zero_upsample(dev, p, x, scale, jitter, out_size)), exact=True)


def cases(level: str = "quick") -> list[Case]:
    tiny = [case(1, 3, 3, 5, 2), case(2, 5, 3, 4, 2, (0.25, -0.4)), case(1, 2, 3, 5, 1.5, (0.1, 0.3))]
    if level == "tiny":
        return tiny
    quick = tiny + [case(1, 12, 8, 12, 3), case(1, 4, 7, 13, (2, 4), (0.5, -0.5))]
    if level == "quick":
        return quick
    full = quick + [case(1, 1, 1, 1, 2), case(1, 7, 31, 27, 4, (-0.1, 0.45)),
                    case(2, 9, 7, 13, 1.5, (-0.5, 0.5)), case(1, 3, 5, 7, (1.75, 2.5), (0.2, -0.3)),
                    case(1, 3, 11, 9, 1, (0.3, 0.0)), case(1, 5, 9, 10, 2.0, (0.0, 0.0))]
    return full
