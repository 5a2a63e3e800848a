"""A DepthToSpace (a pixel shuffle) fused into the conv that feeds it (passes.fuse_conv_depth_to_space,
kernels/d2s_index.h): the rows that store it (conv.D2S_ROWS) give the unfused pair's values, bit
for bit in fp32; a row that cannot (the CPU's blocked rows) runs the pair apart; onnxruntime agrees."""
import numpy as np
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

import clss
import clss.model as M
from clss import tuning
from clss.model import layout
from clss.ops import conv
from clss.ops.space_to_depth import depth_to_space
from clss.tolerance import DEFAULT_TOL, compare


def _model(h, w):
    """x -> relu(conv 3x3 -> 12) -> DepthToSpace CRD 2 -> + skip (x's first 3 channels resized:
    an Add after the activation, left apart), and sigmoid(DepthToSpace DCR 3 (conv 1x1 -> 27)
    + skip3): the residual and the activation in the shuffled space, fused."""
    g = np.random.default_rng(7)
    inits = [numpy_helper.from_array((g.standard_normal((12, 5, 3, 3)) * 0.3).astype(np.float32), "w1"),
             numpy_helper.from_array(g.standard_normal(12).astype(np.float32), "b1"),
             numpy_helper.from_array((g.standard_normal((27, 5, 1, 1)) * 0.3).astype(np.float32), "w2"),
             numpy_helper.from_array(np.array([0, 3], np.int64), "ch"),
             numpy_helper.from_array(np.array([], np.float32), "roi"),
             numpy_helper.from_array(np.array([1, 1, 2, 2], np.float32), "sc")]
    nodes = [helper.make_node("Conv", ["x", "w1", "b1"], ["c1"], pads=[1, 1, 1, 1]),
             helper.make_node("Relu", ["c1"], ["r1"]),
             helper.make_node("DepthToSpace", ["r1"], ["d1"], blocksize=2, mode="CRD"),
             helper.make_node("Slice", ["x", "ch", "ch_end", "axes"], ["x3"]),
             helper.make_node("Resize", ["x3", "roi", "sc"], ["skip"], mode="nearest"),
             helper.make_node("Add", ["d1", "skip"], ["y1"]),
             helper.make_node("Conv", ["x", "w2"], ["c2"]),
             helper.make_node("DepthToSpace", ["c2"], ["d2"], blocksize=3, mode="DCR"),
             helper.make_node("Resize", ["x3", "roi", "sc3"], ["skip3"], mode="nearest"),
             helper.make_node("Add", ["skip3", "d2"], ["a2"]),
             helper.make_node("Sigmoid", ["a2"], ["y2"])]
    inits[3] = numpy_helper.from_array(np.array([0], np.int64), "ch")
    inits += [numpy_helper.from_array(np.array([3], np.int64), "ch_end"),
              numpy_helper.from_array(np.array([1], np.int64), "axes"),
              numpy_helper.from_array(np.array([1, 1, 3, 3], np.float32), "sc3")]
    graph = helper.make_graph(nodes, "d2s", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 5, h, w])],
                              [helper.make_tensor_value_info("y1", TensorProto.FLOAT, None),
                               helper.make_tensor_value_info("y2", TensorProto.FLOAT, None)], inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 9
    return m


