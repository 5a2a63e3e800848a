"""Conformance cases of the run-time matrix products (clss/ops/matmul.py,
kernels/matmul.cl): MatMul with broadcasting batches and 1-D operands, attention's
Q K^T and softmax(.) V shapes, Gemm with transposes, alpha, beta and a broadcast C."""
from __future__ import annotations

import numpy as np

from ...ops.base import rng
from ...ops.matmul import gemm, matmul
from ..case import Case, host_call
from ..twin import node_model


def matmul_case(sa, sb):
    g = rng("matmul", sa, sb)
    ins = {"a": g.standard_normal(sa).astype(np.float32), "b": g.standard_normal(sb).astype(np.float32)}
    return Case("matmul", f"{'x'.join(map(str, sa))} @ {'x'.join(map(str, sb))}", ins,
                node_model("MatMul", ins), host_call(lambda dev, p, a, b: matmul(dev, p, a, b)))


def gemm_case(m, k, n, trans_a=False, trans_b=False, c_shape=(), alpha=1.0, beta=1.0):
    g = rng("gemm", m, k, n, trans_a, trans_b, c_shape, alpha, beta)
    ins = {"a": g.standard_normal((k, m) if trans_a else (m, k)).astype(np.float32),
           "b": g.standard_normal((n, k) if trans_b else (k, n)).astype(np.float32)}
    if c_shape is not None:
        ins["c"] = g.standard_normal(c_shape).astype(np.float32)
    twin = node_model("Gemm", ins, alpha=alpha, beta=beta, transA=int(trans_a), transB=int(trans_b))
    variant = f"{m}x{k}x{n}" + (" A^T" if trans_a else "") + (" B^T" if trans_b else "") + (
        f" C {list(c_shape)}" if c_shape is not None else " no C") + f" alpha={alpha} beta={beta}"
    return Case("gemm", variant, ins, twin,
                host_call(lambda dev, p, a, b, c=None: gemm(dev, p, a, b, c, alpha, beta, trans_a, trans_b)))


def cases(level: str = "quick") -> list[Case]:
    if level == "tiny":
        # (the last two reach the fast path's kernels: 8 contiguous columns and a tail,
        # dot products along k of two 8-wide steps and a tail)
        return [matmul_case((2, 3, 5, 7), (1, 3, 7, 6)), matmul_case((5, 7), (7,)),
                gemm_case(5, 7, 6, True, True, (6,), 0.5, 2.0),
                matmul_case((2, 1, 3, 5), (1, 2, 5, 11)), gemm_case(3, 19, 5, False, True, (5,), 1.0, 0.5)]
    out = [matmul_case((2, 4, 64, 16), (2, 4, 16, 64)),     # attention Q K^T: 4 heads, 64 tokens
           matmul_case((2, 4, 64, 64), (2, 4, 64, 16)),     # softmax(.) V
           matmul_case((3, 1, 17, 9), (1, 5, 9, 11)),        # batches broadcast both ways
           gemm_case(32, 48, 40, False, True, (40,))]
    if level != "full":
        return out
    out += [
        matmul_case((7,), (7, 13)),
        matmul_case((7,), (3, 7, 2)),
        matmul_case((1, 1), (1, 1)),
        matmul_case((23, 31), (31, 29)),
        matmul_case((2, 3, 4, 5, 6), (6, 7)),
        gemm_case(13, 17, 11),
        gemm_case(13, 17, 11, True, False, (13, 1), 1.5, 0.5),
        gemm_case(13, 17, 11, False, False, (13, 11), 1.0, -1.0),
        gemm_case(13, 17, 11, True, True, None, 2.0, 1.0),
        gemm_case(5, 0, 4, c_shape=(4,)),
    ]
    return out
