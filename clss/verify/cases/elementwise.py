"""Conformance cases of the elementwise, data-movement and per-row reduction ops
(clss/ops/elementwise.py, kernels/elementwise.cl): ONNX twins and seeded cases,
`cases(level)` for `clss verify` and the tests."""
from __future__ import annotations

import numpy as np

from ...ops.base import rng
from ...ops.elementwise import (COMPARISONS, PAD_MODES, UNARY, _UNARY_ONNX, _onnx_flatten, argmax,
                                binary, clip, clip_tensors, concat, copy, expand, gather, pad, softmax,
                                split, tile, transpose, unary, variadic, where)
from ...ops.elementwise import slice as slice_  # (ONNX's name; not the builtin)
from ...tolerance import Tolerance
from ..case import Case, host_call
from ..twin import node_model


_ONNX_BINARY = {"add": "Add", "sub": "Sub", "mul": "Mul", "div": "Div", "min": "Min", "max": "Max",
                "prelu": "PRelu", "greater": "Greater", "less": "Less", "equal": "Equal",
                "greater_equal": "GreaterOrEqual", "less_equal": "LessOrEqual", "pow": "Pow"}
_ONNX_UNARY = {name: (op, defaults) for op, (name, defaults) in _UNARY_ONNX.items()}
# Gelu (opset 20) has a handler of its own: its two forms are one unary op each.
_ONNX_UNARY.update({"gelu": ("Gelu", {}), "gelu_tanh": ("Gelu", {})})
_OPSET = {"Gelu": 20, "Mish": 18}
# Selections, sign flips and roundings: the output is one of the (rounded) inputs, or an integer.
_EXACT_UNARY = ("relu", "abs", "neg", "clip", "floor", "ceil", "round", "sign")
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
    if op in ("sqrt", "pow_base"):
        return g.uniform(0.0, 4.0, shape).astype(np.float32)
    if op == "log":
        return g.uniform(0.05, 8.0, shape).astype(np.float32)
    if op == "reciprocal":
        return (g.uniform(0.25, 4.0, shape) * g.choice([-1, 1], shape)).astype(np.float32)
    if op == "pow_exp":
        return g.uniform(-2.0, 3.0, shape).astype(np.float32)
    if op == "exp":
        return g.uniform(-8.0, 8.0, shape).astype(np.float32)
    return (g.standard_normal(shape) * 2).astype(np.float32)


def binary_case(op, sa, sb):
    g = rng("binary", op, sa, sb)
    a = _data(g, sa, "pow_base" if op == "pow" else op)
    b = _data(g, sb, {"div": "div_den", "pow": "pow_exp"}.get(op, op))
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
        b = float(beta if beta is not None else defaults.get("gamma", defaults.get("beta", 0.0)))
        if op == "gelu_tanh":
            attrs["approximate"] = "tanh"
        if op_type in _OPSET:
            attrs["opset"] = _OPSET[op_type]
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
                host_call(lambda dev, p, x: slice_(dev, p, x, starts, ends, axes, steps)), exact=True)


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


def clip_tensors_case(shape, lo, hi):
    """Clip with its bounds as graph inputs (run-time tensors), either side open."""
    g = rng("clip tensors", shape, lo, hi)
    ins = {"x": _data(g, shape)}
    if lo is not None:
        ins["lo"] = np.array(lo, np.float32)
    if hi is not None:
        ins["hi"] = np.array(hi, np.float32)
    node_ins = {"x": ins["x"], "lo": ins.get("lo"), "hi": ins.get("hi")}
    if hi is None:
        del node_ins["hi"]
    return Case("clip_tensors", f"{_shape_str(shape)} [{lo}, {hi}]", ins, node_model("Clip", node_ins),
                host_call(lambda dev, p, x, lo=None, hi=None: clip_tensors(dev, p, x, lo, hi)), exact=True)


def log_softmax_case(shape, axis):
    x = _data(rng("log_softmax", shape, axis), shape) * 4
    return Case("log_softmax", f"{_shape_str(shape)} axis={axis}", {"x": x},
                node_model("LogSoftmax", {"x": x}, axis=axis),
                host_call(lambda dev, p, x: softmax(dev, p, x, axis, log=True)))


def gather_case(shape, indices, axis):
    x = _data(rng("gather", shape, axis), shape)
    idx = np.array(indices, np.int64)
    return Case("gather", f"{_shape_str(shape)} {idx.tolist()} axis={axis}", {"x": x},
                node_model("Gather", {"x": x, "i": idx}, initializers={"i": idx}, axis=axis),
                host_call(lambda dev, p, x: gather(dev, p, x, idx, axis)), exact=True)


def tile_case(shape, reps):
    x = _data(rng("tile", shape, reps), shape)
    r = np.array(reps, np.int64)
    return Case("tile", f"{_shape_str(shape)} x{list(reps)}", {"x": x},
                node_model("Tile", {"x": x, "r": r}, initializers={"r": r}),
                host_call(lambda dev, p, x: tile(dev, p, x, reps)), exact=True)


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
            binary_case("pow", (1, 3, 5, 7), (1, 3, 1, 7)),
            clip_tensors_case((1, 3, 5, 7), -0.5, 0.75),
            log_softmax_case((2, 5, 3, 7), 1),
            softmax_case((3, 21), -1),          # softmax_rows: two blocks of 8 and a tail
            log_softmax_case((3, 21), -1),
            gather_case((2, 5, 3, 7), [3, 0, -1], 1),
            tile_case((1, 3, 2, 5), (2, 1, 3, 1)),
            transpose_case((2, 3, 2, 5, 3), (2, 0, 3, 1, 4)),   # five runs: gather8
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
        binary_case("pow", (2, 5, 16, 20), ()),
        clip_tensors_case((2, 5, 16, 20), -0.5, 1.0),
        log_softmax_case((2, 17, 16, 20), -1),
        gather_case((2, 17, 16, 20), 4, 1),
        tile_case((1, 5, 16, 20), (1, 2, 1, 2)),
        transpose_case((2, 5, 3, 4, 6), (2, 0, 3, 1, 4)),
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
        binary_case("pow", (1, 23, 7, 13), (1, 23, 7, 13)),
        binary_case("pow", (2, 3, 7, 13), (13,)),
        clip_tensors_case((1, 3, 7, 13), None, 0.5),
        clip_tensors_case((1, 3, 7, 13), -0.25, None),
        clip_tensors_case((1, 3, 7, 13), 1.0, -1.0),   # min > max: all max
        log_softmax_case((2, 3, 7, 13), 0),
        log_softmax_case((5, 1000), 1),
        gather_case((2, 3, 7, 13), -1, 0),
        gather_case((2, 3, 7, 13), [[1, -1], [0, 5]], 3),
        gather_case((7, 13), [6, 0, 6], 0),
        tile_case((2, 3, 7, 13), (2, 3, 1, 2)),
        tile_case((5,), (3,)),
        transpose_case((2, 3, 4, 5, 6, 7), (0, 1, 3, 2, 4, 5)),
        transpose_case((2, 3, 5, 7, 3, 2), (5, 3, 1, 4, 2, 0)),   # six runs
    ]
    return out
