"""Gated convolutions as one blocked conv (clss/model/passes.py fuse_gated_conv,
kernels/conv.cl -DGATED, fast path model.gated_conv): LeakyRelu(Conv_f(x)) *
Sigmoid(Conv_g(x)), NSRD's gated conv, where a work-item holds a block of features and its
gates. The fused conv sums each output exactly as the feature and gate convs do and rounds
each factor to the storage precision as the unfused graph stores it, so it is compared bit
for bit with the unfused nodes, and within the conv tolerance with onnxruntime."""
from __future__ import annotations

import numpy as np
import onnxruntime as ort
import pytest
from onnx import helper, numpy_helper

import clss
from clss import selfcheck
from clss.model import gated_conv_graph
from clss.model.graph import build
from clss.model.passes import fuse_gated_conv, run_passes
from clss.ops import conv
from clss.tolerance import DEFAULT_TOL, EXACT, compare


def _graph(model):
    g, _, _ = build(model, None)
    run_passes(g)
    return g


def test_fuses_both_pairs_and_interleaves_blocks():
    model = gated_conv_graph()
    g = _graph(model)
    assert fuse_gated_conv(g, 16) == 2
    fused = [n for n in g.nodes if n.op == "clss.Conv"]
    assert len(fused) == 2 and all(n.attrs["gated"] for n in fused) and not any(n.op == "Mul" for n in g.nodes)
    w = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    # 32 channels in blocks of 16: f[0:16], g[0:16], f[16:32], g[16:32]
    big = next(n for n in fused if g.consts[n.inputs[1]].shape[0] == 64)
    wb = g.consts[big.inputs[1]]
    for j, (role, c0) in enumerate((("f", 0), ("g", 0), ("f", 16), ("g", 16))):
        np.testing.assert_array_equal(wb[16 * j:16 * j + 16], w[f"w{role}1"][c0:c0 + 16])
    assert not big.inputs[2]            # the second pair has no bias
    # in blocks of 8 the 16-channel pair interleaves too
    g8 = _graph(model)
    assert fuse_gated_conv(g8, 8) == 2
    small = next(n for n in g8.nodes if n.op == "clss.Conv" and g8.consts[n.inputs[1]].shape[0] == 32)
    np.testing.assert_array_equal(g8.consts[small.inputs[1]][8:16], w["wg0"][0:8])


def test_leaves_what_is_not_a_gated_pair():
    model = gated_conv_graph()
    # a gate that is not a Sigmoid
    m1 = gated_conv_graph()
    for n in m1.graph.node:
        if n.op_type == "Sigmoid":
            n.op_type = "Tanh"
    assert fuse_gated_conv(_graph(m1), 16) == 0
    # channels that are not whole blocks
    assert fuse_gated_conv(_graph(model), 32) == 1      # 32 channels fuse, 16 do not
    # a factor read twice (also a graph output)
    m2 = gated_conv_graph()
    m2.graph.output.append(helper.make_tensor_value_info("ag0", 1, [1, 16, 5, 29]))
    assert fuse_gated_conv(_graph(m2), 16) == 1


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_gated_conv_is_the_unfused_graph_bit_for_bit(any_dev, prec):
    if not any_dev.is_cpu or not selfcheck.enabled(any_dev, prec, "conv.blocked"):
        pytest.skip(f"{any_dev.info.name}: the blocked conv does not apply here")
    model = gated_conv_graph(18, 7, 37)
    x = np.random.default_rng(2).standard_normal((1, 18, 7, 37)).astype(np.float32)
    outs = {}
    for on in (True, False):
        with selfcheck.forcing("model.gated_conv", on):
            m = clss.Model(model, device=any_dev, precision=prec)
            assert any("gated_conv" in line for line in m.pass_log) == on
            outs[on] = m.run({"x": x})
    want = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"]).run(None, {"x": x})
    for k, name in enumerate(("y0", "y1")):
        c = compare(outs[True][name], outs[False][name], EXACT)
        assert c.passed, c
        c = compare(outs[True][name], want[k], DEFAULT_TOL[prec])
        assert c.passed, c


def test_gated_conv_refuses_what_it_cannot_do(dev):
    g = np.random.default_rng(1)
    x = dev.to_device(g.standard_normal((1, 16, 5, 9)).astype(np.float32))
    v = conv.vector_width(dev)
    with pytest.raises(ValueError, match="gated"):      # not whole vector pairs
        conv.conv2d(dev, "fp32", x, dev.to_device(g.standard_normal((2 * v + 2, 16, 3, 3)).astype(np.float32)),
                    pads=(1, 1, 1, 1), gated=True)
    with pytest.raises(ValueError, match="gated"):      # a residual
        conv.conv2d(dev, "fp32", x, dev.to_device(g.standard_normal((2 * v, 16, 3, 3)).astype(np.float32)),
                    pads=(1, 1, 1, 1), gated=True, residual=dev.to_device(np.zeros((1, v, 5, 9), np.float32)))
