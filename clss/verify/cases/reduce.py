"""Conformance cases of the Reduce* family (clss/ops/reduce.py, kernels/reduce.cl): every
reduction over leading, trailing, inner and non-adjacent axes, keepdims or not, the
spatial mean of channel attention, empty reductions; axes as an input (opset 18)."""
from __future__ import annotations

import numpy as np

from ...ops.base import rng
from ...ops.reduce import ONNX_OPS, reduce
from ...tolerance import Tolerance
from ..case import Case, host_call
from ..twin import node_model

_OP_TYPE = {name: op for op, name in ONNX_OPS.items()}
# Prod multiplies every element: keep them near 1 so that the product stays in range.
_SELECTS = ("max", "min")
# Half storage rounds the one output; sums of thousands of terms accumulate in float.
_FP16_TOL = {"fp16": Tolerance(2e-3, 2e-3)}


def _data(g, shape, op):
    if op == "prod":
        return g.uniform(0.8, 1.25, shape).astype(np.float32)
    if op == "logsum":
        return g.uniform(0.1, 2.0, shape).astype(np.float32)
    return (g.standard_normal(shape) * 2).astype(np.float32)


def reduce_case(op, shape, axes, keepdims=True):
    g = rng("reduce", op, shape, axes, keepdims)
    x = _data(g, shape, op)
    ins = {"x": x}
    inits = {}
    if axes is not None:
        ins["axes"] = inits["axes"] = np.array(axes, np.int64)
    twin = node_model(_OP_TYPE[op], ins, initializers=inits, opset=18, keepdims=int(keepdims))
    variant = f"{'x'.join(map(str, shape))} axes={axes}" + ("" if keepdims else " drop")
    return Case(f"reduce_{op}", variant, {"x": x}, twin,
                host_call(lambda dev, p, x: reduce(dev, p, op, x, axes, keepdims)),
                exact=op in _SELECTS, tol=_FP16_TOL)


def cases(level: str = "quick") -> list[Case]:
    ops = list(_OP_TYPE)
    if level == "tiny":
        return [reduce_case(op, (2, 3, 5, 7), [2, 3]) for op in ops] + [
            reduce_case("sum", (2, 3, 5, 7), [1], keepdims=False),
            reduce_case("max", (2, 3, 5, 7), [0, 2]),
            reduce_case("mean", (2, 3, 5, 7), None, keepdims=False),
            reduce_case("max", (2, 3, 1, 11), [1]),   # reduce8: a block of 8 outputs and a tail
        ]
    out = [reduce_case(op, (2, 5, 16, 20), [-2, -1]) for op in ops]
    out += [reduce_case("mean", (2, 17, 16, 20), [1], keepdims=False),
            reduce_case("sum", (3, 64, 20), [-1]),
            reduce_case("max", (2, 5, 16, 20), [0, 2])]
    if level != "full":
        return out
    for op in ops:
        out += [reduce_case(op, (1, 23, 7, 13), [1]),
                reduce_case(op, (2, 3, 31, 27), [0, 3], keepdims=False),
                reduce_case(op, (1, 1, 1, 1), None)]
    out += [
        reduce_case("mean", (1, 7, 67, 131), [2, 3]),        # channel attention's spatial mean
        reduce_case("mean", (2, 3, 4, 5, 6, 7), [1, 3, 5]),  # three separated axes
        reduce_case("sum", (2, 3, 4, 5, 6, 7), [0, 1, 2, 3, 4], keepdims=False),
        reduce_case("l2", (5, 1000), [1]),
        reduce_case("logsumexp", (2, 17, 7, 13), [1]),
        reduce_case("sum", (2, 0, 5), [1]),                  # empty reduction: identities
        reduce_case("max", (2, 0, 5), [1], keepdims=False),
        reduce_case("prod", (3, 0), [1]),
        reduce_case("sum", (2, 3, 5), [], keepdims=True),    # empty axes: reduce everything
    ]
    return out
