"""Scatter with atomic reductions (kernels/scatter.cl): FSR2 previous-depth
reconstruction and ONNX ScatterElements (opset 18) on float data.

``scatter_depth`` is stage 2 of the CLSS frame (clss-frame.md): each pixel's depth is
pushed to the bilinear taps of its reprojected position with atomic max (reversed-Z)
or min, into a uint32 buffer of float32 bits. Its ONNX twin is ScatterElements with
reduction max/min over indices computed in numpy (clss/verify/cases/scatter.py).

``scatter_elements`` accumulates in float32 bits (32-bit atomics only), so fp16 data
is widened on entry and rounded once at the end. max/min are exact for any float
(order-preserving key); add/mul use compare-and-swap loops, so their rounding depends
on the (unspecified) order of duplicate updates; with reduction none, duplicates are
order-dependent in ONNX too: one of the updates lands, which is unspecified.
"""
from __future__ import annotations

import numpy as np
import pyopencl.cltypes as cltypes

from ..device import Device
from .base import Unsupported, as_str, check_storage, onnx_op

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
