"""Matrix products of run-time tensors (kernels/matmul.cl): ONNX MatMul with batch
broadcasting and Gemm with alpha, beta, transA, transB and a broadcast C.

clss.Model lowers a MatMul or Gemm whose B is constant (a linear layer) to a 1x1
convolution, and a MatMul of two run-time tensors with equal or single batches to a
grouped one (clss/model/passes.py): those keep the conv family's fast paths. What the
lowering leaves comes here: a Gemm with a run-time B, batch dimensions that broadcast
against each other, 1-D operands. Operands are read through strides: a transposed or
broadcast operand is never copied."""
from __future__ import annotations

import numpy as np

from .. import selfcheck
from ..device import Device
from ..tolerance import DEFAULT_TOL
from .base import Unsupported, unsupported_on_value_error, check_storage, onnx_op, rng
from .conv import builtin_free
from .elementwise import _broadcast_strides, _contiguous_strides, coalesce

# (TM, TN) per kernel: rows and columns of the output per work-item (matmul_n8: TM rows of
# 8 columns). Measured on a 2-core Zen 3 with pip's PoCL (4096x256 @ 256x512, transB): the
# k8 kernel 86 ms at 4 x 4 (its 16 float8 sums spill), 64 at 4 x 2.
TILES = {"matmul": (4, 4), "matmul_n8": (4, 1), "matmul_k8": (4, 2)}
# The vector kernels: matmul_n8 (B's columns contiguous: 8 of them per load) and matmul_k8
# (A's rows and B's columns contiguous along k: dot products of 8-wide loads); 0 selects
# the reference kernel `matmul` (scalar loads through strides) for every product.
MATMUL_VEC = 1
FAST = "matmul.vectors"
BUILD_VARIANTS = [dict(HAS_C=c) for c in (0, 1)]   # each builds matmul, matmul_n8 and matmul_k8


def _batch2(batch, sa, sb):
    """Coalesce the batch dims to at most two, with A's and B's strides along them."""
    dims, (ta, tb) = coalesce(batch, [sa, sb])
    if len(dims) > 2:
        raise ValueError(f"matmul: {len(dims)} batch dimensions after merging neighbours; the kernel takes 2")
    k = 2 - len(dims)
    return [1] * k + dims, [0] * k + ta, [0] * k + tb


def _batch_strides(shape, batch) -> list[int]:
    """An operand's element strides along the broadcast batch dims (0 where it broadcasts)."""
    full = (1,) * (len(batch) + 2 - len(shape)) + tuple(shape)
    st = _contiguous_strides(full)
    return [0 if full[i] == 1 else st[i] for i in range(len(batch))]