@pytest.fixture
def gpu_config(monkeypatch, tmp_path):
    """A GPU's configuration on the CPU: no blocked layout, the NCHW direct row first."""
    monkeypatch.setenv("CLSS_TUNING_DB", str(tmp_path / "tuning.json"))
    monkeypatch.setattr(layout, "enabled", lambda dev, prec: False)
    monkeypatch.setattr(tuning, "shipped", lambda dev: {"ops": {"conv2d": {"order": ["direct"]}}})


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
@pytest.mark.parametrize("hw", [(7, 11), (16, 24)])
def test_a_fused_shuffle_gives_the_pairs_values(dev, prec, hw, gpu_config, monkeypatch):
    model = _model(*hw)
    x = np.random.default_rng(1).standard_normal((1, 5) + hw).astype(np.float32)
    m = clss.Model(model, device=dev, precision=prec)
    got = m.run({"x": x})
    # two shuffles fused, then the second's residual Add and Sigmoid
    assert "conv_depth_to_space: 4" in m._current().pass_log
    fused = {n.attrs["d2s"][0]: n for n in m._current().graph.nodes if n.op == "clss.Conv" and n.attrs.get("d2s")}
    assert fused[2].attrs["activation"] == "relu" and not fused[2].inputs[3]
    assert fused[3].attrs["activation"] == "sigmoid" and fused[3].inputs[3] == "skip3"
    monkeypatch.setattr(M, "fuse_conv_depth_to_space", lambda g: 0)
    ref = clss.Model(model, device=dev, precision=prec).run({"x": x})
    want = dict(zip(["y1", "y2"], ort.InferenceSession(model.SerializeToString(),
                                                       providers=["CPUExecutionProvider"]).run(None, {"x": x})))
    for k in ("y1", "y2"):
        if prec == "fp32":
            np.testing.assert_array_equal(got[k], ref[k], err_msg=k)
        assert compare(got[k], want[k], DEFAULT_TOL[prec] if prec == "fp32" else conv_fp16_tol()).passed, k


def conv_fp16_tol():
    return DEFAULT_TOL["fp16"].__class__(5e-3, 5e-3)


def test_on_the_cpus_configuration_the_pair_runs_apart(dev, monkeypatch):
    """With the blocked layout the shuffle's conv is blocked or its row stores no shuffle:
    either the pass leaves it or the dry run runs the unfused parts, with the same values."""
    model = _model(8, 16)
    x = np.random.default_rng(2).standard_normal((1, 5, 8, 16)).astype(np.float32)
    got = clss.Model(model, device=dev).run({"x": x})
    monkeypatch.setattr(M, "fuse_conv_depth_to_space", lambda g: 0)
    ref = clss.Model(model, device=dev).run({"x": x})
    for k in ("y1", "y2"):
        np.testing.assert_array_equal(got[k], ref[k])


@pytest.mark.parametrize("row", sorted(conv.D2S_ROWS - {"mma"}))
@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_each_row_that_stores_a_shuffle_stores_the_pairs_bits(dev, row, prec):
    """conv2d(depth_to_space=) against conv2d then depth_to_space, with the activation and no
    residual: bit for bit (the store moves values, computes nothing); odd sizes, both modes,
    a 1x1 conv (the direct row's flattened-pixels path is off with a shuffle)."""
    g = np.random.default_rng(3)
    for cin, cout, hw, k, r, mode, act in ((5, 12, (7, 13), 3, 2, "CRD", "relu"),
                                           (6, 27, (5, 9), 3, 3, "DCR", "leaky_relu"),
                                           (8, 16, (4, 17), 1, 2, "DCR", "tanh")):
        x = dev.to_device(g.standard_normal((1, cin) + hw).astype(np.float32), prec)
        w = dev.to_device((g.standard_normal((cout, cin, k, k)) * 0.3).astype(np.float32), prec)
        b = dev.to_device(g.standard_normal(cout).astype(np.float32), prec)
        kw = dict(pads=(k // 2,) * 4, activation=act, tuning={"VARIANT": row})
        y = conv.conv2d(dev, prec, x, w, b, depth_to_space=(r, mode), **kw)
        z = depth_to_space(dev, prec, conv.conv2d(dev, prec, x, w, b, **kw), r, mode)
        assert tuple(y.shape) == (1, cout // r // r, hw[0] * r, hw[1] * r)
        np.testing.assert_array_equal(dev.to_host(y), dev.to_host(z))


def test_a_row_that_stores_no_shuffle_says_so(dev):
    x = dev.to_device(np.ones((1, 16, 8, 8), np.float32))
    w = dev.to_device(np.ones((16, 16, 3, 3), np.float32))
    with pytest.raises(ValueError, match="stores no DepthToSpace"):
        conv.conv2d(dev, "fp32", x, w, pads=(1, 1, 1, 1), depth_to_space=(2, "CRD"),
                    tuning={"VARIANT": "winograd_gemm"})
    with pytest.raises(ValueError, match="dividing the 16 output channels"):
        conv.conv2d(dev, "fp32", x, w, pads=(1, 1, 1, 1), depth_to_space=(3, "CRD"))
