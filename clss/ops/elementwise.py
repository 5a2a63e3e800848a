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
from .base import (DEFAULT_TOL, EXACT, Case, Tolerance, Unsupported, as_str, check_storage, host_call,
                   onnx_op, rng)
from .conv import builtin_free
from .twin import node_model

BINARY = {"add": 0, "sub": 1, "mul": 2, "div": 3, "min": 4, "max": 5, "prelu": 6,
          "greater": 7, "less": 8, "equal": 9, "greater_equal": 10, "less_equal": 11}
COMPARISONS = ("greater", "less", "equal", "greater_equal", "less_equal")
UNARY = {"relu": 0, "leaky_relu": 1, "sigmoid": 2, "tanh": 3, "elu": 4, "hard_sigmoid": 5,
         "abs": 6, "neg": 7, "exp": 8, "sqrt": 9, "clip": 10}
PAD_MODES = {"constant": 0, "edge": 1, "reflect": 2, "wrap": 3}
_VEC = 8  # elements per work-item in the flat kernels
# Every -D combination the launches use, for build checks (fp16-native included,
# which PoCL cannot compile): (defines) of kernels/elementwise.cl.
BUILD_VARIANTS = ([dict(OP=o, A_SCALAR=a, B_SCALAR=b) for o in BINARY.values() for a, b in ((0, 0), (1, 0), (0, 1))]
                  + [dict(UOP=u) for u in UNARY.values()] + [dict(PAD_MODE=m) for m in PAD_MODES.values()]
                  + [dict(LAST=1)])


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


