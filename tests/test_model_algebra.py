"""The conv-through-resize graph pass (clss/model/passes.py: conv_through_resize)
against onnxruntime: Conv1x1(Concat(Resize(e_i)..., e0)) rewritten as a sum of
1x1 convolutions run before the Resize. Random level counts, channel counts,
odd sizes, resize modes (nearest, linear, cubic), scales or sizes, bias or none,
activation or none, and parts that must stay (down-sampling Resize, a Resize
whose output is also read elsewhere). fp32 and fp16."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from onnx import helper

from helpers import CHAIN_TOL, SETTINGS, check_graph


@st.composite
def decoder(draw):
    g = np.random.default_rng(draw(st.integers(0, 2**16)))
    h, w = draw(st.integers(3, 9)), draw(st.integers(3, 9))
    cout = draw(st.sampled_from([1, 3, 4]))
    c0 = draw(st.sampled_from([2, 5, 8]))
    feeds = {"e0": g.standard_normal((1, c0, h, w)).astype(np.float32)}
    nodes, inits, parts = [], {}, ["e0"]
    mode = draw(st.sampled_from(["linear", "nearest", "cubic"]))
    for i in range(1, draw(st.integers(1, 3)) + 1):
        f = draw(st.sampled_from([2, 3, 4]))
        down = draw(st.integers(0, 5)) == 0          # a part the pass must keep
        ci = draw(st.sampled_from([cout, cout + 3, 9]))
        shape = (1, ci, h * f, w * f) if down else (1, ci, -(-h // f), -(-w // f))
        feeds[f"e{i}"] = g.standard_normal(shape).astype(np.float32)
        sc = np.array([1, 1, h / shape[2], w / shape[3]], np.float32)
        exact = not down and h % f == 0 and w % f == 0     # an integer scale: no rounding question
        if exact and draw(st.booleans()):
            inits[f"sc{i}"] = sc
            ins = [f"e{i}", "", f"sc{i}"]
        else:
            inits[f"sz{i}"] = np.array([1, ci, h, w], np.int64)
            ins = [f"e{i}", "", "", f"sz{i}"]
        nodes.append(helper.make_node("Resize", ins, [f"r{i}"], mode=mode))
        parts.append(f"r{i}")
    shared = draw(st.integers(0, 4)) == 0 and len(parts) > 1
    order = draw(st.permutations(parts))
    nodes.append(helper.make_node("Concat", list(order), ["cat"], axis=1))
    ctot = sum(feeds["e0"].shape[1] if p == "e0" else feeds[f"e{p[1:]}"].shape[1] for p in order)
    inits["w"] = (g.standard_normal((cout, ctot, 1, 1)) / np.sqrt(ctot)).astype(np.float32)
    ins = ["cat", "w"]
    if draw(st.booleans()):
        inits["b"] = g.standard_normal(cout).astype(np.float32)
        ins.append("b")
    act = draw(st.sampled_from(["Relu", None]))
    nodes.append(helper.make_node("Conv", ins, ["c" if act else "y"], kernel_shape=[1, 1]))
    if act:
        nodes.append(helper.make_node(act, ["c"], ["y"]))
    outputs = ["y"] + ([parts[1]] if shared else [])
    # The pass pays, so fires, for an up-sampled part read only by the Concat
    # whose channel count is at least the convolution's outputs.
    fires = any(feeds[f"e{p[1:]}"].shape[2] <= h and feeds[f"e{p[1:]}"].shape[1] >= cout
                and not (shared and p == parts[1]) for p in parts[1:])
    return nodes, feeds, outputs, inits, fires


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
@settings(max_examples=15, **SETTINGS)
@given(case=decoder())
def test_conv_through_resize(prec, case):
    nodes, feeds, outputs, inits, fires = case
    cm = check_graph(nodes, feeds, outputs, inits, prec, CHAIN_TOL)
    assert any(line.startswith("conv_resize") for line in cm.pass_log) == fires, cm.pass_log


def test_conv_through_resize_fires_on_the_clss_decoder():
    """The CLSS classifier's decoder fuse (Concat of enc0 and three up-sampled
    levels -> Conv1x1 240->16) is rewritten, and the network still matches."""
    import clss
    from clss.tolerance import Tolerance, compare
    from clss.verify.twin import run_ort
    from clss.methods.clss.networks import CLASSIFIER_CHANNELS, build_classifier
    m = build_classifier(height=48, width=80)
    x = np.random.default_rng(1).standard_normal((1, CLASSIFIER_CHANNELS, 48, 80)).astype(np.float32)
    cm = clss.Model(m)
    assert any(line.startswith("conv_resize: 1") for line in cm.pass_log), cm.pass_log
    c = compare(cm.run({"x": x})["logits"], run_ort(m, {"x": x})[0], Tolerance(2e-5, 2e-4))
    assert c.passed, c.detail
