"""Conformance cases of the depth scatter and ScatterElements (clss/ops/scatter.py,
kernels/scatter.cl): ONNX twins and seeded cases, `cases(level)` for `clss verify` and the
tests."""
from __future__ import annotations

import numpy as np
from onnx import helper

from ...ops.base import rng
from ...ops.scatter import (DEPTH_MODES, FAR, REDUCTIONS, WEIGHT_THRESHOLD, bits_as_float,
                            scatter_depth, scatter_elements)
from ..case import Case
from ..twin import make_model, node_model


def depth_taps(motion: np.ndarray, weight_threshold: float = WEIGHT_THRESHOLD) -> np.ndarray:
    """ScatterElements indices for scatter_depth, [N, 4*h*w] int64 into a flattened
    [N, h*w + 1] buffer: tap k of pixel p at k*h*w + p; taps that are off screen or
    weigh <= the threshold point at the dump slot h*w. The float32 arithmetic is the
    kernel's, operation for operation, so the threshold test agrees exactly."""
    m = np.asarray(motion, np.float32)
    n, _, h, w = m.shape
    px = np.arange(w, dtype=np.float32)[None, None, :] + m[:, 0]
    py = np.arange(h, dtype=np.float32)[None, :, None] + m[:, 1]
    bx, by = np.floor(px), np.floor(py)
    fx, fy = px - bx, py - by
    one = np.float32(1)
    weights = [(one - fx) * (one - fy), fx * (one - fy), (one - fx) * fy, fx * fy]
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(bx) & np.isfinite(by)
        bxi = np.where(finite, bx, -10).astype(np.int64)
        byi = np.where(finite, by, -10).astype(np.int64)
    taps = []
    for k, wk in enumerate(weights):
        tx, ty = bxi + (k & 1), byi + (k >> 1)
        ok = finite & (wk > np.float32(weight_threshold)) & (tx >= 0) & (tx < w) & (ty >= 0) & (ty < h)
        taps.append(np.where(ok, ty * w + tx, h * w).reshape(n, h * w))
    return np.concatenate(taps, axis=1).astype(np.int64)


def twin_scatter_depth(depth: np.ndarray, idx: np.ndarray, mode: str, clear: float | None = None):
    """Reshape -> Concat x4 (the updates of the 4 taps) -> ScatterElements(max|min) into a
    cleared [N, h*w + 1] buffer -> drop the dump slot -> [N,1,h,w]."""
    n, _, h, w = depth.shape
    clear = FAR[mode] if clear is None else clear
    nodes = [helper.make_node("Reshape", ["depth", "flat"], ["d"]),
             helper.make_node("Concat", ["d", "d", "d", "d"], ["upd"], axis=1),
             helper.make_node("ScatterElements", ["buf", "idx", "upd"], ["s"], axis=1, reduction=mode),
             helper.make_node("Slice", ["s", "zero", "hw", "one"], ["s2"]),
             helper.make_node("Reshape", ["s2", "shape"], ["y0"])]
    inits = {"flat": np.array([n, h * w], np.int64), "buf": np.full((n, h * w + 1), clear, np.float32),
             "zero": np.array([0], np.int64), "hw": np.array([h * w], np.int64), "one": np.array([1], np.int64),
             "shape": np.array([n, 1, h, w], np.int64)}
    return make_model(nodes, {"depth": depth, "idx": idx}, ["y0"], initializers=inits, opset=18)


def twin_scatter_elements(data, indices, updates, axis, reduction):
    return node_model("ScatterElements", {"data": data, "indices": indices, "updates": updates},
                      axis=axis, reduction=reduction)


# --- cases ----------------------------------------------------------------------

def depth_case(n, h, w, mode, reach=2.0, *, snap=False):
    """Random depths moved by random motions (fp16-exact, so that both precisions
    scatter to the same taps); ``snap`` puts some motions on integer and near-integer
    positions, where the weight threshold decides which taps are written."""
    g = rng("scatter_depth", n, h, w, mode, reach, snap)
    depth = g.uniform(0, 1, (n, 1, h, w)).astype(np.float32)
    depth[g.random(depth.shape) < 0.05] = 0.0
    motion = g.uniform(-reach, reach, (n, 2, h, w))
    if snap:
        frac = g.choice(np.array([0.0, 0.005, 0.0078125, 0.0125, 0.99, 0.995, 0.5]), motion.shape)
        motion = np.where(g.random(motion.shape) < 0.5, np.round(motion) + frac, motion)
    motion = motion.astype(np.float16).astype(np.float32)
    idx = depth_taps(motion)

    def run(dev, prec, inputs):
        buf = scatter_depth(dev, prec, dev.to_device(inputs["depth"], prec), dev.to_device(inputs["motion"], prec),
                            mode)
        return [bits_as_float(buf.get())]
    return Case("scatter_depth", f"{mode} {n}x1x{h}x{w} reach{reach}{' snap' if snap else ''}",
                {"depth": depth, "motion": motion, "idx": idx}, twin_scatter_depth(depth, idx, mode), run,
                exact=True)


