"""Scatter with atomic reductions (kernels/scatter.cl): FSR2 previous-depth
reconstruction and ONNX ScatterElements (opset 18) on float data.

``scatter_depth`` is stage 2 of the CLSS frame (clss-frame.md): each pixel's depth is
pushed to the bilinear taps of its reprojected position with atomic max (reversed-Z)
or min, into a uint32 buffer of float32 bits. Its ONNX twin is ScatterElements with
reduction max/min over indices computed here in numpy.

``scatter_elements`` accumulates in float32 bits (32-bit atomics only), so fp16 data
is widened on entry and rounded once at the end. max/min are exact for any float
(order-preserving key); add/mul use compare-and-swap loops, so their rounding depends
on the (unspecified) order of duplicate updates; with reduction none, duplicates are
order-dependent in ONNX too: one of the updates lands, which is unspecified.
"""
from __future__ import annotations

import numpy as np
import pyopencl.cltypes as cltypes
from onnx import helper

from ..device import Device
from .base import Case, Unsupported, as_str, check_storage, onnx_op, rng
from .twin import make_model, node_model

REDUCTIONS = ("none", "add", "mul", "max", "min")
DEPTH_MODES = ("max", "min")
# The far plane, the identity of each reduction over depths in [0, 1]: reversed-Z keeps
# the max (far = 0.0), standard Z the min (far = 1.0, as FSR2 clears it).
FAR = {"max": 0.0, "min": 1.0}
# FSR2's fReconstructedDepthBilinearWeightThreshold.
WEIGHT_THRESHOLD = 0.01
MAX_RANK = 8


def _depth_mode(mode: str) -> int:
    if mode not in DEPTH_MODES:
        raise ValueError(f"mode must be 'max' (reversed-Z) or 'min', got {mode!r}")
    return int(mode == "max")


def scatter_depth(dev: Device, prec: str, depth, motion, mode: str = "max", *, clear: float | None = None,
                  weight_threshold: float = WEIGHT_THRESHOLD, out=None):
    """depth [N,1,h,w], motion [N,2,h,w] (render pixels, ``prev = p + motion``), storage
    precision -> uint32 [N,1,h,w] of float32 bits (``bits_as_float`` views it as float).

    The buffer is cleared to ``clear`` (default ``FAR[mode]``), then pixel (x, y)'s depth
    goes to each tap (floor(x + mx) + i, floor(y + my) + j), i, j in {0, 1}, that is on
    screen and whose bilinear weight exceeds ``weight_threshold``, keeping the max or min.
    Depths must be >= 0 (float bits order as uints only then); negative and NaN depths
    are skipped, -0 counts as +0."""
    check_storage("depth", depth, prec)
    check_storage("motion", motion, prec)
    depth_max = _depth_mode(mode)
    if depth.ndim != 4 or depth.shape[1] != 1:
        raise ValueError(f"scatter_depth: depth {depth.shape}: expected [N,1,h,w]")
    n, _, h, w = depth.shape
    if motion.shape != (n, 2, h, w):
        raise ValueError(f"scatter_depth: motion {motion.shape}: expected {(n, 2, h, w)}")
    if out is None:
        out = dev.empty(depth.shape, dtype=np.uint32)
    elif out.dtype != np.uint32 or out.shape != depth.shape:
        raise TypeError(f"scatter_depth: out must be uint32 {depth.shape}, got {out.dtype} {out.shape}")
    clear = FAR[mode] if clear is None else float(clear)
    if out.size:
        # fill_u32 comes from the same build as scatter_depth: one compile per variant.
        opts = {"DEPTH_MAX": depth_max}
        dev.launch(dev.kernel("scatter", "fill_u32", prec, **opts), (out.size,),
                   (out.data, np.uint32(np.float32(clear).view(np.uint32)), np.int32(out.size)))
        k = dev.kernel("scatter", "scatter_depth", prec, **opts)
        dev.launch(k, (w, h, n), (depth.data, motion.data, out.data, np.int32(h), np.int32(w), np.int32(n),
                                  np.float32(weight_threshold)))
    return out


