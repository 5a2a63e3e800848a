"""Elementwise ops, layout ops and per-row reductions (kernels/elementwise.cl).

Arithmetic: binary ops with ONNX multidirectional broadcasting (add, sub, mul,
div, min, max, prelu; greater/less/equal -> bool), variadic Min/Max/Sum,
clip, standalone activations, softmax and argmax along any axis.
Data movement, bit-exact: where, concat, split, slice, pad, transpose, expand, copy; reshape-like
ops are metadata only (a view on the same buffer).

Broadcast and strided launches coalesce the shapes to at most four dimensions
(merging dimensions that are contiguous for every operand, dropping size-1
ones); a shape that still needs more raises ValueError (Unsupported in ONNX).
"""
from __future__ import annotations

import numpy as np

from .. import selfcheck
from ..device import Device, storage_dtype
from ..tolerance import DEFAULT_TOL, EXACT
from .base import Unsupported, unsupported_on_value_error, as_str, check_storage, onnx_op, rng
from .conv import builtin_free

BINARY = {"add": 0, "sub": 1, "mul": 2, "div": 3, "min": 4, "max": 5, "prelu": 6,
          "greater": 7, "less": 8, "equal": 9, "greater_equal": 10, "less_equal": 11, "pow": 12}
COMPARISONS = ("greater", "less", "equal", "greater_equal", "less_equal")
UNARY = {"relu": 0, "leaky_relu": 1, "sigmoid": 2, "tanh": 3, "elu": 4, "hard_sigmoid": 5,
         "abs": 6, "neg": 7, "exp": 8, "sqrt": 9, "clip": 10, "hard_swish": 11, "gelu": 12,
         "gelu_tanh": 13, "erf": 14, "log": 15, "reciprocal": 16, "softplus": 17, "softsign": 18,
         "selu": 19, "celu": 20, "thresholded_relu": 21, "mish": 22, "floor": 23, "ceil": 24,
         "round": 25, "sign": 26, "sin": 27, "cos": 28}
PAD_MODES = {"constant": 0, "edge": 1, "reflect": 2, "wrap": 3}
_VEC = 8  # elements per work-item in the flat kernels
# Every -D combination the launches use, for build checks (fp16-native included,
# which PoCL cannot compile): (defines) of kernels/elementwise.cl.
BUILD_VARIANTS = ([dict(OP=o, A_SCALAR=a, B_SCALAR=b) for o in BINARY.values() for a, b in ((0, 0), (1, 0), (0, 1))]
                  + [dict(UOP=u) for u in UNARY.values()] + [dict(PAD_MODE=m) for m in PAD_MODES.values()]
                  + [dict(LAST=1), dict(LOG_SOFTMAX=1)]
                  + [dict(CLIP_LO_BUF=lo, CLIP_HI_BUF=hi) for lo in (0, 1) for hi in (0, 1)])


# --- shapes ----------------------------------------------------------------------

def _contiguous_strides(shape) -> list[int]:
    st, acc = [], 1
    for n in reversed(shape):
        st.append(acc)
        acc *= int(n)
    return st[::-1]


def _broadcast_strides(shape, out_shape) -> list[int]:
    """Element strides of `shape` read as `out_shape` (0 along broadcast dims)."""
    shape = (1,) * (len(out_shape) - len(shape)) + tuple(shape)
    return [0 if n == 1 else s for n, s in zip(shape, _contiguous_strides(shape))]


def coalesce(out_shape, strides: list[list[int]]):
    """Drop size-1 dims and merge neighbours that one stride covers for every
    operand. Returns (shape, strides) of at most the input rank."""
    dims = [(int(n), [s[i] for s in strides]) for i, n in enumerate(out_shape) if n != 1]
    merged: list[tuple[int, list[int]]] = []
    for n, st in dims:
        if merged and all(ps == s * n for ps, s in zip(merged[-1][1], st)):
            merged[-1] = (merged[-1][0] * n, st)
        else:
            merged.append((n, st))
    return [m[0] for m in merged], [[m[1][k] for m in merged] for k in range(len(strides))]


def _four(shape, strides, what: str):
    if len(shape) > 4:
        raise ValueError(f"{what}: needs {len(shape)} dimensions after coalescing; the kernels take 4")
    pad = 4 - len(shape)
    return [1] * pad + list(shape), [[0] * pad + list(s) for s in strides]


def _grid(shape4):
    d0, d1, d2, d3 = shape4
    return (d3, d2, d0 * d1), [np.int32(d1), np.int32(d2), np.int32(d3), np.int32(d0 * d1)]


def _axis(axis: int, rank: int) -> int:
    if not -rank <= axis < max(rank, 1):
        raise ValueError(f"axis {axis} out of range for rank {rank}")
    return axis % rank if rank else 0


def _i32(*vs):
    return [np.int32(v) for v in vs]


# --- binary ------------------------------------------------------------------------

# Broadcasting binary ops whose operands are contiguous or broadcast along the
# innermost (coalesced) axis: kernel binary_bcast8, 8 outputs per work-item;
# 0 selects the reference kernel binary_bcast (one output per work-item).
BCAST_VEC = 1


