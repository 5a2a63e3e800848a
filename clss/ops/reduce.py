"""Reductions over any set of axes (kernels/reduce.cl): the ONNX Reduce* family.

ReduceSum, ReduceMean, ReduceMax, ReduceMin, ReduceProd, ReduceL1, ReduceL2,
ReduceSumSquare, ReduceLogSum and ReduceLogSumExp, with ``axes`` as an attribute (before
opset 18; ReduceSum before 13) or as an input known at load, ``keepdims`` and
``noop_with_empty_axes``. The input is coalesced into at most four kept and four reduced
dimensions (a 6-D reduction over non-adjacent axes is still four of each, after merging
the neighbours that sit together in memory); more raises Unsupported.
"""
from __future__ import annotations

import numpy as np

from .. import selfcheck
from ..device import Device
from ..tolerance import DEFAULT_TOL
from .base import Unsupported, check_storage, onnx_op, rng
from .conv import builtin_free
from .elementwise import _contiguous_strides, coalesce

# Reductions whose outputs are neighbours in the input (k3 == 1): eight per work-item
# (kernel reduce8), loads through clang vectors on PoCL; 0 selects the reference kernel
# `reduce` (one output per work-item) with the builtin loads.
REDUCE_VEC = 1
FAST = "reduce.outputs8"

OPS = {"sum": 0, "mean": 1, "max": 2, "min": 3, "prod": 4, "l1": 5, "l2": 6, "sumsq": 7,
       "logsum": 8, "logsumexp": 9}
ONNX_OPS = {"ReduceSum": "sum", "ReduceMean": "mean", "ReduceMax": "max", "ReduceMin": "min",
            "ReduceProd": "prod", "ReduceL1": "l1", "ReduceL2": "l2", "ReduceSumSquare": "sumsq",
            "ReduceLogSum": "logsum", "ReduceLogSumExp": "logsumexp"}
BUILD_VARIANTS = [dict(ROP=v) for v in OPS.values()]   # each builds reduce and reduce8


def _pad4(shape, strides, what):
    if len(shape) > 4:
        raise ValueError(f"{what}: {len(shape)} dimensions after merging neighbours; the kernel takes 4")
    k = 4 - len(shape)
    return [1] * k + list(shape), [0] * k + list(strides)


def out_shape(shape, axes, keepdims: bool) -> tuple:
    axes = set(axes)
    if keepdims:
        return tuple(1 if i in axes else int(n) for i, n in enumerate(shape))
    return tuple(int(n) for i, n in enumerate(shape) if i not in axes)


def normalise_axes(axes, rank: int) -> list[int]:
    out = []
    for a in axes:
        a = int(a)
        if not -rank <= a < max(rank, 1):
            raise ValueError(f"axis {a} out of range for rank {rank}")
        out.append(a % rank if rank else 0)
    if len(set(out)) != len(out):
        raise ValueError(f"axes {list(axes)} repeat an axis")
    return out


def reduce(dev: Device, prec: str, op: str, x, axes=None, keepdims: bool = True, out=None):
    """ONNX Reduce<op> of x over ``axes`` (None or empty: all axes, as ONNX reads empty
    axes without noop_with_empty_axes). op: a key of OPS."""
    if op not in OPS:
        raise ValueError(f"unknown reduction {op!r}; one of {sorted(OPS)}")
    check_storage("x", x, prec)
    rank = x.ndim
    axes = list(range(rank)) if axes is None or len(axes) == 0 else normalise_axes(axes, rank)
    shape = out_shape(x.shape, axes, keepdims)
    out = out if out is not None else dev.empty(shape, prec)
    if out.size == 0:
        return out
    st = _contiguous_strides(x.shape)
    kept = [(int(n), s) for i, (n, s) in enumerate(zip(x.shape, st)) if i not in axes]
    red = sorted(((int(x.shape[i]), st[i]) for i in axes), key=lambda t: -t[1])
    count = int(np.prod([n for n, _ in red], dtype=np.int64))
    if count == 0:
        red = [(0, 1)]   # an empty reduction: the kernel's loops run zero times (ONNX's identities)
    kshape, (kst,) = coalesce([n for n, _ in kept], [[s for _, s in kept]]) if kept else ([], [[]])
    rshape, (rst,) = coalesce([n for n, _ in red], [[s for _, s in red]]) if red else ([], [[]])
    if count == 0:
        rshape, rst = [0], [1]
    K, ks = _pad4(kshape, kst, f"Reduce over axes {axes} of {tuple(x.shape)} (kept)")
    R, rs = _pad4(rshape, rst, f"Reduce over axes {axes} of {tuple(x.shape)} (reduced)")
    fast = bool(REDUCE_VEC) and selfcheck.enabled(dev, prec, FAST)
    vec8 = fast and ks[3] == 1 and K[3] >= 8 and rs[3] != 1
    k = dev.kernel("reduce", "reduce8" if vec8 else "reduce", prec, ROP=OPS[op],
                   CLSS_CLANG_VECTORS=builtin_free(dev) if fast else 0)
    i32 = np.int32
    dev.launch(k, (-(-K[3] // 8) if vec8 else K[3], K[2], K[0] * K[1]),
               (x.data, out.data, i32(K[1]), i32(K[2]), i32(K[3]), i32(K[0] * K[1]),
                *map(i32, ks), *map(i32, R), *map(i32, rs), np.float32(max(count, 0))))
    return out


# --- ONNX -----------------------------------------------------------------------------

def _onnx_reduce(op):
    def handler(dev, prec, attrs, inputs):
        x = inputs[0]
        axes = inputs[1] if len(inputs) > 1 and inputs[1] is not None else attrs.get("axes")
        keepdims = bool(attrs.get("keepdims", 1))
        if axes is not None:
            axes = [int(a) for a in np.asarray(axes).ravel()]
        if not axes:
            if attrs.get("noop_with_empty_axes", 0):
                from .elementwise import copy
                return [copy(dev, prec, x)]
            axes = None
        try:
            return [reduce(dev, prec, op, x, axes, keepdims)]
        except ValueError as e:
            raise Unsupported(str(e)) from None
    return handler


for _op_type, _name in ONNX_OPS.items():
    onnx_op(_op_type, const_inputs=(1,))(_onnx_reduce(_name))


# --- fast path (clss/selfcheck.py): against the one-output-per-work-item kernel ----------

def _selfcheck(dev: Device, prec: str) -> list[np.ndarray]:
    """Channel reductions over rows of 21 (a ragged tail of eight-wide blocks), a spatial
    mean (a contiguous row), every kind of fold (sum, max, logsumexp)."""
    x = dev.to_device(rng("reduce selfcheck").standard_normal((2, 5, 3, 21)).astype(np.float32), prec)
    return [dev.to_host(reduce(dev, prec, op, x, axes)) for op, axes in
            (("sum", [1]), ("max", [1, 2]), ("logsumexp", [0, 1]), ("mean", [2, 3]))]


selfcheck.register(selfcheck.FastPath(
    FAST, "reduce", {"CLSS_CLANG_VECTORS": 1}, {"CLSS_CLANG_VECTORS": 0}, check=_selfcheck,
    tolerance=DEFAULT_TOL.__getitem__,
    what="reductions: eight neighbouring outputs per work-item (kernel reduce8) and clang vector "
         "loads / one output per work-item (kernel reduce) with the builtin loads"))