def bits_as_float(buf):
    """A float32 view of a uint32 depth-bits buffer (no copy; device or host array)."""
    return buf.view(np.float32)


def scatter_elements(dev: Device, prec: str, data, indices, updates, axis: int = 0,
                     reduction: str = "none", out=None):
    """ONNX ScatterElements: out = copy of data; for every position j of indices,
    out[j with j[axis] replaced by indices[j]] (op)= updates[j]. indices: int32 or
    int64 device array (negative values count from the end; out-of-range ones are
    dropped, where ONNX calls them an error). ``out`` may be ``data`` (in place)."""
    check_storage("data", data, prec)
    check_storage("updates", updates, prec)
    if reduction not in REDUCTIONS:
        raise ValueError(f"reduction must be one of {', '.join(REDUCTIONS)}, got {reduction!r}")
    if indices.dtype not in (np.int32, np.int64):
        raise TypeError(f"indices: expected int32 or int64, got {indices.dtype}")
    r = data.ndim
    if not 1 <= r <= MAX_RANK:
        raise ValueError(f"scatter_elements: rank {r} not in 1..{MAX_RANK}")
    if not -r <= axis < r:
        raise ValueError(f"scatter_elements: axis {axis} out of range for rank {r}")
    axis %= r
    if indices.shape != updates.shape or indices.ndim != r or any(
            i > d for k, (i, d) in enumerate(zip(indices.shape, data.shape)) if k != axis):
        raise ValueError(f"scatter_elements: indices {indices.shape} / updates {updates.shape} do not fit "
                         f"data {data.shape} (same rank, same shape, no larger than data off the axis)")
    out = out if out is not None else dev.empty(data.shape, prec)
    if out.size == 0:
        return out
    # init, scatter and final share one build per (precision, reduction, index type)
    opts = {"RED": REDUCTIONS.index(reduction), "IDX64": int(indices.dtype == np.int64)}
    keyed = reduction in ("max", "min")
    # fp32 accumulates in the output buffer itself; fp16 needs 32-bit room for atomics.
    acc = out if prec == "fp32" else dev.empty(data.shape, dtype=np.uint32)
    nd = np.int32(data.size)
    dev.launch(dev.kernel("scatter", "scatter_init", prec, **opts), (data.size,), (data.data, acc.data, nd))
    if indices.size:
        strides = np.cumprod((data.shape[1:] + (1,))[::-1])[::-1]   # element strides, C order
        ishape = list(indices.shape[::-1]) + [1] * (MAX_RANK - r)
        dstride = [0 if k == axis else int(s) for k, s in enumerate(strides)][::-1] + [0] * (MAX_RANK - r)
        k = dev.kernel("scatter", "scatter_elements", prec, **opts)
        dev.launch(k, (indices.size,), (indices.data, updates.data, acc.data, np.int32(indices.size),
                                        cltypes.make_int8(*ishape), cltypes.make_int8(*dstride),
                                        np.int32(data.shape[axis]), np.int32(strides[axis])))
    if prec != "fp32" or keyed:
        dev.launch(dev.kernel("scatter", "scatter_final", prec, **opts), (data.size,), (acc.data, out.data, nd))
    return out


# --- ONNX -----------------------------------------------------------------------

@onnx_op("ScatterElements")
def _onnx_scatter_elements(dev, prec, attrs, inputs):
    data, indices, updates = inputs[:3]
    reduction = as_str(attrs.get("reduction", "none"))
    if reduction not in REDUCTIONS:
        raise Unsupported(f"ScatterElements reduction {reduction!r}")
    if data.ndim > MAX_RANK:
        raise Unsupported(f"ScatterElements of rank {data.ndim} (at most {MAX_RANK})")
    return [scatter_elements(dev, prec, data, indices, updates, int(attrs.get("axis", 0)), reduction)]


# --- twins ----------------------------------------------------------------------

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
