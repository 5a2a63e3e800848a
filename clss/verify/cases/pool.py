"""Conformance cases of MaxPool / AveragePool / the global pools (clss/ops/pool.py,
kernels/pool.cl): ONNX twins and seeded cases, `cases(level)` for `clss verify` and the
tests."""
from __future__ import annotations

import numpy as np

from ...ops.base import rng
from ...ops.pool import _per_dim, avg_pool, global_avg_pool, global_max_pool, max_pool
from ...tolerance import Tolerance
from ..case import Case, host_call
from ..twin import node_model

# GlobalAveragePool is a long reduction and onnxruntime, the reference, sums in
# another order. Measured against a float64 mean (tests/test_ops_pool.py): clss
# stays within 3e-6*max|ref| up to 3840x2160, onnxruntime drifts to 2.5e-5 at
# 1920x1080 on zero-mean data; the fp32 bound covers the larger of the two.
GLOBAL_AVG_TOL = {"fp32": Tolerance(5e-5, 1e-4)}

def _attrs_for_twin(kernel, stride, pads, dilation, ceil_mode, auto_pad, nd):
    a = dict(kernel_shape=_per_dim(kernel, nd, 1, "kernel"))
    if stride is not None:
        a["strides"] = _per_dim(stride, nd, 1, "stride")
    if dilation is not None:
        a["dilations"] = _per_dim(dilation, nd, 1, "dilation")
    if auto_pad != "NOTSET":
        a["auto_pad"] = auto_pad
    elif pads is not None:
        a["pads"] = [int(pads)] * (2 * nd) if isinstance(pads, int) else list(pads)
    if ceil_mode:
        a["ceil_mode"] = 1
    return a


def max_pool_case(shape, kernel, stride=None, pads=None, dilation=None, ceil_mode=False,
                  auto_pad="NOTSET", indices=False, tag=""):
    g = rng("maxpool", shape, kernel, stride, pads, dilation, ceil_mode, auto_pad, indices)
    x = g.standard_normal(shape).astype(np.float32)
    nd = len(shape) - 2
    twin = node_model("MaxPool", {"x": x}, n_outputs=2 if indices else 1,
                      out_dtypes=[np.float32, np.int64] if indices else None,
                      **_attrs_for_twin(kernel, stride, pads, dilation, ceil_mode, auto_pad, nd))

    def fn(dev, p, x):
        r = max_pool(dev, p, x, kernel, stride, pads, dilation, ceil_mode, auto_pad, return_indices=indices)
        return list(r) if indices else r
    variant = tag or _variant(shape, kernel, stride, pads, dilation, ceil_mode, auto_pad)
    return Case("max_pool", variant + (" +indices" if indices else ""), {"x": x}, twin, host_call(fn),
                exact=True)


def avg_pool_case(shape, kernel, stride=None, pads=None, dilation=None, ceil_mode=False,
                  count_include_pad=False, auto_pad="NOTSET", tag=""):
    g = rng("avgpool", shape, kernel, stride, pads, dilation, ceil_mode, count_include_pad, auto_pad)
    x = g.standard_normal(shape).astype(np.float32)
    nd = len(shape) - 2
    attrs = _attrs_for_twin(kernel, stride, pads, dilation, ceil_mode, auto_pad, nd)
    if count_include_pad:
        attrs["count_include_pad"] = 1
    # AveragePool gained dilations in opset 19.
    twin = node_model("AveragePool", {"x": x}, opset=19 if dilation is not None else 18, **attrs)
    fn = host_call(lambda dev, p, x: avg_pool(dev, p, x, kernel, stride, pads, dilation, ceil_mode,
                                              count_include_pad, auto_pad))
    variant = tag or _variant(shape, kernel, stride, pads, dilation, ceil_mode, auto_pad)
    return Case("avg_pool", variant + (" cip" if count_include_pad else ""), {"x": x}, twin, fn)


def global_case(kind: str, shape, chunk=None):
    g = rng("global", kind, shape, chunk)
    # Post-activation-like data (mostly positive) keeps the mean away from zero,
    # where a relative bound would measure cancellation instead of the kernel.
    x = (g.standard_normal(shape) + 0.5).astype(np.float32)
    op = "GlobalAveragePool" if kind == "avg" else "GlobalMaxPool"
    fn = global_avg_pool if kind == "avg" else global_max_pool
    variant = "x".join(map(str, shape)) + (f" chunk{chunk}" if chunk else "")
    return Case(f"global_{kind}_pool", variant, {"x": x}, node_model(op, {"x": x}),
                host_call(lambda dev, p, x: fn(dev, p, x, chunk=chunk)),
                exact=kind == "max", tol=GLOBAL_AVG_TOL if kind == "avg" else {})


def _variant(shape, kernel, stride, pads, dilation, ceil_mode, auto_pad):
    parts = ["x".join(map(str, shape)), f"k{kernel}"]
    if stride is not None:
        parts.append(f"s{stride}")
    if pads is not None and auto_pad == "NOTSET":
        parts.append(f"p{pads}")
    if dilation is not None:
        parts.append(f"d{dilation}")
    if ceil_mode:
        parts.append("ceil")
    if auto_pad != "NOTSET":
        parts.append(auto_pad)
    return " ".join(p.replace(" ", "") for p in parts)