def _launch(dev, prec, a, b, c, out, M, N, K, B, sa, sb, sc, alpha, beta):
    if out.size == 0:
        return out
    if K == 0:   # an empty sum: zeros (plus beta * C)
        sa, sb, K = [0] * 4, [0] * 4, 0
    name = "matmul"
    if MATMUL_VEC and K > 0 and selfcheck.enabled(dev, prec, FAST):
        if sb[3] == 1 and N >= 8:
            name = "matmul_n8"
        elif sa[3] == 1 and sb[2] == 1 and K >= 8:
            name = "matmul_k8"
    tm, tn = TILES[name]
    extra = {} if name == "matmul" else {"CLSS_CLANG_VECTORS": builtin_free(dev)}
    k = dev.kernel("matmul", name, prec, TM=tm, TN=tn, HAS_C=int(c is not None), **extra)
    if name == "matmul_n8":
        tn = 8    # columns per work-item
    i32, i64 = np.int32, np.int64
    dev.launch(k, (-(-N // tn), -(-M // tm), B[0] * B[1]),
               (a.data, b.data, (c if c is not None else a).data, out.data, i32(M), i32(N), i32(K),
                i32(B[1]), *map(i64, sa), *map(i64, sb), *map(i64, sc), np.float32(alpha),
                np.float32(beta)))
    return out


def matmul(dev: Device, prec: str, a, b, out=None):
    """numpy.matmul semantics (ONNX MatMul): 1-D operands promoted and the added axis
    dropped, batch dimensions broadcast."""
    check_storage("a", a, prec)
    check_storage("b", b, prec)
    sa_shape = (1,) + tuple(a.shape) if a.ndim == 1 else tuple(a.shape)
    sb_shape = tuple(b.shape) + (1,) if b.ndim == 1 else tuple(b.shape)
    if a.ndim == 0 or b.ndim == 0:
        raise ValueError("matmul of a scalar")
    M, K = sa_shape[-2:]
    K2, N = sb_shape[-2:]
    if K != K2:
        raise ValueError(f"matmul: inner sizes differ, {tuple(a.shape)} @ {tuple(b.shape)}")
    batch = tuple(np.broadcast_shapes(sa_shape[:-2], sb_shape[:-2]))
    shape = batch + (M, N)
    if a.ndim == 1:
        shape = shape[:-2] + (N,)
    if b.ndim == 1:
        shape = shape[:-1]
    out = out if out is not None else dev.empty(shape, prec)
    st_a, st_b = _contiguous_strides(sa_shape), _contiguous_strides(sb_shape)
    ba, bb = _batch_strides(sa_shape, batch), _batch_strides(sb_shape, batch)
    B, ta, tb = _batch2(list(batch), ba, bb) if batch else ([1, 1], [0, 0], [0, 0])
    return _launch(dev, prec, a, b, None, out, M, N, K, B, ta + [st_a[-2], st_a[-1]],
                   tb + [st_b[-2], st_b[-1]], [0, 0], 1.0, 0.0)


def gemm(dev: Device, prec: str, a, b, c=None, alpha: float = 1.0, beta: float = 1.0,
         trans_a: bool = False, trans_b: bool = False, out=None):
    """ONNX Gemm: alpha * A' B' + beta * C, A' = A^T with trans_a (likewise B), C
    broadcast to [M, N]."""
    check_storage("a", a, prec)
    check_storage("b", b, prec)
    if a.ndim != 2 or b.ndim != 2:
        raise ValueError(f"Gemm takes 2-D A and B, got {tuple(a.shape)} and {tuple(b.shape)}")
    M, K = (a.shape[1], a.shape[0]) if trans_a else tuple(a.shape)
    K2, N = (b.shape[1], b.shape[0]) if trans_b else tuple(b.shape)
    if K != K2:
        raise ValueError(f"Gemm: inner sizes differ ({K} and {K2})")
    sa = [a.shape[1], 1][::-1] if trans_a else [a.shape[1], 1]
    sb = [b.shape[1], 1][::-1] if trans_b else [b.shape[1], 1]
    sc = [0, 0]
    if c is not None:
        check_storage("c", c, prec)
        try:
            ok = np.broadcast_shapes(tuple(c.shape), (M, N)) == (M, N)
        except ValueError:
            ok = False
        if not ok:
            raise ValueError(f"Gemm: C of shape {tuple(c.shape)} does not broadcast to {(M, N)}")
        sc = _broadcast_strides(tuple(c.shape), (M, N))
    out = out if out is not None else dev.empty((M, N), prec)
    return _launch(dev, prec, a, b, c, out, int(M), int(N), int(K), [1, 1], [0, 0] + sa, [0, 0] + sb, sc,
                   alpha, beta)


# --- ONNX -----------------------------------------------------------------------------

_unsupported = unsupported_on_value_error


@onnx_op("MatMul")
def _onnx_matmul(dev, prec, attrs, inputs):
    return [_unsupported(matmul, dev, prec, inputs[0], inputs[1])]


@onnx_op("Gemm")
def _onnx_gemm(dev, prec, attrs, inputs):
    c = inputs[2] if len(inputs) > 2 else None
    return [_unsupported(gemm, dev, prec, inputs[0], inputs[1], c, float(attrs.get("alpha", 1.0)),
                         float(attrs.get("beta", 1.0)), bool(attrs.get("transA", 0)),
                         bool(attrs.get("transB", 0)))]


# --- fast path (clss/selfcheck.py): the vector kernels against `matmul` ------------------

def _selfcheck(dev: Device, prec: str) -> list[np.ndarray]:
    """A product with contiguous B columns and ragged N (21: two blocks of 8 and a tail), one
    read as dot products (Gemm with transB, K = 19: two 8-wide steps and a tail), with C."""
    g = rng("matmul selfcheck")
    up = lambda *s: dev.to_device(g.standard_normal(s).astype(np.float32), prec)   # noqa: E731
    a, b, bt, c = up(2, 7, 19), up(2, 19, 21), up(21, 19), up(21)
    return [dev.to_host(matmul(dev, prec, a, b)),
            dev.to_host(gemm(dev, prec, up(7, 19), bt, c, 0.5, 2.0, False, True))]


selfcheck.register(selfcheck.FastPath(
    FAST, "matmul", {"MATMUL_VEC": 1, "CLSS_CLANG_VECTORS": 1}, {"MATMUL_VEC": 0}, check=_selfcheck,
    tolerance=DEFAULT_TOL.__getitem__,
    what="products on 8-wide loads: 8 contiguous columns of B per load (matmul_n8) or dot products "
         "along k (matmul_k8) / scalar loads through strides (kernel matmul)"))
