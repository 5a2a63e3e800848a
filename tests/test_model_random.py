"""Randomly generated ONNX graphs through clss.Model against onnxruntime
(hypothesis, derandomized so the set of kernel variants compiled is stable):
single ops with random attributes, and multi-op graphs (conv stacks with
activations, residual adds, skip concatenations, pooling and upsampling,
pixel (un)shuffles, channel attention), fp32 and fp16, odd sizes and channel
counts, with and without shapes on the graph outputs. In fp16 the reference
is onnxruntime on fp16-rounded inputs and weights (what the engine stores)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from onnx import helper

from clss.tolerance import Tolerance
from helpers import CHAIN_TOL, SETTINGS, check_graph

TOL = {"fp32": Tolerance(1e-5, 1e-4), "fp16": Tolerance(1e-3, 1e-3)}
# Chains store every intermediate in fp16: one rounding per op compounds.
CHANNELS = st.sampled_from([1, 2, 3, 5, 7, 8, 13])
SIDE = st.integers(1, 11)


# --- single ops ---------------------------------------------------------------------------

@st.composite
def single_op(draw):
    g = np.random.default_rng(draw(st.integers(0, 2**16)))
    n = draw(st.sampled_from([1, 1, 2]))
    c = draw(CHANNELS)
    h, w = draw(SIDE), draw(SIDE)
    x = g.standard_normal((n, c, h, w)).astype(np.float32)
    feeds, inits = {"x": x}, {}
    op = draw(st.sampled_from(["Conv", "Conv", "Conv", "ConvTranspose", "act", "binary", "MaxPool",
                               "AveragePool", "GlobalAveragePool", "Resize", "Concat", "Slice", "Pad",
                               "Softmax", "DepthToSpace", "SpaceToDepth", "MatMul", "Gemm", "GridSample"]))
    if op == "Conv":
        k = draw(st.sampled_from([1, 3]))
        s = draw(st.sampled_from([1, 2]))
        d = draw(st.sampled_from([1, 1, 2]))
        p = draw(st.integers(0, k // 2 * d))
        groups = [gr for gr in (1, c) if c % gr == 0]
        grp = draw(st.sampled_from(groups))
        cout = grp * draw(st.sampled_from([1, 2, 3, 5]))
        hh, ww = max(h, (k - 1) * d + 1 - 2 * p), max(w, (k - 1) * d + 1 - 2 * p)
        x = g.standard_normal((n, c, hh, ww)).astype(np.float32)
        feeds = {"x": x}
        inits = {"w": (g.standard_normal((cout, c // grp, k, k)) / np.sqrt(c // grp * k * k)).astype(np.float32)}
        ins = ["x", "w"]
        if draw(st.booleans()):
            inits["b"] = g.standard_normal(cout).astype(np.float32) * 0.1
            ins.append("b")
        nodes = [helper.make_node("Conv", ins, ["c"], kernel_shape=[k, k], strides=[s, s], dilations=[d, d],
                                  pads=[p] * 4, group=grp)]
        act = draw(st.sampled_from([None, "Relu", "LeakyRelu", "Sigmoid", "Tanh"]))
        if act:
            nodes.append(helper.make_node(act, ["c"], ["y"]))
        else:
            nodes[0].output[0] = "y"
    elif op == "ConvTranspose":
        k = draw(st.sampled_from([2, 3]))
        s = draw(st.sampled_from([1, 2]))
        p = draw(st.integers(0, k - 1))
        op_ = draw(st.integers(0, s - 1))
        cout = draw(CHANNELS)
        inits = {"w": (g.standard_normal((c, cout, k, k)) / np.sqrt(c * k * k)).astype(np.float32),
                 "b": g.standard_normal(cout).astype(np.float32) * 0.1}
        hh, ww = h + 2, w + 2
        x = g.standard_normal((n, c, hh, ww)).astype(np.float32)
        feeds = {"x": x}
        nodes = [helper.make_node("ConvTranspose", ["x", "w", "b"], ["y"], kernel_shape=[k, k], strides=[s, s],
                                  pads=[p] * 4, output_padding=[op_, op_])]
    elif op == "act":
        a = draw(st.sampled_from(["Relu", "LeakyRelu", "Sigmoid", "Tanh", "Clip", "PRelu"]))
        if a == "Clip":
            inits = {"lo": np.array(-0.5, np.float32), "hi": np.array(0.7, np.float32)}
            nodes = [helper.make_node("Clip", ["x", "lo", "hi"], ["y"])]
        elif a == "PRelu":
            inits = {"slope": g.random((c, 1, 1), np.float32)}
            nodes = [helper.make_node("PRelu", ["x", "slope"], ["y"])]
        elif a == "LeakyRelu":
            nodes = [helper.make_node(a, ["x"], ["y"], alpha=float(draw(st.sampled_from([0.01, 0.2, 1.5]))))]
        else:
            nodes = [helper.make_node(a, ["x"], ["y"])]
    elif op == "binary":
        b_op = draw(st.sampled_from(["Add", "Sub", "Mul", "Div", "Min", "Max"]))
        bshape = draw(st.sampled_from([(n, c, h, w), (1, c, 1, 1), (1, 1, h, w), (w,), ()]))
        b = g.standard_normal(bshape).astype(np.float32)
        if b_op == "Div":
            b = (np.abs(b) + 0.5) * np.sign(b + 1e-3)
        if draw(st.booleans()):
            inits = {"b": b}
        else:
            feeds["b"] = b
        nodes = [helper.make_node(b_op, ["x", "b"], ["y"])]
    elif op in ("MaxPool", "AveragePool"):
        k = draw(st.sampled_from([2, 3]))
        s = draw(st.sampled_from([1, 2]))
        p = draw(st.integers(0, k // 2))
        hh, ww = max(h, k), max(w, k)
        feeds = {"x": g.standard_normal((n, c, hh, ww)).astype(np.float32)}
        attrs = dict(kernel_shape=[k, k], strides=[s, s], pads=[p] * 4, ceil_mode=int(draw(st.booleans())))
        if op == "AveragePool":
            attrs["count_include_pad"] = int(draw(st.booleans()))
        if attrs["ceil_mode"] and p:
            attrs["ceil_mode"] = 0   # windows starting in the padding differ between opsets
        nodes = [helper.make_node(op, ["x"], ["y"], **attrs)]
    elif op == "GlobalAveragePool":
        nodes = [helper.make_node(op, ["x"], ["y"])]
    elif op == "Resize":
        mode = draw(st.sampled_from(["nearest", "linear"]))
        sc = draw(st.sampled_from([2.0, 3.0, 0.5]))
        inits = {"sc": np.array([1, 1, sc, sc], np.float32)}
        hh, ww = max(h, 2), max(w, 2)
        feeds = {"x": g.standard_normal((n, c, hh, ww)).astype(np.float32)}
        nodes = [helper.make_node("Resize", ["x", "", "sc"], ["y"], mode=mode,
                                  coordinate_transformation_mode=draw(st.sampled_from(
                                      ["half_pixel", "asymmetric", "align_corners", "pytorch_half_pixel"])))]
    elif op == "Concat":
        c2 = draw(CHANNELS)
        feeds["x2"] = g.standard_normal((n, c2, h, w)).astype(np.float32)
        inits = {"k": g.standard_normal((n, 2, h, w)).astype(np.float32)}
        nodes = [helper.make_node("Concat", ["x", "k", "x2"], ["y"], axis=1)]
    elif op == "Slice":
        axis = draw(st.sampled_from([1, 2, 3]))
        size = x.shape[axis]
        start = draw(st.integers(0, max(size - 1, 0)))
        step = draw(st.sampled_from([1, 1, 2]))
        inits = {"st": np.array([start], np.int64), "en": np.array([size], np.int64),
                 "ax": np.array([axis], np.int64), "sp": np.array([step], np.int64)}
        nodes = [helper.make_node("Slice", ["x", "st", "en", "ax", "sp"], ["y"])]
    elif op == "Pad":
        mode = draw(st.sampled_from(["constant", "reflect", "edge"]))
        hh, ww = max(h, 3), max(w, 3)
        feeds = {"x": g.standard_normal((n, c, hh, ww)).astype(np.float32)}
        pads = [0, 0, draw(st.integers(0, 2)), draw(st.integers(0, 2)), 0, 0,
                draw(st.integers(0, 2)), draw(st.integers(0, 2))]
        inits = {"p": np.array(pads, np.int64)}
        nodes = [helper.make_node("Pad", ["x", "p"], ["y"], mode=mode)]
    elif op == "Softmax":
        nodes = [helper.make_node("Softmax", ["x"], ["y"], axis=draw(st.sampled_from([1, -1])))]
    elif op == "DepthToSpace":
        r = draw(st.sampled_from([2, 3]))
        feeds = {"x": g.standard_normal((n, c * r * r, h, w)).astype(np.float32)}
        nodes = [helper.make_node(op, ["x"], ["y"], blocksize=r, mode=draw(st.sampled_from(["DCR", "CRD"])))]
    elif op == "SpaceToDepth":
        r = draw(st.sampled_from([2, 3]))
        feeds = {"x": g.standard_normal((n, c, h * r, w * r)).astype(np.float32)}
        nodes = [helper.make_node(op, ["x"], ["y"], blocksize=r)]
    elif op == "MatMul":
        m_, k_, n_ = draw(SIDE), draw(SIDE), draw(SIDE)
        feeds = {"a": g.standard_normal((n, m_, k_)).astype(np.float32)}
        b = g.standard_normal((k_, n_)).astype(np.float32)
        if draw(st.booleans()):
            inits = {"b": b}
        else:
            feeds["b"] = b
        nodes = [helper.make_node("MatMul", ["a", "b"], ["y"])]
    elif op == "Gemm":
        m_, k_, n_ = draw(SIDE), draw(SIDE), draw(SIDE)
        tb = int(draw(st.booleans()))
        feeds = {"a": g.standard_normal((m_, k_)).astype(np.float32)}
        inits = {"b": g.standard_normal((n_, k_) if tb else (k_, n_)).astype(np.float32),
                 "c": g.standard_normal(draw(st.sampled_from([(n_,), (m_, n_), (1, n_)]))).astype(np.float32)}
        nodes = [helper.make_node("Gemm", ["a", "b", "c"], ["y"], transB=tb,
                                  alpha=float(draw(st.sampled_from([1.0, 0.5]))),
                                  beta=float(draw(st.sampled_from([1.0, 2.0]))))]
    else:  # GridSample
        hh, ww = draw(SIDE), draw(SIDE)
        feeds["grid"] = g.uniform(-1.2, 1.2, (n, hh, ww, 2)).astype(np.float32)
        nodes = [helper.make_node("GridSample", ["x", "grid"], ["y"],
                                  mode=draw(st.sampled_from(["bilinear", "nearest", "bicubic"])),
                                  padding_mode=draw(st.sampled_from(["zeros", "border", "reflection"])),
                                  align_corners=int(draw(st.booleans())))]
        if {a.name: a.s for a in nodes[0].attribute}["mode"] == b"nearest":
            # Exact ties between two source pixels round differently: keep samples off them.
            feeds["grid"] = np.round(feeds["grid"] * 64) / 64 + 1 / 256
    return nodes, feeds, inits


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
@settings(max_examples=30, **SETTINGS)
@given(case=single_op(), shapeless=st.booleans())
def test_random_single_op(prec, case, shapeless):
    nodes, feeds, inits = case
    tol = dict(TOL)
    if nodes[0].op_type == "GridSample" and prec == "fp16":
        tol["fp16"] = Tolerance(2e-3, 2e-3)   # bicubic: 16 taps with negative lobes
    check_graph(nodes, feeds, ["y"], inits, prec, tol, shapeless=shapeless)


# --- multi-op graphs --------------------------------------------------------------------------

@st.composite
def graph(draw):
    """A random network: each step reads one or two earlier tensors."""
    g = np.random.default_rng(draw(st.integers(0, 2**16)))
    c0 = draw(CHANNELS)
    h, w = 2 * draw(st.integers(1, 6)), 2 * draw(st.integers(1, 6))
    feeds = {"x": g.standard_normal((1, c0, h, w)).astype(np.float32)}
    inits, nodes = {}, []
    tensors = {"x": (c0, h, w)}
    k = [0]

    def name(s):
        k[0] += 1
        return f"{s}{k[0]}"

    def const(v, s="w"):
        n = name(s)
        inits[n] = np.asarray(v, np.float32)
        return n

    for _ in range(draw(st.integers(2, 7))):
        src = draw(st.sampled_from(sorted(tensors)))
        c, hh, ww = tensors[src]
        kind = draw(st.sampled_from(["conv", "conv", "conv", "residual", "concat", "pool_up", "shuffle",
                                     "attention", "scale", "pointwise"]))
        y = name("t")
        if kind in ("conv", "pointwise"):
            kk = 3 if kind == "conv" else 1
            cout = draw(CHANNELS)
            wn = const(g.standard_normal((cout, c, kk, kk)) / np.sqrt(c * kk * kk))
            bn = const(g.standard_normal(cout) * 0.1, "b")
            act = draw(st.sampled_from(["Relu", "LeakyRelu", "Sigmoid", "Tanh", None]))
            t = name("c") if act else y
            nodes.append(helper.make_node("Conv", [src, wn, bn], [t], pads=[kk // 2] * 4))
            if act:
                nodes.append(helper.make_node(act, [t], [y]))
            tensors[y] = (cout, hh, ww)
        elif kind == "residual":
            wn = const(g.standard_normal((c, c, 3, 3)) / np.sqrt(9 * c))
            t = name("c")
            nodes.append(helper.make_node("Conv", [src, wn], [t], pads=[1] * 4))
            s = name("s")
            nodes.append(helper.make_node("Add", [src, t], [s]))
            nodes.append(helper.make_node("Relu", [s], [y]))
            tensors[y] = (c, hh, ww)
        elif kind == "concat":
            same = sorted(t for t, v in tensors.items() if v[1:] == (hh, ww))
            other = draw(st.sampled_from(same))
            nodes.append(helper.make_node("Concat", [src, other], [y], axis=1))
            tensors[y] = (c + tensors[other][0], hh, ww)
        elif kind == "pool_up" and hh % 2 == 0 and ww % 2 == 0:
            p = name("p")
            pool = draw(st.sampled_from(["MaxPool", "AveragePool"]))
            nodes.append(helper.make_node(pool, [src], [p], kernel_shape=[2, 2], strides=[2, 2]))
            nodes.append(helper.make_node("Resize", [p, "", const([1, 1, 2, 2], "sc")], [y],
                                          mode=draw(st.sampled_from(["nearest", "linear"]))))
            tensors[y] = (c, hh, ww)
        elif kind == "shuffle" and hh % 2 == 0 and ww % 2 == 0:
            t = name("s2d")
            nodes.append(helper.make_node("SpaceToDepth", [src], [t], blocksize=2))
            wn = const(g.standard_normal((4 * c, 4 * c, 1, 1)) / np.sqrt(4 * c))
            u = name("c")
            nodes.append(helper.make_node("Conv", [t, wn], [u]))
            nodes.append(helper.make_node("DepthToSpace", [u], [y], blocksize=2, mode="CRD"))
            tensors[y] = (c, hh, ww)
        elif kind == "attention":
            gap, z, s = name("gap"), name("z"), name("sig")
            nodes.append(helper.make_node("GlobalAveragePool", [src], [gap]))
            wn = const(g.standard_normal((c, c, 1, 1)) / np.sqrt(c))
            nodes.append(helper.make_node("Conv", [gap, wn], [z]))
            nodes.append(helper.make_node("Sigmoid", [z], [s]))
            nodes.append(helper.make_node("Mul", [src, s], [y]))
            tensors[y] = (c, hh, ww)
        else:
            nodes.append(helper.make_node("Mul", [src, const(g.uniform(0.5, 1.5, (1, c, 1, 1)), "k")], [y]))
            tensors[y] = (c, hh, ww)
    outs = [y for y in tensors if y != "x"][-2:]
    return nodes, feeds, inits, outs


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
@settings(max_examples=12, **SETTINGS)
@given(case=graph(), shapeless=st.booleans())
def test_random_graph(prec, case, shapeless):
    nodes, feeds, inits, outs = case
    if not outs:
        return
    used = {t for n in nodes for t in n.input}
    # Tensors nobody reads are graph outputs too, so every node is checked.
    dangling = [t for n in nodes for t in n.output if t not in used and t not in outs]
    check_graph(nodes, feeds, outs + dangling, inits, prec, CHAIN_TOL, shapeless=shapeless)