def binary(dev: Device, prec: str, op: str, a, b, out=None, relu: bool = False):
    """ONNX-broadcasting binary op. Comparisons return a bool (uchar) tensor.
    relu: Relu(a op b) in the same pass (arithmetic ops only; clss.Model's
    binary_relu pass)."""
    if op not in BINARY:
        raise ValueError(f"unknown binary op {op!r}; one of {sorted(BINARY)}")
    if relu and op in COMPARISONS:
        raise ValueError(f"relu: {op} is a comparison")
    check_storage("a", a, prec)
    check_storage("b", b, prec)
    shape = tuple(np.broadcast_shapes(a.shape, b.shape))
    if op == "prelu" and shape != tuple(a.shape):
        raise ValueError(f"prelu: slope {b.shape} does not broadcast to x {a.shape}")
    dtype = np.bool_ if op in COMPARISONS else None
    out = out if out is not None else dev.empty(shape, prec, dtype)
    n = out.size
    if n == 0:
        return out
    if (a.shape == shape or a.size == 1) and (b.shape == shape or b.size == 1):
        k = dev.kernel("elementwise", "binary_flat", prec, OP=BINARY[op], RELU=int(relu),
                       A_SCALAR=int(a.shape != shape), B_SCALAR=int(b.shape != shape))
        dev.launch(k, (-(-n // _VEC),), (a.data, b.data, out.data, np.int32(n)))
        return out
    dims, (sa, sb) = coalesce(shape, [_broadcast_strides(a.shape, shape), _broadcast_strides(b.shape, shape)])
    dims, (sa, sb) = _four(dims, [sa, sb], op)
    gs, dargs = _grid(dims)
    if (BCAST_VEC and sa[3] in (0, 1) and sb[3] in (0, 1) and dims[3] >= 8
            and selfcheck.enabled(dev, prec, "elementwise.bcast8")):
        k = dev.kernel("elementwise", "binary_bcast8", prec, OP=BINARY[op], RELU=int(relu),
                       CLSS_CLANG_VECTORS=builtin_free(dev))
        dev.launch(k, (-(-gs[0] // 8), gs[1], gs[2]), (a.data, b.data, out.data, *dargs, *_i32(*sa, *sb)))
        return out
    k = dev.kernel("elementwise", "binary_bcast", prec, OP=BINARY[op], RELU=int(relu))
    dev.launch(k, gs, (a.data, b.data, out.data, *dargs, *_i32(*sa, *sb)))
    return out


def add(dev, prec, a, b, out=None):
    return binary(dev, prec, "add", a, b, out)


def sub(dev, prec, a, b, out=None):
    return binary(dev, prec, "sub", a, b, out)


def mul(dev, prec, a, b, out=None):
    return binary(dev, prec, "mul", a, b, out)


def div(dev, prec, a, b, out=None):
    return binary(dev, prec, "div", a, b, out)


def minimum(dev, prec, a, b, out=None):
    return binary(dev, prec, "min", a, b, out)


def maximum(dev, prec, a, b, out=None):
    return binary(dev, prec, "max", a, b, out)


def prelu(dev, prec, x, slope, out=None):
    """x < 0 ? x * slope : x, slope broadcast to x (ONNX PRelu)."""
    return binary(dev, prec, "prelu", x, slope, out)


def greater(dev, prec, a, b, out=None):
    return binary(dev, prec, "greater", a, b, out)


def less(dev, prec, a, b, out=None):
    return binary(dev, prec, "less", a, b, out)


def equal(dev, prec, a, b, out=None):
    return binary(dev, prec, "equal", a, b, out)


def variadic(dev: Device, prec: str, op: str, xs):
    """ONNX Min/Max/Sum over any number of broadcastable inputs, folded pairwise
    left to right (in half storage each partial Sum is rounded to half)."""
    if op not in ("min", "max", "add"):
        raise ValueError(f"variadic op must be min, max or add, got {op!r}")
    xs = list(xs)
    if not xs:
        raise ValueError("variadic op needs at least one input")
    if len(xs) == 1:
        return copy(dev, prec, xs[0])
    acc = binary(dev, prec, op, xs[0], xs[1])
    for x in xs[2:]:
        shape = tuple(np.broadcast_shapes(acc.shape, x.shape))
        acc = binary(dev, prec, op, acc, x, out=acc if shape == acc.shape else None)
    return acc


def where(dev: Device, prec: str, cond, a, b, out=None):
    """cond ? a : b with broadcasting; cond a bool/uint8 tensor. Bit-exact."""
    if cond.dtype not in (np.bool_, np.uint8):
        raise TypeError(f"where: condition must be bool or uint8, got {cond.dtype}")
    check_storage("a", a, prec)
    check_storage("b", b, prec)
    shape = tuple(np.broadcast_shapes(cond.shape, a.shape, b.shape))
    out = out if out is not None else dev.empty(shape, prec)
    if out.size == 0:
        return out
    dims, st = coalesce(shape, [_broadcast_strides(t.shape, shape) for t in (cond, a, b)])
    dims, st = _four(dims, st, "where")
    gs, dargs = _grid(dims)
    k = dev.kernel("elementwise", "where_bcast", prec)
    dev.launch(k, gs, (cond.data, a.data, b.data, out.data, *dargs, *_i32(*st[0], *st[1], *st[2])))
    return out


# --- unary -------------------------------------------------------------------------

def unary(dev: Device, prec: str, op: str, x, alpha: float = 0.0, beta: float = 0.0, out=None):
    """Standalone activation / elementwise function; alpha, beta as the ONNX op's."""
    if op not in UNARY:
        raise ValueError(f"unknown unary op {op!r}; one of {sorted(UNARY)}")
    check_storage("x", x, prec)
    out = out if out is not None else dev.empty(x.shape, prec)
    n = x.size
    if n == 0:
        return out
    k = dev.kernel("elementwise", "unary", prec, UOP=UNARY[op])
    dev.launch(k, (-(-n // _VEC),), (x.data, out.data, np.int32(n), np.float32(alpha), np.float32(beta)))
    return out


def relu(dev, prec, x, out=None):
    return unary(dev, prec, "relu", x, out=out)


def leaky_relu(dev, prec, x, alpha: float = 0.01, out=None):
    return unary(dev, prec, "leaky_relu", x, alpha, out=out)


def sigmoid(dev, prec, x, out=None):
    return unary(dev, prec, "sigmoid", x, out=out)


def tanh(dev, prec, x, out=None):
    return unary(dev, prec, "tanh", x, out=out)


def clip(dev, prec, x, lo: float | None = None, hi: float | None = None, out=None):
    """min(max(x, lo), hi); None leaves that side open; NaN passes through."""
    lo = -np.inf if lo is None else float(lo)
    hi = np.inf if hi is None else float(hi)
    return unary(dev, prec, "clip", x, lo, hi, out=out)


# --- data movement --------------------------------------------------------------------

_COPY_RUN_CPU = 8


def _copy_rows(dev, prec, src, dst, length, rows, src_stride, src_off, dst_stride, dst_off):
    if length <= 0 or rows <= 0:
        return
    run = _COPY_RUN_CPU if dev.is_cpu else 1     # runs of 8 per work-item (elementwise.cl -DRUN)
    k = dev.kernel("elementwise", "copy_rows", prec, RUN=run, CLSS_CLANG_VECTORS=builtin_free(dev))
    dev.launch(k, (-(-length // (_VEC * run)), rows),
               (src.data, dst.data, *_i32(length, rows, src_stride, src_off, dst_stride, dst_off)))


def copy(dev: Device, prec: str, x, out=None):
    """A new tensor with x's bits (ONNX Identity)."""
    check_storage("x", x, prec)
    out = out if out is not None else dev.empty(x.shape, prec)
    _copy_rows(dev, prec, x, out, x.size, 1, 0, 0, 0, 0)
    return out


def concat(dev: Device, prec: str, xs, axis: int = 1, out=None, in_place=()):
    """Concatenate along `axis` (any, negative counts from the end). Bit-exact.
    in_place: indices of inputs already stored where they go in `out` (a clss.Model whose
    memory plan gave their producers `out`'s bytes: clss/model/execute.py), not copied."""
    xs = list(xs)
    if not xs:
        raise ValueError("concat needs at least one input")
    for i, x in enumerate(xs):
        check_storage(f"x{i}", x, prec)
    rank = xs[0].ndim
    axis = _axis(axis, rank)
    for x in xs:
        if x.ndim != rank or any(x.shape[d] != xs[0].shape[d] for d in range(rank) if d != axis):
            raise ValueError(f"concat along axis {axis}: shapes {[tuple(t.shape) for t in xs]} disagree")
    total = sum(x.shape[axis] for x in xs)
    shape = list(xs[0].shape)
    shape[axis] = total
    out = out if out is not None else dev.empty(shape, prec)
    outer = int(np.prod(shape[:axis], dtype=np.int64))
    inner = int(np.prod(shape[axis + 1:], dtype=np.int64))
    off = 0
    for i, x in enumerate(xs):
        n = x.shape[axis] * inner
        if i not in in_place:
            _copy_rows(dev, prec, x, out, n, outer, n, 0, total * inner, off)
        off += n
    return out


def split(dev: Device, prec: str, x, split, axis: int = 0):
    """Split along `axis` into parts of the given sizes, or into `split` (an int)
    parts as ONNX Split-18 num_outputs (ceil-sized, the last smaller). Bit-exact."""
    check_storage("x", x, prec)
    axis = _axis(axis, x.ndim)
    n = x.shape[axis]
    if isinstance(split, (int, np.integer)):
        parts = int(split)
        if parts < 1:
            raise ValueError(f"split into {parts} parts")
        size = -(-n // parts)
        sizes = [min(size, max(0, n - i * size)) for i in range(parts)]
    else:
        sizes = [int(s) for s in split]
    if sum(sizes) != n or min(sizes, default=0) < 0:
        raise ValueError(f"split sizes {sizes} do not add up to {n} along axis {axis}")
    outer = int(np.prod(x.shape[:axis], dtype=np.int64))
    inner = int(np.prod(x.shape[axis + 1:], dtype=np.int64))
    outs, off = [], 0
    for s in sizes:
        shape = list(x.shape)
        shape[axis] = s
        y = dev.empty(shape, prec)
        _copy_rows(dev, prec, x, y, s * inner, outer, n * inner, off, s * inner, 0)
        outs.append(y)
        off += s * inner
    return outs


def slice_params(shape, starts, ends, axes=None, steps=None):
    """ONNX Slice semantics: per-dim (start, step, length) after clamping."""
    rank = len(shape)
    axes = list(range(len(starts))) if axes is None else [int(a) for a in axes]
    steps = [1] * len(starts) if steps is None else [int(s) for s in steps]
    if not len(starts) == len(ends) == len(axes) == len(steps):
        raise ValueError("slice: starts, ends, axes and steps must have the same length")
    sel = [(0, 1, int(n)) for n in shape]
    seen = set()
    for st, en, ax, sp in zip(starts, ends, axes, steps):
        ax = _axis(ax, rank)
        if ax in seen:
            raise ValueError(f"slice: axis {ax} repeated")
        seen.add(ax)
        if sp == 0:
            raise ValueError("slice: step 0")
        n = int(shape[ax])
        st, en = int(st), int(en)
        st = st + n if st < 0 else st
        en = en + n if en < 0 else en
        if sp > 0:
            st, en = min(max(st, 0), n), min(max(en, 0), n)
            length = max(0, -(-(en - st) // sp))
        else:
            st, en = min(max(st, 0), n - 1), min(max(en, -1), n - 1)
            length = max(0, -(-(st - en) // -sp))
        sel[ax] = (st, sp, length)
    return sel


def slice(dev: Device, prec: str, x, starts, ends, axes=None, steps=None):  # noqa: A001 - ONNX name
    """ONNX Slice (any steps, negative included; out-of-range bounds clamp). Bit-exact."""
    check_storage("x", x, prec)
    sel = slice_params(x.shape, starts, ends, axes, steps)
    shape = [s[2] for s in sel]
    out = dev.empty(shape, prec)
    if out.size == 0:
        return out
    st = _contiguous_strides(x.shape)
    base = sum(s[0] * t for s, t in zip(sel, st))
    _gather(dev, prec, x, out, base, [s[1] * t for s, t in zip(sel, st)], "slice")
    return out


def transpose(dev: Device, prec: str, x, perm=None):
    """ONNX Transpose (perm default: reversed axes). Any rank whose permutation
    leaves at most 4 runs of axes that stay together. Bit-exact."""
    check_storage("x", x, prec)
    rank = x.ndim
    perm = list(range(rank))[::-1] if perm is None else [int(p) for p in perm]
    if sorted(p % rank if rank else p for p in perm) != list(range(rank)):
        raise ValueError(f"transpose: perm {perm} is not a permutation of the {rank} axes of {x.shape}")
    perm = [p % rank for p in perm]
    out = dev.empty([x.shape[p] for p in perm], prec)
    if out.size:
        st = _contiguous_strides(x.shape)
        _gather(dev, prec, x, out, 0, [st[p] for p in perm], "transpose")
    return out


def expand(dev: Device, prec: str, x, shape):
    """ONNX Expand: x broadcast with ``shape`` (a gather with stride 0 along the
    broadcast axes). Bit-exact."""
    check_storage("x", x, prec)
    out_shape = tuple(np.broadcast_shapes(tuple(x.shape), tuple(int(s) for s in shape)))
    out = dev.empty(out_shape, prec)
    if out.size:
        _gather(dev, prec, x, out, 0, _broadcast_strides(x.shape, out_shape), "expand")
    return out


def _gather(dev, prec, x, out, base: int, src_strides, what: str):
    """out[i] = x[base + sum_d i_d * src_strides[d]] over out's shape: the
    strided copy that slice, transpose and expand are."""
    dims, (src,) = coalesce(out.shape, [list(src_strides)])
    if len(dims) == 1 and src == [1] and base + out.size < 2**31:
        # One contiguous run (a channel slice of one image, NSRR's slot split): the
        # vectorised row copy, 5x the gather kernel's speed on such a slice (PoCL; its
        # buffer copy is a one-thread memcpy, slower still)
        _copy_rows(dev, prec, x, out, out.size, 1, 0, base, 0, 0)
        return
    if len(dims) > 4:
        # more than four runs of axes (a 5-D/6-D transpose: attention heads, window partitions)
        if len(dims) > 8:
            raise ValueError(f"{what}: needs {len(dims)} dimensions after coalescing; the kernels take 8")
        pad = 8 - len(dims)
        d8, s8 = [1] * pad + list(dims), [0] * pad + list(src)
        k = dev.kernel("elementwise", "gather8", prec)
        dev.launch(k, (out.size,), (x.data, out.data, np.int64(out.size), np.int64(base),
                                    *_i32(*d8[1:]), *_i32(*s8)))
        return
    dims, (src,) = _four(dims, [src], what)
    gs, dargs = _grid(dims)
    k = dev.kernel("elementwise", "gather", prec)
    dev.launch(k, gs, (x.data, out.data, *dargs, np.int64(base), *_i32(*src)))


# Softmax over the last axis: one row per work-item, eight lanes at a time (kernel
# softmax_rows); 0 selects the reference kernel `softmax` for it too.
SOFTMAX_ROWS = 1

# Pad with 8 outputs per work-item along the last axis (kernel pad8); 0 selects
# the reference kernel `pad` (one output per work-item).
PAD_VEC = 1
PAD_BLOCKS = 8          # blocks of 8 outputs per pad8 work-item


def pad(dev: Device, prec: str, x, pads, mode: str = "constant", value: float = 0.0, axes=None):
    """ONNX Pad: pads = [begin per axis..., end per axis...] (negative crops),
    modes constant / edge / reflect / wrap. Bit-exact."""
    check_storage("x", x, prec)
    if mode not in PAD_MODES:
        raise ValueError(f"pad mode must be one of {sorted(PAD_MODES)}, got {mode!r}")
    rank = x.ndim
    axes = list(range(rank)) if axes is None else [_axis(int(a), rank) for a in axes]
    pads = [int(p) for p in pads]
    if len(pads) != 2 * len(axes):
        raise ValueError(f"pad: {len(pads)} pads for {len(axes)} axes")
    pb, pe = [0] * rank, [0] * rank
    for i, ax in enumerate(axes):
        pb[ax], pe[ax] = pads[i], pads[len(axes) + i]
    shape = [int(n) + b + e for n, b, e in zip(x.shape, pb, pe)]
    if min(shape, default=1) < 0:
        raise ValueError(f"pad: negative output shape {shape}")
    out = dev.empty(shape, prec)
    if out.size == 0:
        return out
    if mode in ("reflect", "wrap", "edge") and any(
            (b or e) and n == 0 for n, b, e in zip(x.shape, pb, pe)):
        raise ValueError(f"pad mode {mode} needs non-empty padded axes")
    # Merge runs of unpadded axes (and drop unpadded size-1 axes): they are plain copies.
    dims = []  # [in, begin, out]
    for n, b, e in zip(x.shape, pb, pe):
        if b == 0 and e == 0:
            if n == 1:
                continue
            if dims and dims[-1][1] == 0 and dims[-1][0] == dims[-1][2]:
                dims[-1] = [dims[-1][0] * n, 0, dims[-1][2] * n]
                continue
        dims.append([int(n), b, int(n) + b + e])
    if len(dims) > 4:
        raise ValueError(f"pad: needs {len(dims)} dimensions after coalescing; the kernels take 4")
    dims = [[1, 0, 1]] * (4 - len(dims)) + dims
    gs, dargs = _grid([d[2] for d in dims])
    vec = bool(PAD_VEC) and selfcheck.enabled(dev, prec, "elementwise.pad8")
    if vec:
        gs = (-(-gs[0] // (8 * PAD_BLOCKS)), gs[1], gs[2])
    bits = np.array(value, dtype=storage_dtype(prec))
    bits = bits.view(np.uint32 if bits.itemsize == 4 else np.uint16)
    # An empty input is never read (constant mode pads everything) but needs a buffer.
    src = x if x.size else dev.empty((1,), prec)
    if vec:
        k = dev.kernel("elementwise", "pad8", prec, PAD_MODE=PAD_MODES[mode], PAD_BLOCKS=PAD_BLOCKS,
                       CLSS_CLANG_VECTORS=builtin_free(dev))
    else:
        k = dev.kernel("elementwise", "pad", prec, PAD_MODE=PAD_MODES[mode])
    dev.launch(k, gs, (src.data, out.data, *dargs, *_i32(*[d[0] for d in dims], *[d[1] for d in dims]),
                       bits.reshape(())[()]))
    return out


def gather(dev: Device, prec: str, x, indices, axis: int = 0):
    """ONNX Gather with indices known at load (negative ones count from the end). Bit-exact."""
    check_storage("x", x, prec)
    axis = _axis(axis, x.ndim)
    idx = np.asarray(indices).astype(np.int64)
    n = int(x.shape[axis])
    if idx.size and (idx.min() < -n or idx.max() >= n):
        raise ValueError(f"gather: an index of {idx.ravel().tolist()[:8]} is out of range for axis {axis} "
                         f"of length {n}")
    idx = np.where(idx < 0, idx + n, idx).astype(np.int32)
    shape = tuple(x.shape[:axis]) + idx.shape + tuple(x.shape[axis + 1:])
    out = dev.empty(shape, prec)
    if out.size == 0:
        return out
    if idx.size == 1:   # a scalar index (q, k, v = qkv[0], qkv[1], qkv[2]): a strided copy
        sel = [(0, 1, int(m)) for m in x.shape]
        sel[axis] = (int(idx.ravel()[0]), 1, 1)
        st = _contiguous_strides(x.shape)
        _gather(dev, prec, x, out, sel[axis][0] * st[axis],
                [t for k, t in enumerate(st) if k != axis] if idx.ndim == 0 else st, "gather")
        return out
    _, outer, length, inner = _rows(x, axis)
    d_idx = dev.to_device(idx.ravel())
    k = dev.kernel("elementwise", "gather_axis", prec)
    dev.launch(k, (inner, idx.size, outer), (x.data, d_idx.data, out.data,
                                             *_i32(length, inner, idx.size, outer)))
    return out


def tile(dev: Device, prec: str, x, repeats):
    """ONNX Tile: an Expand of x viewed with a size-1 axis before each tiled one, one axis
    at a time (each a broadcast gather of at most three runs). Bit-exact."""
    check_storage("x", x, prec)
    reps = [int(r) for r in repeats]
    if len(reps) != x.ndim or min(reps, default=1) < 0:
        raise ValueError(f"tile: repeats {reps} for a tensor of rank {x.ndim}")
    y = x
    for ax, r in enumerate(reps):
        if r == 1:
            continue
        shape = list(y.shape)
        view = reshape(y, shape[:ax] + [1] + shape[ax:])
        y = reshape(expand(dev, prec, view, shape[:ax] + [r] + shape[ax:]),
                    shape[:ax] + [r * shape[ax]] + shape[ax + 1:])
    return y if y is not x else copy(dev, prec, x)


def clip_tensors(dev: Device, prec: str, x, lo=None, hi=None, out=None):
    """min(max(x, lo), hi) with the bounds as one-element device tensors (ONNX Clip whose
    min/max are computed or fed at run time); None leaves that side open."""
    check_storage("x", x, prec)
    for what, t in (("min", lo), ("max", hi)):
        if t is not None:
            check_storage(f"Clip {what}", t, prec)
            if t.size != 1:
                raise ValueError(f"Clip {what} must be a scalar, got shape {tuple(t.shape)}")
    out = out if out is not None else dev.empty(x.shape, prec)
    n = x.size
    if n == 0:
        return out
    k = dev.kernel("elementwise", "clip_buf", prec, CLIP_LO_BUF=int(lo is not None), CLIP_HI_BUF=int(hi is not None))
    dev.launch(k, (-(-n // _VEC),), (x.data, out.data, np.int32(n), (lo if lo is not None else x).data,
                                     (hi if hi is not None else x).data))
    return out


def reshape(x, shape):
    """A view of x with another shape (no copy, no kernel)."""
    return x.reshape(tuple(int(s) for s in shape))


# --- per-row reductions ---------------------------------------------------------------

def _rows(x, axis):
    axis = _axis(axis, x.ndim)
    outer = int(np.prod(x.shape[:axis], dtype=np.int64))
    inner = int(np.prod(x.shape[axis + 1:], dtype=np.int64))
    return axis, outer, int(x.shape[axis]), inner


def softmax(dev: Device, prec: str, x, axis: int = -1, out=None, log: bool = False):
    """ONNX Softmax-13 along one axis, with max subtraction; log=True: LogSoftmax."""
    check_storage("x", x, prec)
    axis, outer, length, inner = _rows(x, axis)
    out = out if out is not None else dev.empty(x.shape, prec)
    if out.size == 0:
        return out
    if (SOFTMAX_ROWS and inner == 1 and length >= 8
            and selfcheck.enabled(dev, prec, "elementwise.softmax_rows")):
        k = dev.kernel("elementwise", "softmax_rows", prec, LOG_SOFTMAX=int(log),
                       CLSS_CLANG_VECTORS=builtin_free(dev))
        dev.launch(k, (outer,), (x.data, out.data, *_i32(length, outer)))
        return out
    k = dev.kernel("elementwise", "softmax", prec, LOG_SOFTMAX=int(log))
    dev.launch(k, (inner, outer), (x.data, out.data, *_i32(length, inner, outer)))
    return out


def argmax(dev: Device, prec: str, x, axis: int = 0, keepdims: bool = True,
           select_last_index: bool = False):
    """ONNX ArgMax: int64 indices of the (first, or last) maximum along axis."""
    check_storage("x", x, prec)
    axis, outer, length, inner = _rows(x, axis)
    if length == 0:
        raise ValueError("argmax over an empty axis")
    shape = list(x.shape)
    if keepdims:
        shape[axis] = 1
    else:
        del shape[axis]
    out = dev.empty(shape, dtype=np.int64)
    if out.size == 0:
        return out
    k = dev.kernel("elementwise", "argmax", prec, LAST=int(bool(select_last_index)))
    dev.launch(k, (inner, outer), (x.data, out.data, *_i32(length, inner, outer)))
    return out


# --- ONNX -----------------------------------------------------------------------------

# Split-13 without `split` means one equal part per node output: callers (the node-case
# harness, clss.Model) pass the output count as attrs["num_outputs"].
NODE_DEVIATIONS = {
    "test_identity_opt": "optional-typed input; the kernels take tensors",
    "test_identity_sequence": "sequence-typed input; the kernels take tensors",
}


_unsupported = unsupported_on_value_error


for _op_type, _name in (("Add", "add"), ("Sub", "sub"), ("Mul", "mul"), ("Div", "div"),
                        ("PRelu", "prelu"), ("Pow", "pow"), ("Greater", "greater"), ("Less", "less"),
                        ("Equal", "equal"), ("GreaterOrEqual", "greater_equal"),
                        ("LessOrEqual", "less_equal")):
    onnx_op(_op_type)(lambda dev, prec, attrs, inputs, _n=_name:
                      [_unsupported(binary, dev, prec, _n, inputs[0], inputs[1])])

for _op_type, _name in (("Min", "min"), ("Max", "max"), ("Sum", "add")):
    onnx_op(_op_type)(lambda dev, prec, attrs, inputs, _n=_name:
                      [_unsupported(variadic, dev, prec, _n, [i for i in inputs if i is not None])])

# ONNX op type -> (unary op, ONNX defaults of its alpha/beta attributes)
_UNARY_ONNX = {"Relu": ("relu", {}), "LeakyRelu": ("leaky_relu", {"alpha": 0.01}),
               "Sigmoid": ("sigmoid", {}), "Tanh": ("tanh", {}), "Elu": ("elu", {"alpha": 1.0}),
               "HardSigmoid": ("hard_sigmoid", {"alpha": 0.2, "beta": 0.5}),
               "Abs": ("abs", {}), "Neg": ("neg", {}), "Exp": ("exp", {}), "Sqrt": ("sqrt", {}),
               "HardSwish": ("hard_swish", {}), "Erf": ("erf", {}), "Log": ("log", {}),
               "Reciprocal": ("reciprocal", {}), "Softplus": ("softplus", {}), "Softsign": ("softsign", {}),
               "Selu": ("selu", {"alpha": 1.67326319217681884765625, "gamma": 1.05070102214813232421875}),
               "Celu": ("celu", {"alpha": 1.0}), "ThresholdedRelu": ("thresholded_relu", {"alpha": 1.0}),
               "Mish": ("mish", {}), "Floor": ("floor", {}), "Ceil": ("ceil", {}), "Round": ("round", {}),
               "Sign": ("sign", {}), "Sin": ("sin", {}), "Cos": ("cos", {})}


def _onnx_unary(name, defaults):
    def handler(dev, prec, attrs, inputs):
        p = {**defaults, **{k: v for k, v in attrs.items() if k in defaults}}
        # Selu's second parameter is gamma
        beta = p.get("gamma", p.get("beta", 0.0))
        return [unary(dev, prec, name, inputs[0], float(p.get("alpha", 0.0)), float(beta))]
    return handler


for _op_type, (_name, _defaults) in _UNARY_ONNX.items():
    onnx_op(_op_type)(_onnx_unary(_name, _defaults))


def _scalar(v, what):
    v = np.asarray(v)
    if v.size != 1:
        raise Unsupported(f"{what} must be a scalar, got shape {v.shape}")
    return float(v.reshape(()))


@onnx_op("Clip")
def _onnx_clip(dev, prec, attrs, inputs):
    # Clip-11+: min/max are tensors (constants arrive as device tensors too: one kernel reads
    # them from memory, so a bound fed or computed at run time needs no new launch setup);
    # Clip-6: attributes.
    lo = inputs[1] if len(inputs) > 1 else None
    hi = inputs[2] if len(inputs) > 2 else None
    if lo is None and hi is None and ("min" in attrs or "max" in attrs):
        return [clip(dev, prec, inputs[0], attrs.get("min"), attrs.get("max"))]
    return [_unsupported(clip_tensors, dev, prec, inputs[0], lo, hi)]


@onnx_op("Gelu")
def _onnx_gelu(dev, prec, attrs, inputs):
    approx = as_str(attrs.get("approximate", "none"))
    if approx not in ("none", "tanh"):
        raise Unsupported(f"Gelu approximate={approx!r}")
    return [unary(dev, prec, "gelu" if approx == "none" else "gelu_tanh", inputs[0])]


@onnx_op("LogSoftmax")
def _onnx_log_softmax(dev, prec, attrs, inputs):
    return [_unsupported(softmax, dev, prec, inputs[0], int(attrs.get("axis", -1)), log=True)]


@onnx_op("Gather", const_inputs=(1,))
def _onnx_gather(dev, prec, attrs, inputs):
    return [_unsupported(gather, dev, prec, inputs[0], inputs[1], int(attrs.get("axis", 0)))]


@onnx_op("Tile", const_inputs=(1,))
def _onnx_tile(dev, prec, attrs, inputs):
    return [_unsupported(tile, dev, prec, inputs[0], _ints(inputs[1]))]


@onnx_op("Where")
def _onnx_where(dev, prec, attrs, inputs):
    return [_unsupported(where, dev, prec, inputs[0], inputs[1], inputs[2])]


@onnx_op("Softmax")
def _onnx_softmax(dev, prec, attrs, inputs):
    # Softmax-13 semantics (one axis, default -1); the opset < 13 "coerce to 2-D"
    # form differs only when axis is not the last one.
    return [_unsupported(softmax, dev, prec, inputs[0], int(attrs.get("axis", -1)))]


@onnx_op("ArgMax")
def _onnx_argmax(dev, prec, attrs, inputs):
    return [_unsupported(argmax, dev, prec, inputs[0], int(attrs.get("axis", 0)),
                         bool(attrs.get("keepdims", 1)), bool(attrs.get("select_last_index", 0)))]


@onnx_op("Concat")
def _onnx_concat(dev, prec, attrs, inputs):
    return [_unsupported(concat, dev, prec, [i for i in inputs if i is not None], int(attrs["axis"]),
                         in_place=tuple(attrs.get("_in_place", ())))]


@onnx_op("Split", const_inputs=(1,))
def _onnx_split(dev, prec, attrs, inputs):
    x = inputs[0]
    parts = inputs[1] if len(inputs) > 1 and inputs[1] is not None else attrs.get("split")
    if parts is None:
        if "num_outputs" not in attrs:
            raise Unsupported("Split without split sizes or num_outputs (the output count is not passed)")
        parts = int(attrs["num_outputs"])
    else:
        parts = [int(s) for s in np.asarray(parts).ravel()]
    return _unsupported(split, dev, prec, x, parts, int(attrs.get("axis", 0)))


def _ints(v):
    return None if v is None else [int(s) for s in np.asarray(v).ravel()]


@onnx_op("Slice", const_inputs=(1, 2, 3, 4))
def _onnx_slice(dev, prec, attrs, inputs):
    ins = list(inputs) + [None] * (5 - len(inputs))
    if ins[1] is None:  # Slice-1: attributes
        starts, ends, axes, steps = attrs["starts"], attrs["ends"], attrs.get("axes"), None
    else:
        starts, ends, axes, steps = (_ints(v) for v in ins[1:5])
    return [_unsupported(slice, dev, prec, ins[0], list(starts), list(ends), axes, steps)]


@onnx_op("Pad", const_inputs=(1, 2, 3))
def _onnx_pad(dev, prec, attrs, inputs):
    ins = list(inputs) + [None] * (4 - len(inputs))
    mode = as_str(attrs.get("mode", "constant"))
    if mode not in PAD_MODES:
        raise Unsupported(f"Pad mode {mode!r}")
    if ins[1] is None:  # Pad-2: attributes
        pads, value, axes = attrs["pads"], float(attrs.get("value", 0.0)), None
    else:
        pads = _ints(ins[1])
        value = _scalar(ins[2], "Pad constant_value") if ins[2] is not None else 0.0
        axes = _ints(ins[3])
    return [_unsupported(pad, dev, prec, ins[0], pads, mode, value, axes)]


@onnx_op("Transpose")
def _onnx_transpose(dev, prec, attrs, inputs):
    return [_unsupported(transpose, dev, prec, inputs[0], attrs.get("perm"))]


@onnx_op("Expand", const_inputs=(1,))
def _onnx_expand(dev, prec, attrs, inputs):
    return [_unsupported(expand, dev, prec, inputs[0], _ints(inputs[1]))]


@onnx_op("Identity")
def _onnx_identity(dev, prec, attrs, inputs):
    return [copy(dev, prec, inputs[0])]


@onnx_op("Reshape", const_inputs=(1,))
def _onnx_reshape(dev, prec, attrs, inputs):
    x, spec = inputs[0], _ints(inputs[1])
    allowzero = bool(attrs.get("allowzero", 0))
    shape = [x.shape[i] if (s == 0 and not allowzero) else s for i, s in enumerate(spec)]
    if shape.count(-1) > 1:
        raise Unsupported(f"Reshape {spec}: more than one -1")
    if -1 in shape:
        known = int(np.prod([s for s in shape if s != -1], dtype=np.int64))
        shape[shape.index(-1)] = x.size // known if known else 0
    if int(np.prod(shape, dtype=np.int64)) != x.size:
        raise Unsupported(f"Reshape of {x.shape} to {spec}: sizes differ")
    return [reshape(x, shape)]


@onnx_op("Flatten")
def _onnx_flatten(dev, prec, attrs, inputs):
    x = inputs[0]
    axis = int(attrs.get("axis", 1))
    axis = axis + x.ndim if axis < 0 else axis
    outer = int(np.prod(x.shape[:axis], dtype=np.int64))
    return [reshape(x, (outer, int(np.prod(x.shape[axis:], dtype=np.int64))))]


@onnx_op("Squeeze", const_inputs=(1,))
def _onnx_squeeze(dev, prec, attrs, inputs):
    x = inputs[0]
    axes = _ints(inputs[1]) if len(inputs) > 1 and inputs[1] is not None else attrs.get("axes")
    if axes is None:
        shape = [n for n in x.shape if n != 1]
    else:
        drop = {a % x.ndim for a in axes}
        if any(x.shape[a] != 1 for a in drop):
            raise Unsupported(f"Squeeze axes {axes} of shape {x.shape}: not size 1")
        shape = [n for i, n in enumerate(x.shape) if i not in drop]
    return [reshape(x, shape)]


@onnx_op("Unsqueeze", const_inputs=(1,))
def _onnx_unsqueeze(dev, prec, attrs, inputs):
    x = inputs[0]
    axes = _ints(inputs[1]) if len(inputs) > 1 and inputs[1] is not None else list(attrs["axes"])
    rank = x.ndim + len(axes)
    axes = sorted(a % rank for a in axes)
    shape = list(x.shape)
    for a in axes:
        shape.insert(a, 1)
    return [reshape(x, shape)]


# --- fast paths (clss/selfcheck.py): each against its one-output-per-work-item kernel

def _selfcheck_pad(dev: Device, prec: str) -> list[np.ndarray]:
    """Constant, edge and reflect pads of rows off multiples of 8 (tails, both ends)."""
    x = dev.to_device(rng("pad selfcheck").standard_normal((1, 3, 5, 21)).astype(np.float32), prec)
    return [dev.to_host(pad(dev, prec, x, [0, 0, 1, 3, 0, 0, 2, 12], mode)) for mode in
            ("constant", "edge", "reflect")]


def _selfcheck_bcast(dev: Device, prec: str) -> list[np.ndarray]:
    """Broadcasts along channels and rows, contiguous innermost axes of 21 (a ragged tail)."""
    g = rng("bcast selfcheck")
    a = dev.to_device(g.standard_normal((1, 3, 5, 21)).astype(np.float32), prec)
    b = dev.to_device(g.standard_normal((1, 1, 5, 21)).astype(np.float32), prec)
    c = dev.to_device(g.standard_normal((1, 3, 1, 21)).astype(np.float32), prec)
    return [dev.to_host(binary(dev, prec, op, a, o)) for op in ("add", "mul") for o in (b, c)]


selfcheck.register(selfcheck.FastPath(
    "elementwise.pad8", "elementwise", {"PAD_VEC": 1}, {"PAD_VEC": 0}, check=_selfcheck_pad,
    tolerance=lambda prec: EXACT, what="pad: 8 x PAD_BLOCKS outputs per work-item (kernel pad8)"))
def _selfcheck_softmax_rows(dev: Device, prec: str) -> list[np.ndarray]:
    """Rows of 21 and 8 (a ragged tail, a single block), softmax and log-softmax."""
    g = rng("softmax rows selfcheck")
    outs = []
    for shape in ((3, 5, 21), (4, 8)):
        x = dev.to_device((g.standard_normal(shape) * 4).astype(np.float32), prec)
        outs += [dev.to_host(softmax(dev, prec, x, -1, log=lg)) for lg in (False, True)]
    return outs


selfcheck.register(selfcheck.FastPath(
    "elementwise.softmax_rows", "elementwise", {"SOFTMAX_ROWS": 1, "CLSS_CLANG_VECTORS": 1},
    {"SOFTMAX_ROWS": 0}, check=_selfcheck_softmax_rows, tolerance=DEFAULT_TOL.__getitem__,
    what="softmax over the last axis: one row per work-item, eight lanes at a time (kernel softmax_rows) "
         "/ one work-item per row walking rows L apart (kernel softmax)"))
selfcheck.register(selfcheck.FastPath(
    "elementwise.bcast8", "elementwise", {"BCAST_VEC": 1}, {"BCAST_VEC": 0}, check=_selfcheck_bcast,
    tolerance=DEFAULT_TOL.__getitem__,
    what="broadcasting binary ops: 8 outputs per work-item (kernel binary_bcast8)"))
