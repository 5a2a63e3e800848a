"""Conformance cases of the jitter-aware zero upsample (clss/ops/zero_upsample.py,
kernels/zero_upsample.cl): ONNX twins and seeded cases, `cases(level)` for `clss verify` and
the tests."""
from __future__ import annotations

import numpy as np
from onnx import helper

from ...ops.base import rng
from ...ops.zero_upsample import _axis, _pair, output_size, placement, zero_upsample
from ..case import Case, host_call
from ..twin import make_model


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