def cases(level: str = "quick") -> list[Case]:
    if level == "tiny":
        return [
            max_pool_case((1, 3, 7, 9), 2, 2),
            max_pool_case((1, 2, 5, 27), 3, 1, 1),                  # max_pool_row8: inside, edges, tail
            max_pool_case((1, 2, 7, 9), (3, 3), (2, 2), (1, 0, 1, 2), (2, 1), ceil_mode=True, indices=True),
            avg_pool_case((1, 3, 7, 9), 3, 2, (1, 1, 2, 0)),
            avg_pool_case((1, 2, 7, 9), 3, 2, 1, ceil_mode=True, count_include_pad=True),
            global_case("avg", (1, 3, 5, 7)),
            global_case("avg", (1, 2, 9, 13), chunk=32),
            global_case("max", (1, 3, 5, 7)),
            global_case("max", (1, 2, 9, 13), chunk=32),
        ]
    out = [
        max_pool_case((2, 5, 16, 20), 2, 2),
        max_pool_case((1, 3, 13, 7), 3, 1, 1),
        max_pool_case((1, 3, 13, 7), 3, 2, (0, 1, 2, 1), ceil_mode=True, indices=True),
        avg_pool_case((2, 5, 16, 20), 2, 2),
        avg_pool_case((1, 3, 13, 7), 3, 2, (1, 1, 2, 0), count_include_pad=True),
        avg_pool_case((1, 3, 13, 7), 3, 2, 1, ceil_mode=True),
        global_case("avg", (2, 5, 16, 20)),
        global_case("avg", (1, 3, 64, 72)),
        global_case("max", (2, 5, 16, 20)),
        global_case("max", (1, 3, 64, 72)),
    ]
    if level != "full":
        return out
    for shape in [(1, 1, 1, 1), (1, 3, 7, 13), (2, 17, 31, 27), (1, 23, 8, 8)]:
        kmax = min(3, shape[2] + 2)
        out += [max_pool_case(shape, (kmax, 2), (2, 1), 1),
                avg_pool_case(shape, (kmax, 2), (2, 1), 1),
                avg_pool_case(shape, (kmax, 2), (2, 1), 1, count_include_pad=True),
                global_case("avg", shape), global_case("max", shape)]
    out += [
        max_pool_case((1, 5, 31, 27), 3, 2, (1, 0, 0, 1), dilation=2),
        max_pool_case((1, 5, 31, 27), 3, 2, dilation=(2, 3), ceil_mode=True),
        max_pool_case((2, 3, 7, 13), (2, 3), (3, 2), auto_pad="SAME_UPPER"),
        # max_pool_row8 (3 wide, unit stride along x): inside blocks, edges, tails
        max_pool_case((1, 3, 13, 71), 3, 1, 1),
        max_pool_case((2, 2, 11, 37), (5, 3), (2, 1), (2, 0, 1, 2), dilation=(2, 1)),
        max_pool_case((1, 2, 9, 19), 3, 1, (0, 0, 1, 1), ceil_mode=True),
        # POOL_ROWS: 4 output rows per work-item, a 5-row window, uneven pads, 10 % 4 rows
        max_pool_case((1, 2, 10, 23), (5, 3), 1, (2, 1, 1, 1)),
        max_pool_case((2, 3, 7, 13), (2, 3), (3, 2), auto_pad="SAME_LOWER"),
        max_pool_case((2, 3, 7, 13), (2, 3), (3, 2), auto_pad="VALID"),
        max_pool_case((2, 3, 7, 13), 3, 2, 1, indices=True),
        max_pool_case((2, 3, 31), 3, 2, (1, 0)),
        max_pool_case((1, 2, 5, 7, 6), 2, 2, ceil_mode=True),
        avg_pool_case((1, 5, 31, 27), 3, 2, (1, 0, 0, 1), dilation=2),
        avg_pool_case((1, 5, 31, 27), 3, 2, (1, 0, 0, 1), dilation=2, count_include_pad=True),
        avg_pool_case((2, 3, 7, 13), (2, 3), (3, 2), auto_pad="SAME_UPPER"),
        avg_pool_case((2, 3, 7, 13), (2, 3), (3, 2), auto_pad="SAME_LOWER", count_include_pad=True),
        avg_pool_case((2, 3, 7, 13), (2, 3), (3, 2), auto_pad="VALID"),
        avg_pool_case((1, 3, 10, 10), 3, 3, 1, ceil_mode=True, count_include_pad=True),
        avg_pool_case((1, 3, 11, 11), 4, 3, 2, ceil_mode=True, count_include_pad=True),
        avg_pool_case((2, 3, 31), 3, 2, (1, 0), count_include_pad=True),
        avg_pool_case((1, 2, 5, 7, 6), 2, 2, 1, count_include_pad=True),
        global_case("avg", (1, 2, 128, 128)),
        global_case("avg", (1, 3, 45, 45), chunk=64),
        global_case("avg", (2, 1, 3, 3000)),
        global_case("max", (1, 3, 45, 45), chunk=64),
        global_case("max", (2, 2, 3, 4, 5)),
    ]
    return out