def elements_case(dshape, ishape, axis, reduction, *, negative=False, idx_dtype=np.int64):
    """ScatterElements with duplicates for the reductions (none gets distinct indices per
    line: its result would be order-dependent), negative data (the keyed max/min),
    optionally negative indices and int32 indices."""
    g = rng("scatter_elements", dshape, ishape, axis, reduction, negative, np.dtype(idx_dtype).name)
    r = len(dshape)
    a = axis % r
    data = g.standard_normal(dshape).astype(np.float32)
    updates = g.standard_normal(ishape).astype(np.float32)
    if reduction == "mul":
        updates = (np.sign(updates) * g.uniform(0.5, 1.5, ishape)).astype(np.float32)
    dim = dshape[a]
    if reduction == "none":
        if ishape[a] > dim:
            raise ValueError("reduction none needs distinct indices: indices longer than the axis")
        keys = g.random(tuple(dim if k == a else s for k, s in enumerate(ishape)))
        idx = np.take(np.argsort(keys, axis=a), np.arange(ishape[a]), axis=a)
    else:
        idx = g.integers(0, dim, ishape)
    if negative:
        idx = np.where(g.random(ishape) < 0.5, idx - dim, idx)
    idx = idx.astype(idx_dtype)

    def run(dev, prec, inputs):
        out = scatter_elements(dev, prec, dev.to_device(inputs["data"], prec), dev.to_device(inputs["indices"]),
                               dev.to_device(inputs["updates"], prec), axis, reduction)
        return [dev.to_host(out)]
    variant = (f"{reduction} axis{axis} {'x'.join(map(str, dshape))}<-{'x'.join(map(str, ishape))}"
               f"{' neg' if negative else ''}{' int32' if idx_dtype == np.int32 else ''}")
    return Case("scatter_elements", variant, {"data": data, "indices": idx, "updates": updates},
                twin_scatter_elements(data, idx, updates, axis, reduction), run,
                exact=reduction in ("none", "max", "min"))


def cases(level: str = "quick") -> list[Case]:
    out = []
    if level == "tiny":
        for mode in DEPTH_MODES:
            out.append(depth_case(1, 5, 7, mode, 1.5, snap=True))
        for red in REDUCTIONS:
            out.append(elements_case((3, 5), (3, 4), 1, red, negative=True))
        out.append(elements_case((4, 3), (6, 3), 0, "max", idx_dtype=np.int32))
        return out
    for mode in DEPTH_MODES:
        out.append(depth_case(1, 7, 13, mode))
        out.append(depth_case(2, 31, 27, mode, 3.0, snap=True))
    for red in REDUCTIONS:
        out.append(elements_case((2, 7, 13), (2, 7, 9), -1, red, negative=True))
    if level != "full":
        return out
    for mode in DEPTH_MODES:
        out.append(depth_case(1, 1, 1, mode, 0.9))
        out.append(depth_case(1, 1, 9, mode, 1.2, snap=True))
        out.append(depth_case(2, 13, 7, mode, 12.0))          # mostly off screen
        out.append(depth_case(1, 31, 27, mode, 0.6, snap=True))  # dense collisions, threshold edges
    for red in REDUCTIONS:
        out.append(elements_case((1,), (1,), 0, red))
        out.append(elements_case((23,), (17 if red == "none" else 40,), 0, red, negative=True))
        out.append(elements_case((5, 7, 13), (3, 7, 11), 0, red))
        out.append(elements_case((2, 3, 5, 7), (2, 2, 5, 6), 2, red, negative=True))
        out.append(elements_case((2, 3, 5, 7), (1, 3, 4, 7), -3, red, idx_dtype=np.int32))
        out.append(elements_case((3, 1, 2, 1, 2, 1, 3, 2), (2, 1, 2, 1, 1, 1, 3, 2), 6, red))
    return out


# NSS's frame kernels (clss/methods/nss/nss.cl; its atomic depth path is scatter_depth) run
# with this family's cases, so that `clss verify` checks them (clss.ops.FAMILIES lists the
# families).
_cases_scatter = cases


def cases(level: str = "quick") -> list[Case]:  # noqa: F811
    from .nss import cases as nss_cases
    return _cases_scatter(level) + nss_cases(level)