def binary(dev: Device, prec: str, op: str, a, b, out=None):
    """ONNX-broadcasting binary op. Comparisons return a bool (uchar) tensor."""
    if op not in BINARY:
        raise ValueError(f"unknown binary op {op!r}; one of {sorted(BINARY)}")
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
        k = dev.kernel("elementwise", "binary_flat", prec, OP=BINARY[op],
                       A_SCALAR=int(a.shape != shape), B_SCALAR=int(b.shape != shape))
        dev.launch(k, (-(-n // _VEC),), (a.data, b.data, out.data, np.int32(n)))
        return out
    dims, (sa, sb) = coalesce(shape, [_broadcast_strides(a.shape, shape), _broadcast_strides(b.shape, shape)])
    dims, (sa, sb) = _four(dims, [sa, sb], op)
    gs, dargs = _grid(dims)
    if (BCAST_VEC and sa[3] in (0, 1) and sb[3] in (0, 1) and dims[3] >= 8
            and selfcheck.enabled(dev, prec, "elementwise.bcast8")):
        k = dev.kernel("elementwise", "binary_bcast8", prec, OP=BINARY[op],
                       CLSS_CLANG_VECTORS=builtin_free(dev))
        dev.launch(k, (-(-gs[0] // 8), gs[1], gs[2]), (a.data, b.data, out.data, *dargs, *_i32(*sa, *sb)))
        return out
    k = dev.kernel("elementwise", "binary_bcast", prec, OP=BINARY[op])
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

def _copy_rows(dev, prec, src, dst, length, rows, src_stride, src_off, dst_stride, dst_off):
    if length <= 0 or rows <= 0:
        return
    k = dev.kernel("elementwise", "copy_rows", prec)
    dev.launch(k, (-(-length // _VEC), rows),
               (src.data, dst.data, *_i32(length, rows, src_stride, src_off, dst_stride, dst_off)))


def copy(dev: Device, prec: str, x, out=None):
    """A new tensor with x's bits (ONNX Identity)."""
    check_storage("x", x, prec)
    out = out if out is not None else dev.empty(x.shape, prec)
    _copy_rows(dev, prec, x, out, x.size, 1, 0, 0, 0, 0)
    return out


def concat(dev: Device, prec: str, xs, axis: int = 1, out=None):
    """Concatenate along `axis` (any, negative counts from the end). Bit-exact."""
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
    for x in xs:
        n = x.shape[axis] * inner
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
    dims, (src,) = _four(dims, [src], what)
    gs, dargs = _grid(dims)
    k = dev.kernel("elementwise", "gather", prec)
    dev.launch(k, gs, (x.data, out.data, *dargs, np.int64(base), *_i32(*src)))


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


def reshape(x, shape):
    """A view of x with another shape (no copy, no kernel)."""
    return x.reshape(tuple(int(s) for s in shape))


# --- per-row reductions ---------------------------------------------------------------

def _rows(x, axis):
    axis = _axis(axis, x.ndim)
    outer = int(np.prod(x.shape[:axis], dtype=np.int64))
    inner = int(np.prod(x.shape[axis + 1:], dtype=np.int64))
    return axis, outer, int(x.shape[axis]), inner


def softmax(dev: Device, prec: str, x, axis: int = -1, out=None):
    """ONNX Softmax-13 along one axis, with max subtraction."""
    check_storage("x", x, prec)
    axis, outer, length, inner = _rows(x, axis)
    out = out if out is not None else dev.empty(x.shape, prec)
    if out.size == 0:
        return out
    k = dev.kernel("elementwise", "softmax", prec)
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


def _unsupported(fn, *args, **kw):
    try:
        return fn(*args, **kw)
    except ValueError as e:
        raise Unsupported(str(e)) from None


for _op_type, _name in (("Add", "add"), ("Sub", "sub"), ("Mul", "mul"), ("Div", "div"),
                        ("PRelu", "prelu"), ("Greater", "greater"), ("Less", "less"),
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
               "Abs": ("abs", {}), "Neg": ("neg", {}), "Exp": ("exp", {}), "Sqrt": ("sqrt", {})}


def _onnx_unary(name, defaults):
    def handler(dev, prec, attrs, inputs):
        p = {**defaults, **{k: v for k, v in attrs.items() if k in defaults}}
        return [unary(dev, prec, name, inputs[0], float(p.get("alpha", 0.0)), float(p.get("beta", 0.0)))]
    return handler


for _op_type, (_name, _defaults) in _UNARY_ONNX.items():
    onnx_op(_op_type)(_onnx_unary(_name, _defaults))


def _scalar(v, what):
    v = np.asarray(v)
    if v.size != 1:
        raise Unsupported(f"{what} must be a scalar, got shape {v.shape}")
    return float(v.reshape(()))


@onnx_op("Clip", const_inputs=(1, 2))
def _onnx_clip(dev, prec, attrs, inputs):
    lo = inputs[1] if len(inputs) > 1 else None
    hi = inputs[2] if len(inputs) > 2 else None
    lo = _scalar(lo, "Clip min") if lo is not None else attrs.get("min")
    hi = _scalar(hi, "Clip max") if hi is not None else attrs.get("max")
    return [clip(dev, prec, inputs[0], lo, hi)]


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
    return [_unsupported(concat, dev, prec, [i for i in inputs if i is not None], int(attrs["axis"]))]


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


# --- conformance cases --------------------------------------------------------------

_ONNX_BINARY = {"add": "Add", "sub": "Sub", "mul": "Mul", "div": "Div", "min": "Min", "max": "Max",
                "prelu": "PRelu", "greater": "Greater", "less": "Less", "equal": "Equal",
                "greater_equal": "GreaterOrEqual", "less_equal": "LessOrEqual"}
_ONNX_UNARY = {name: (op, defaults) for op, (name, defaults) in _UNARY_ONNX.items()}
# Selections and sign flips: the output is one of the (rounded) inputs.
_EXACT_UNARY = ("relu", "abs", "neg", "clip")
# Each pairwise fold of a variadic Sum rounds to half storage once more.
_SUM_FP16_TOL = {"fp16": Tolerance(2e-3, 2e-3)}


def _shape_str(*shapes):
    return " ".join("x".join(map(str, s)) or "scalar" for s in shapes)


def _data(g, shape, op=""):
    return np.asarray(_draw(g, shape, op), np.float32)


def _draw(g, shape, op):
    if op in COMPARISONS or op in ("min", "max", "argmax_ties"):
        return g.integers(-3, 4, shape).astype(np.float32)  # ties and equalities
    if op == "div_den":
        return (g.uniform(0.5, 2.0, shape) * g.choice([-1, 1], shape)).astype(np.float32)
    if op == "sqrt":
        return g.uniform(0.0, 4.0, shape).astype(np.float32)
    if op == "exp":
        return g.uniform(-8.0, 8.0, shape).astype(np.float32)
    return (g.standard_normal(shape) * 2).astype(np.float32)


def binary_case(op, sa, sb):
    g = rng("binary", op, sa, sb)
    a = _data(g, sa, op)
    b = _data(g, sb, "div_den" if op == "div" else op)
    twin = node_model(_ONNX_BINARY[op], {"a": a, "b": b},
                      out_dtypes=[np.bool_] if op in COMPARISONS else None)
    return Case(op, _shape_str(sa, sb), {"a": a, "b": b}, twin,
                host_call(lambda dev, p, a, b: binary(dev, p, op, a, b)),
                exact=op in COMPARISONS or op in ("min", "max"))


def variadic_case(op, shapes):
    g = rng("variadic", op, shapes)
    xs = {f"x{i}": _data(g, s, op) for i, s in enumerate(shapes)}
    onnx_type = {"min": "Min", "max": "Max", "add": "Sum"}[op]
    return Case(onnx_type.lower(), _shape_str(*shapes), xs, node_model(onnx_type, xs),
                host_call(lambda dev, p, **xs: variadic(dev, p, op, [xs[k] for k in sorted(xs)])),
                exact=op != "add", tol=_SUM_FP16_TOL if op == "add" and len(shapes) > 2 else {})


def where_case(sc, sa, sb):
    g = rng("where", sc, sa, sb)
    ins = {"c": np.asarray(g.random(sc) < 0.5), "a": _data(g, sa), "b": _data(g, sb)}
    return Case("where", _shape_str(sc, sa, sb), ins, node_model("Where", ins),
                host_call(lambda dev, p, c, a, b: where(dev, p, c, a, b)), exact=True)


def unary_case(op, shape, alpha=None, beta=None):
    g = rng("unary", op, shape, alpha, beta)
    x = _data(g, shape, op)
    if op == "clip":
        lo = np.float32(-1.0 if alpha is None else alpha)
        hi = np.float32(1.5 if beta is None else beta)
        twin = node_model("Clip", {"x": x, "lo": lo, "hi": hi}, initializers={"lo": lo, "hi": hi})
        fn = host_call(lambda dev, p, x: clip(dev, p, x, lo, hi))
    else:
        attrs = {}
        if alpha is not None:
            attrs["alpha"] = float(alpha)
        if beta is not None:
            attrs["beta"] = float(beta)
        op_type, defaults = _ONNX_UNARY[op]
        a = float(alpha if alpha is not None else defaults.get("alpha", 0.0))
        b = float(beta if beta is not None else defaults.get("beta", 0.0))
        twin = node_model(op_type, {"x": x}, **attrs)
        fn = host_call(lambda dev, p, x: unary(dev, p, op, x, a, b))
    variant = _shape_str(shape) + "".join(f" {k}={v}" for k, v in (("alpha", alpha), ("beta", beta))
                                          if v is not None)
    return Case(op, variant, {"x": x}, twin, fn, exact=op in _EXACT_UNARY)


def concat_case(shapes, axis):
    g = rng("concat", shapes, axis)
    xs = {f"x{i}": _data(g, s) for i, s in enumerate(shapes)}
    return Case("concat", f"{_shape_str(*shapes)} axis={axis}", xs, node_model("Concat", xs, axis=axis),
                host_call(lambda dev, p, **xs: concat(dev, p, [xs[k] for k in sorted(xs)], axis)),
                exact=True)


def split_case(shape, sizes, axis):
    g = rng("split", shape, sizes, axis)
    x = _data(g, shape)
    sp = np.array(sizes, np.int64)
    twin = node_model("Split", {"x": x, "split": sp}, n_outputs=len(sizes), initializers={"split": sp},
                      axis=axis)
    return Case("split", f"{_shape_str(shape)} {list(sizes)} axis={axis}", {"x": x}, twin,
                host_call(lambda dev, p, x: split(dev, p, x, list(sizes), axis)), exact=True)


def slice_case(shape, starts, ends, axes=None, steps=None):
    g = rng("slice", shape, starts, ends, axes, steps)
    x = _data(g, shape)
    ins = {"x": x, "starts": np.array(starts, np.int64), "ends": np.array(ends, np.int64)}
    if axes is not None or steps is not None:
        ins["axes"] = np.array(axes if axes is not None else range(len(starts)), np.int64)
    if steps is not None:
        ins["steps"] = np.array(steps, np.int64)
    inits = {k: v for k, v in ins.items() if k != "x"}
    variant = f"{_shape_str(shape)} {list(starts)}:{list(ends)}" + (f" axes={list(axes)}" if axes else "") + (
        f" steps={list(steps)}" if steps else "")
    return Case("slice", variant, {"x": x}, node_model("Slice", ins, initializers=inits),
                host_call(lambda dev, p, x: slice(dev, p, x, starts, ends, axes, steps)), exact=True)


def pad_case(shape, pads, mode="constant", value=0.0, axes=None):
    g = rng("pad", shape, pads, mode, value, axes)
    x = _data(g, shape)
    ins = {"x": x, "pads": np.array(pads, np.int64)}
    if mode == "constant":
        ins["value"] = np.array(value, np.float32)
    if axes is not None:
        ins.setdefault("value", None)
        ins["axes"] = np.array(axes, np.int64)
    inits = {k: v for k, v in ins.items() if k != "x" and v is not None}
    variant = f"{_shape_str(shape)} {mode} {list(pads)}" + (f" axes={list(axes)}" if axes else "")
    return Case("pad", variant, {"x": x}, node_model("Pad", ins, initializers=inits, mode=mode),
                host_call(lambda dev, p, x: pad(dev, p, x, pads, mode, value, axes)), exact=True)


def softmax_case(shape, axis):
    x = _data(rng("softmax", shape, axis), shape) * 4
    return Case("softmax", f"{_shape_str(shape)} axis={axis}", {"x": x},
                node_model("Softmax", {"x": x}, axis=axis),
                host_call(lambda dev, p, x: softmax(dev, p, x, axis)))


def argmax_case(shape, axis, keepdims=True, last=False):
    x = _data(rng("argmax", shape, axis, keepdims, last), shape, "argmax_ties" if last else "")
    twin = node_model("ArgMax", {"x": x}, out_dtypes=[np.int64], axis=axis, keepdims=int(keepdims),
                      select_last_index=int(last))
    variant = f"{_shape_str(shape)} axis={axis}" + ("" if keepdims else " drop") + (" last" if last else "")
    return Case("argmax", variant, {"x": x}, twin,
                host_call(lambda dev, p, x: argmax(dev, p, x, axis, keepdims, last)), exact=True)


def identity_case(shape):
    x = _data(rng("identity", shape), shape)
    return Case("identity", _shape_str(shape), {"x": x}, node_model("Identity", {"x": x}),
                host_call(lambda dev, p, x: copy(dev, p, x)), exact=True)


def transpose_case(shape, perm):
    x = _data(rng("transpose", shape, perm), shape)
    return Case("transpose", f"{_shape_str(shape)} perm={list(perm)}", {"x": x},
                node_model("Transpose", {"x": x}, perm=list(perm)),
                host_call(lambda dev, p, x: transpose(dev, p, x, perm)), exact=True)


def expand_case(shape, to):
    x = _data(rng("expand", shape, to), shape)
    sh = np.array(to, np.int64)
    return Case("expand", f"{_shape_str(shape)} to {list(to)}", {"x": x},
                node_model("Expand", {"x": x, "shape": sh}, initializers={"shape": sh}),
                host_call(lambda dev, p, x: expand(dev, p, x, to)), exact=True)


def flatten_case(shape, axis):
    x = _data(rng("flatten", shape), shape)
    return Case("flatten", f"{_shape_str(shape)} axis={axis}", {"x": x},
                node_model("Flatten", {"x": x}, axis=axis),
                host_call(lambda dev, p, x: _onnx_flatten(dev, p, {"axis": axis}, [x])), exact=True)


def cases(level: str = "quick") -> list[Case]:
    if level == "tiny":
        return [
            binary_case("add", (2, 3, 5, 7), (2, 3, 5, 7)),
            binary_case("mul", (1, 3, 5, 7), ()),
            binary_case("sub", (1,), (2, 3, 4, 5)),
            binary_case("div", (2, 3, 5, 7), (1, 3, 1, 1)),
            binary_case("prelu", (1, 3, 5, 7), (3, 1, 1)),
            binary_case("min", (1, 3, 5, 7), (1, 3, 5, 7)),
            binary_case("max", (2, 1, 5, 7), (1, 3, 1, 7)),
            binary_case("greater", (1, 3, 5, 7), (1, 3, 5, 7)),
            binary_case("less", (2, 3, 5, 7), (7,)),
            binary_case("equal", (1, 3, 5, 7), (1, 3, 5, 7)),
            binary_case("greater_equal", (1, 3, 5, 7), (1, 3, 5, 1)),
            binary_case("less_equal", (1, 3, 5, 7), ()),
            where_case((1, 1, 5, 7), (1, 3, 5, 7), (1, 3, 1, 1)),
            *[unary_case(op, (1, 3, 5, 7)) for op in UNARY],
            concat_case([(1, 3, 5, 7), (1, 2, 5, 7)], 1),
            split_case((1, 5, 3, 7), [2, 3], 1),
            slice_case((2, 3, 5, 7), [0, 4, -1], [3, 0, -9], [1, 2, 3], [1, -2, -3]),
            *[pad_case((1, 2, 4, 5), [0, 0, 1, 2, 0, 0, 2, 1], mode, 0.5) for mode in PAD_MODES],
            pad_case((1, 2, 3, 21), [0, 0, 1, 3, 0, 0, 0, 2], "edge"),   # pad8's vector copies
            identity_case((2, 3, 5, 7)),
            transpose_case((2, 3, 5, 7), (0, 2, 3, 1)),
            expand_case((3, 1, 7), (2, 1, 5, 1)),
            softmax_case((2, 5, 3, 7), 1),
            argmax_case((2, 5, 3, 7), 1),
            argmax_case((2, 5, 3, 7), -1, keepdims=False, last=True),
        ]
    out = [
        binary_case("add", (2, 5, 16, 20), (2, 5, 16, 20)),
        binary_case("mul", (2, 5, 16, 20), (1, 5, 1, 1)),
        binary_case("sub", (2, 5, 16, 20), ()),
        binary_case("div", (1, 17, 31, 27), (1, 17, 31, 27)),
        binary_case("prelu", (2, 5, 16, 20), (5, 1, 1)),
        binary_case("min", (2, 5, 16, 20), (20,)),
        binary_case("max", (2, 5, 16, 20), (2, 5, 16, 20)),
        binary_case("greater", (2, 5, 16, 20), (1, 5, 1, 1)),
        binary_case("equal", (2, 5, 16, 20), (2, 5, 16, 20)),
        variadic_case("add", [(2, 5, 16, 20), (1, 5, 1, 1), (2, 5, 16, 20)]),
        variadic_case("max", [(2, 5, 16, 20)] * 3),
        where_case((2, 1, 16, 20), (2, 5, 16, 20), (1, 5, 1, 1)),
        unary_case("relu", (2, 5, 16, 20)),
        unary_case("leaky_relu", (2, 5, 16, 20), alpha=0.1),
        unary_case("sigmoid", (2, 5, 16, 20)),
        unary_case("tanh", (2, 5, 16, 20)),
        unary_case("clip", (2, 5, 16, 20), alpha=-0.5, beta=1.0),
        concat_case([(2, 5, 16, 20), (2, 3, 16, 20), (2, 1, 16, 20)], 1),
        split_case((2, 9, 16, 20), [4, 5], 1),
        slice_case((2, 5, 16, 20), [0, 1, 15], [5, 16, 0], [1, 2, 3], [2, 3, -2]),
        pad_case((2, 5, 16, 20), [0, 0, 1, 2, 0, 0, 2, 1], "constant", 0.25),
        pad_case((2, 5, 16, 20), [0, 0, 2, 3, 0, 0, 3, 2], "reflect"),
        transpose_case((2, 5, 16, 20), (0, 2, 3, 1)),
        softmax_case((2, 17, 16, 20), 1),
        argmax_case((2, 17, 16, 20), 1),
    ]
    if level != "full":
        return out
    odd = [(1, 1, 1, 1), (1, 3, 7, 13), (2, 5, 31, 27), (1, 23, 7, 13)]
    for s in odd:
        c = s[1]
        out += [binary_case("add", s, s), binary_case("sub", s, (1, c, 1, 1)),
                binary_case("mul", s, (s[3],)), binary_case("div", (1,), s),
                binary_case("max", s, ()), binary_case("min", (s[0], 1) + s[2:], (1, c, 1, 1)),
                binary_case("prelu", s, (c, 1, 1)), binary_case("less", s, s),
                where_case(s, s, ()), softmax_case(s, 1), argmax_case(s, 1, last=True),
                concat_case([s, (s[0], 2) + s[2:], (s[0], 3) + s[2:]], 1),
                pad_case(s, [0, 0, 1, 1, 0, 0, 1, 1], "edge")]
    for op in UNARY:
        out.append(unary_case(op, (2, 3, 31, 27)))
        out.append(unary_case(op, (1, 1, 1, 7)))
    out += [
        unary_case("leaky_relu", (1, 5, 7, 13), alpha=0.2),
        unary_case("elu", (1, 5, 7, 13), alpha=0.5),
        unary_case("hard_sigmoid", (1, 5, 7, 13), alpha=0.3, beta=0.4),
        unary_case("clip", (1, 5, 7, 13), alpha=1.0, beta=-1.0),  # min > max: all max
        binary_case("add", (2, 3, 4, 5, 6), (3, 4, 1, 1)),      # rank 5 that coalesces to 3
        binary_case("mul", (3, 1, 7), (1, 5, 1)),               # outer-product pattern
        binary_case("greater_equal", (2, 17, 7, 13), (2, 17, 7, 13)),
        binary_case("less_equal", (2, 17, 7, 13), (1, 17, 1, 13)),
        binary_case("equal", (23, 1), (1, 23)),
        variadic_case("add", [(1, 5, 7, 13)]),
        variadic_case("add", [(1, 5, 7, 13), (7, 13), (1,), (1, 5, 1, 1)]),
        variadic_case("min", [(1, 5, 7, 13), (5, 1, 1), (13,)]),
        variadic_case("max", [(2, 1, 7, 13), (1, 3, 7, 13)]),
        where_case((7, 13), (2, 3, 7, 13), (3, 1, 13)),
        where_case((), (1, 3, 7, 13), (1, 3, 7, 13)),
        concat_case([(2, 3, 7, 13), (2, 3, 7, 13)], 0),
        concat_case([(2, 3, 7, 13), (2, 3, 5, 13)], -2),
        concat_case([(2, 3, 7, 1), (2, 3, 7, 13), (2, 3, 7, 4)], 3),
        concat_case([(5,), (7,)], 0),
        split_case((2, 17, 7, 13), [3, 5, 9], 1),
        split_case((2, 17, 7, 13), [7], -2),
        split_case((2, 17, 7, 13), [2, 0, 11], 3),
        split_case((6,), [1, 2, 3], 0),
        slice_case((2, 17, 31, 27), [1, 3], [2, 20]),
        slice_case((2, 17, 31, 27), [-5, 2**62], [-1, -2**62], [2, -1], [2, -1]),
        slice_case((2, 17, 31, 27), [0, 30, 26], [17, -100, -100], [1, 2, 3], [3, -4, -5]),
        slice_case((2, 3, 4, 5, 6), [1, 1], [3, 5], [1, 3]),
        slice_case((7, 13), [3], [3], [0]),   # empty result
        pad_case((1, 3, 7, 13), [0, 0, 2, 3, 0, 0, 4, 1], "reflect"),
        pad_case((1, 3, 7, 13), [0, 0, 9, 20, 0, 0, 9, 20], "wrap"),
        pad_case((1, 3, 7, 13), [0, 1, -2, 3, 1, 2, 1, -4], "constant", -1.5),
        pad_case((2, 3, 7, 13), [1, 2, 3, 4], "edge", axes=[-1, 1]),
        pad_case((2, 3, 4, 5, 6), [0, 0, 0, 1, 1, 0, 0, 0, 1, 1], "constant", 2.0),
        pad_case((7, 13), [2, 3, 1, 0], "constant", 1e30),
        # pad8: 8-wide copies and fills, edges, tails (prime widths)
        pad_case((1, 5, 11, 67), [0, 0, 0, 0, 0, 0, 5, 13], "edge"),
        pad_case((1, 3, 13, 41), [0, 0, 3, 5, 0, 0, 2, 0], "constant", -2.5),
        pad_case((2, 2, 5, 37), [0, 0, 1, 11, 0, 0, 1, 3], "reflect"),
        pad_case((1, 2, 6, 29), [0, 0, 1, 3, 0, 0, 0, 19], "wrap"),
        softmax_case((2, 3, 7, 13), -1),
        softmax_case((2, 3, 7, 13), 0),
        softmax_case((1, 23, 31, 27), -3),
        softmax_case((5, 1000), 1),
        argmax_case((2, 3, 7, 13), -1, keepdims=False),
        argmax_case((2, 3, 7, 13), 0),
        argmax_case((2, 17, 7, 13), 2, last=True),
        identity_case((1, 3, 31, 27)),
        identity_case((5,)),
        transpose_case((1, 23, 7, 13), (0, 3, 1, 2)),
        transpose_case((2, 3, 7, 13), (3, 2, 1, 0)),
        transpose_case((2, 3, 5, 7, 2), (0, 1, 3, 4, 2)),   # rank 5 that coalesces to 4
        transpose_case((7, 13), (1, 0)),
        expand_case((1, 23, 1, 13), (2, 1, 7, 13)),
        expand_case((5,), ()),
        flatten_case((2, 3, 7, 13), 2),
    ]
    return out


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
selfcheck.register(selfcheck.FastPath(
    "elementwise.bcast8", "elementwise", {"BCAST_VEC": 1}, {"BCAST_VEC": 0}, check=_selfcheck_bcast,
    tolerance=DEFAULT_TOL.__getitem__,
    what="broadcasting binary ops: 8 outputs per work-item (kernel binary_bcast8)"))
