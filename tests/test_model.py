"""clss.Model: loading, bad models and inputs, the graph passes, the memory
plan, the device-resident path. Numerics against onnxruntime throughout."""
from __future__ import annotations

import numpy as np
import onnx
import pyopencl.array as cla
import pytest
from onnx import TensorProto, helper, numpy_helper

import clss
from clss.model import InputError, ModelError, UnsupportedModelError
from clss.tolerance import Tolerance, compare
from clss.verify.twin import make_model, run_ort

TOL = {"fp32": Tolerance(1e-5, 1e-4), "fp16": Tolerance(3e-3, 3e-3)}


def rnd(*shape, seed=0, scale=1.0):
    return (np.random.default_rng(seed).standard_normal(shape) * scale).astype(np.float32)


def conv_w(cout, cin, k, seed):
    return rnd(cout, cin, k, k, seed=seed, scale=np.sqrt(2.0 / (cin * k * k)))


def assert_matches(model, feeds, prec="fp32", **kw):
    """Run on clss and onnxruntime (fed the fp16-rounded inputs in fp16); returns the Model."""
    m = clss.Model(model, precision=prec, **kw)
    outs = m.run(feeds)
    ref_feeds = feeds if prec == "fp32" else {
        k: v.astype(np.float16).astype(np.float32) if v.dtype == np.float32 else v for k, v in feeds.items()}
    refs = run_ort(model, ref_feeds)
    for name, r in zip(m.output_names, refs):
        c = compare(outs[name], r, TOL[prec])
        assert c.passed, f"{name} {prec}: max abs {c.max_abs:.3g}, err/tol {c.ratio:.3g} {c.detail}"
    return m


def conv_chain_model(x, n=4, c=6, k=3):
    """x -> n x (Conv k x k, Relu), all with c channels."""
    nodes, inits, t = [], {}, "x"
    cin = x.shape[1]
    for i in range(n):
        inits[f"w{i}"] = conv_w(c, cin, k, i)
        inits[f"b{i}"] = rnd(c, seed=100 + i, scale=0.1)
        nodes.append(helper.make_node("Conv", [t, f"w{i}", f"b{i}"], [f"c{i}"], pads=[k // 2] * 4))
        nodes.append(helper.make_node("Relu", [f"c{i}"], [f"r{i}"]))
        t, cin = f"r{i}", c
    nodes[-1].output[0] = "y"
    return make_model(nodes, {"x": x}, ["y"], initializers=inits)


# --- loading ---------------------------------------------------------------------------

def test_path_bytes_and_proto(tmp_path):
    x = rnd(1, 3, 5, 7)
    m = conv_chain_model(x, n=2)
    p = tmp_path / "m.onnx"
    onnx.save(m, str(p))
    ref = clss.Model(m).run({"x": x})["y"]
    for src in (str(p), p, m.SerializeToString()):
        cm = clss.Model(src)
        assert cm.input_names == ["x"] and cm.output_names == ["y"]
        np.testing.assert_array_equal(cm.run({"x": x})["y"], ref)


def test_malformed_model_gives_checker_message():
    x = rnd(1, 3, 4, 4)
    m = make_model([helper.make_node("Relu", ["x"], ["y"])], {"x": x}, ["y"])
    m.graph.node[0].input[0] = "nowhere"
    with pytest.raises(ModelError, match="onnx checker.*nowhere"):
        clss.Model(m)
    with pytest.raises(ModelError, match="not an ONNX model"):
        clss.Model(b"\x00garbage\xff" * 10)
    with pytest.raises(ModelError, match="no such model file"):
        clss.Model("/nonexistent/model.onnx")


def _relu_model(opset, nodes=None):
    g = helper.make_graph(nodes or [helper.make_node("Relu", ["x"], ["y"])], "g",
                          [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 2, 3, 3])],
                          [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 2, 3, 3])])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", opset)])
    m.ir_version = 10
    return m


def test_opset_range():
    """11-25 run (22-25 only widened types); past 25 a model runs while none of
    its ops changed after 25 (what onnxruntime also runs), else the nodes are named."""
    x = rnd(1, 2, 3, 3)
    with pytest.raises(ModelError, match="opset 10; clss supports opsets 11 to 25"):
        clss.Model(_relu_model(10))
    for opset in (22, 25, 26):
        assert_matches(_relu_model(opset), {"x": x})
    newer = [helper.make_node("Range", ["a", "b", "c"], ["r"], name="the_range"),
             helper.make_node("Relu", ["x"], ["y"])]
    m = _relu_model(27, newer)
    m.graph.initializer.extend(numpy_helper.from_array(np.array(v, np.int64), n)
                               for n, v in (("a", 0), ("b", 3), ("c", 1)))
    with pytest.raises(ModelError, match="opset 27.*'the_range' \\(Range, changed at opset 27\\)"):
        clss.Model(m)


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_graph_outputs_without_shape_or_type(prec):
    """The checker's main-graph rule wants a shape on every output; onnxruntime
    does not, and neither does clss: the shapes come from inference."""
    x = rnd(1, 3, 5, 7)
    m = conv_chain_model(x, n=1)
    m.graph.output.append(helper.make_tensor_value_info("c0", TensorProto.FLOAT, None))  # no shape
    m.graph.output[0].ClearField("type")                                                # no type at all
    with pytest.raises(onnx.checker.ValidationError):
        onnx.checker.check_model(m)
    cm = assert_matches(m, {"x": x}, prec)
    assert cm.output_shapes == {"y": (1, 6, 5, 7), "c0": (1, 6, 5, 7)}


def test_shapeless_outputs_that_are_an_input_or_a_scalar_constant():
    x = rnd(1, 2, 3, 3)
    g = helper.make_graph([helper.make_node("Relu", ["x"], ["y"]),
                           helper.make_node("Constant", [], ["k"], value_float=3.0)], "g",
                          [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 2, 3, 3])],
                          [helper.make_tensor_value_info(n, TensorProto.FLOAT, None) for n in ("y", "x", "k")])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 22)])
    m.ir_version = 10
    outs = clss.Model(m).run({"x": x})
    for name, ref in zip(("y", "x", "k"), run_ort(m, {"x": x})):
        assert outs[name].shape == ref.shape and np.array_equal(outs[name], ref), name


def test_nodes_in_any_order():
    """onnxruntime takes nodes in any order; the checker wants them sorted."""
    x = rnd(1, 3, 5, 7)
    m = conv_chain_model(x, n=2)
    nodes = list(m.graph.node)[::-1]
    del m.graph.node[:]
    m.graph.node.extend(nodes)
    assert_matches(m, {"x": x})


def test_ir_version_past_the_checkers():
    """onnx >= 1.23 writes IR 14, past onnx 1.22's checker (13); onnxruntime 1.32 runs it."""
    x = rnd(1, 3, 5, 7)
    m = conv_chain_model(x, n=1)
    ref = run_ort(m, {"x": x})[0]   # at IR 10: older onnxruntimes refuse 14
    m.ir_version = 14
    y = clss.Model(m).run({"x": x})["y"]
    assert compare(y, ref, TOL["fp32"]).passed


def test_unsupported_op_named_before_its_unknown_shape():
    boxes = np.random.default_rng(0).random((1, 6, 4), np.float32)
    scores = np.random.default_rng(1).random((1, 1, 6), np.float32)
    nodes = [helper.make_node("NonMaxSuppression", ["b", "s", "k"], ["sel"], name="nms"),
             helper.make_node("Cast", ["sel"], ["y"], to=TensorProto.FLOAT)]
    m = make_model(nodes, {"b": boxes, "s": scores}, ["y"], initializers={"k": np.array([3], np.int64)})
    with pytest.raises(UnsupportedModelError) as e:
        clss.Model(m)
    msg = str(e.value)
    assert e.value.nodes[0][:3] == ("nms", "NonMaxSuppression", 18)
    assert msg.index("NonMaxSuppression") < msg.index("could not resolve the shape of tensor 'sel'")


def test_small_exporter_ops_fold_or_vanish():
    """Cast/CastLike between float types, Constant's value_float(s)/value_int(s),
    and Shape -> Gather -> ConstantOfShape chains: nothing of them runs."""
    x = rnd(1, 3, 4, 5)
    nodes = [helper.make_node("Cast", ["x"], ["xf"], to=TensorProto.FLOAT),
             helper.make_node("Constant", [], ["half"], value_float=0.5),
             helper.make_node("Constant", [], ["bias"], value_floats=[0.1, -0.2, 0.3]),
             helper.make_node("Constant", [], ["axes"], value_ints=[0, 2, 3]),
             helper.make_node("Constant", [], ["one"], value_int=1),
             helper.make_node("Unsqueeze", ["bias", "axes"], ["bias4"]),
             helper.make_node("CastLike", ["half", "x"], ["half_like"]),
             helper.make_node("Shape", ["x"], ["sh"]),
             helper.make_node("Gather", ["sh", "one"], ["c"], axis=0),
             helper.make_node("Unsqueeze", ["c", "axes0"], ["c1"]),
             helper.make_node("ConstantOfShape", ["c1"], ["ones"],
                              value=numpy_helper.from_array(np.array([1.0], np.float32))),
             helper.make_node("Reshape", ["ones", "shape4"], ["ones4"]),
             helper.make_node("Mul", ["xf", "half_like"], ["a"]),
             helper.make_node("Add", ["a", "bias4"], ["b"]),
             helper.make_node("Mul", ["b", "ones4"], ["c16"]),
             helper.make_node("Cast", ["c16"], ["y"], to=TensorProto.FLOAT16)]
    m = make_model(nodes, {"x": x}, {"y": np.float16}, opset=22, initializers={
        "axes0": np.array([0], np.int64), "shape4": np.array([1, 3, 1, 1], np.int64)})
    cm = clss.Model(m)
    ops = cm.execution_ops()
    assert set(ops) <= {"Mul", "Add", "Copy"} and ops["Mul"] == 2, ops
    y = cm.run({"x": x})["y"]
    ref = run_ort(m, {"x": x})[0]
    assert compare(y, ref.astype(np.float32), Tolerance(1e-3, 1e-3)).passed   # ort rounds to half


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_bool_cast_and_sparse_constant(prec):
    """mask.float() (Cast of a comparison) runs as Where(mask, 1, 0); a Constant's
    sparse_value is densified at load."""
    x = rnd(1, 2, 3, 5)
    sparse = helper.make_sparse_tensor(helper.make_tensor("v", TensorProto.FLOAT, [2], [1.5, -2.0]),
                                       helper.make_tensor("i", TensorProto.INT64, [2], [1, 7]), [1, 2, 3, 5])
    nodes = [helper.make_node("Greater", ["x", "zero"], ["m"]),
             helper.make_node("Cast", ["m"], ["mf"], to=TensorProto.FLOAT),
             helper.make_node("Constant", [], ["s"], sparse_value=sparse),
             helper.make_node("Mul", ["x", "mf"], ["a"]),
             helper.make_node("Add", ["a", "s"], ["y"])]
    m = make_model(nodes, {"x": x}, ["y"], initializers={"zero": np.zeros(1, np.float32)}, opset=22)
    cm = assert_matches(m, {"x": x}, prec)
    assert cm.execution_ops()["Where"] == 1


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_training_mode_batchnorm(prec):
    x = rnd(3, 5, 7, 6, scale=2.0) + 0.5
    inits = {"s": rnd(5, seed=1), "b": rnd(5, seed=2), "m": rnd(5, seed=3),
             "v": np.abs(rnd(5, seed=4)) + 0.5}
    if prec != "fp32":
        inits = {k: v.astype(np.float16).astype(np.float32) for k, v in inits.items()}
    nodes = [helper.make_node("BatchNormalization", ["x", "s", "b", "m", "v"], ["y", "rm", "rv"],
                              training_mode=1, momentum=0.8, epsilon=1e-3)]
    m = make_model(nodes, {"x": x}, ["y", "rm", "rv"], initializers=inits, opset=15)
    cm = assert_matches(m, {"x": x}, prec)
    assert "BatchNormalization" not in cm.execution_ops()


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_nan_propagates_like_onnxruntime(prec):
    """NaN in -> NaN out, standalone and fused: relu/leaky_relu (conv epilogue,
    MLP layers, elementwise), clip, max, min, hard_sigmoid."""
    x = rnd(1, 4, 5, 7)
    x[0, 1, 2, 3] = x[0, 0, 0, 0] = x[0, 3, 4, 6] = np.nan
    lo, hi, zero = (np.array(v, np.float32) for v in (-0.5, 0.7, 0.0))
    nodes = [helper.make_node("Relu", ["x"], ["relu"]),
             helper.make_node("LeakyRelu", ["x"], ["leaky"], alpha=0.1),
             helper.make_node("Clip", ["x", "lo", "hi"], ["clip"]),
             helper.make_node("Max", ["x", "zero"], ["max"]),
             helper.make_node("Min", ["zero", "x"], ["min"]),
             helper.make_node("HardSigmoid", ["x"], ["hsig"]),
             helper.make_node("Conv", ["x", "w3"], ["c3"], pads=[1] * 4),
             helper.make_node("Relu", ["c3"], ["conv_relu"]),
             helper.make_node("Conv", ["x", "w3"], ["d3"], pads=[1] * 4),
             helper.make_node("Add", ["d3", "x"], ["d3r"]),
             helper.make_node("LeakyRelu", ["d3r"], ["conv_add_leaky"], alpha=0.2),
             helper.make_node("Conv", ["x", "w1"], ["p1"]),
             helper.make_node("Relu", ["p1"], ["p1r"]),
             helper.make_node("Conv", ["p1r", "w2"], ["p2"]),
             helper.make_node("LeakyRelu", ["p2"], ["mlp"], alpha=0.3),
             helper.make_node("ConvTranspose", ["x", "wt"], ["t2"], strides=[2, 2]),
             helper.make_node("Relu", ["t2"], ["deconv_relu"])]
    outs = ["relu", "leaky", "clip", "max", "min", "hsig", "conv_relu", "conv_add_leaky", "mlp", "deconv_relu"]
    inits = {"lo": lo, "hi": hi, "zero": zero, "w3": conv_w(4, 4, 3, 1), "w1": conv_w(6, 4, 1, 2),
             "w2": conv_w(3, 6, 1, 3), "wt": conv_w(4, 3, 2, 4)}
    if prec != "fp32":
        inits = {k: v.astype(np.float16).astype(np.float32) for k, v in inits.items()}
    cm = assert_matches(make_model(nodes, {"x": x}, outs, initializers=inits), {"x": x}, prec)
    ops = cm.execution_ops()
    assert ops["Conv+relu"] == 1 and ops["Conv+Add+leaky_relu"] == 1 and ops["MLP(2 layers)"] == 1, ops
    assert ops["ConvTranspose+relu"] == 1, ops


def _symbolic_model():
    g = helper.make_graph(
        [helper.make_node("Relu", ["x"], ["y"])], "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3, "H", "W"])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 3, "H", "W"])])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 18)])
    m.ir_version = 10
    return m


def test_symbolic_dims_need_input_shapes():
    m = _symbolic_model()
    with pytest.raises(ModelError, match=r"input 'x' has symbolic dimension 'H' \(axis 2\).*input_shapes"):
        clss.Model(m)
    x = rnd(1, 3, 5, 6)
    for spec in ((1, 3, 5, 6), "1x3x5x6"):
        cm = clss.Model(m, input_shapes={"x": spec})
        assert cm.input_shapes == {"x": (1, 3, 5, 6)}
        np.testing.assert_array_equal(cm.run({"x": x})["y"], np.maximum(x, 0))
    with pytest.raises(ModelError, match="'z'.*inputs are 'x'"):
        clss.Model(m, input_shapes={"z": (1, 3, 5, 6)})
    with pytest.raises(ModelError, match="axis 1; the model fixes it to 3"):
        clss.Model(m, input_shapes={"x": (1, 4, 5, 6)})
    with pytest.raises(ModelError, match="rank 3"):
        clss.Model(m, input_shapes={"x": (1, 5, 6)})


def test_absurd_sizes_refused_before_allocation():
    m = _symbolic_model()
    with pytest.raises(ModelError, match=r"over 2\^31-1 elements \(no allocation was made\)"):
        clss.Model(m, input_shapes={"x": (1, 3, 2**20, 2**20)})
    dev = clss.get_device()
    side = int(np.sqrt(dev.info.max_alloc / 4 / 3)) + 64   # just past max alloc
    if 3 * side * side <= 2**31 - 1:   # else the element limit above answers first
        with pytest.raises(ModelError, match="max allocation"):
            clss.Model(m, input_shapes={"x": (1, 3, side, side)})
    # A folded constant that would explode on the host.
    shape = numpy_helper.from_array(np.array([2**14, 2**14, 2**6], np.int64), "s")
    g = helper.make_graph([helper.make_node("ConstantOfShape", ["s"], ["c"]),
                           helper.make_node("Add", ["x", "c"], ["y"])], "g",
                          [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
                          [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["a", "b", "c"])],
                          initializer=[shape])
    big = helper.make_model(g, opset_imports=[helper.make_opsetid("", 18)])
    big.ir_version = 10
    with pytest.raises(ModelError, match="no allocation was made"):
        clss.Model(big)


def test_every_unsupported_node_listed_in_one_error():
    x = rnd(1, 4, 6, 6)
    nodes = [helper.make_node("Relu", ["x"], ["a"], name="ok_relu"),
             helper.make_node("LRN", ["a"], ["b"], size=3, name="the_lrn"),
             helper.make_node("Acosh", ["b"], ["c"], name="the_acosh"),
             helper.make_node("Conv", ["c", "w"], ["y"], name="conv_ok")]
    m = make_model(nodes, {"x": x}, ["y"], initializers={"w": conv_w(3, 4, 1, 0)})
    with pytest.raises(UnsupportedModelError) as e:
        clss.Model(m)
    msg = str(e.value)
    assert "2 node(s)" in msg
    assert "'the_lrn' (LRN, opset 18)" in msg and "'the_acosh' (Acosh, opset 18)" in msg
    assert [n[0] for n in e.value.nodes] == ["the_lrn", "the_acosh"]


def test_data_dependent_shapes_and_constants():
    x = rnd(1, 2, 4, 4)
    s = np.array([1, 1, 2, 2], np.float32)
    nodes = [helper.make_node("Mul", ["scales_in", "one"], ["scales"]),
             helper.make_node("Resize", ["x", "", "scales"], ["y"], mode="nearest", name="rs")]
    m = make_model(nodes, {"x": x, "scales_in": s}, ["y"], initializers={"one": np.ones(4, np.float32)})
    # a graph input that decides a shape: read from the feeds and planned for
    # (tests/test_model_value_inputs.py); what only the running model computes is refused
    cm = clss.Model(m)
    assert list(cm.value_inputs) == ["scales_in"]
    np.testing.assert_array_equal(cm.run({"x": x, "scales_in": s})["y"], run_ort(m, {"x": x, "scales_in": s})[0])
    nodes = [helper.make_node("Clip", ["x", "lo"], ["y"], name="clip")]
    m = make_model(nodes, {"x": x, "lo": np.array(0.0, np.float32)}, ["y"])
    np.testing.assert_array_equal(clss.Model(m).run({"x": x, "lo": np.array(0.0, np.float32)})["y"],
                                  np.maximum(x, 0))


# --- bad inputs ------------------------------------------------------------------------

def test_wrong_inputs_named_with_expectation():
    x = rnd(1, 3, 5, 7)
    cm = clss.Model(conv_chain_model(x, n=1))
    with pytest.raises(InputError, match="unknown input 'X'.*inputs are 'x'"):
        cm.run({"X": x})
    with pytest.raises(InputError, match="missing input 'x'.*float32.*\\(1, 3, 5, 7\\)"):
        cm.run({})
    with pytest.raises(InputError, match="input 'x'.*\\(1, 3, 5, 7\\).*got shape \\(1, 3, 5, 6\\)"):
        cm.run({"x": x[..., :6]})
    with pytest.raises(InputError, match="input 'x': expected float32.*got float64"):
        cm.run({"x": x.astype(np.float64)})
    with pytest.raises(InputError, match="input 'x'.*float16"):  # half only in half precisions
        cm.run({"x": x.astype(np.float16)})
    with pytest.raises(InputError, match="run_device"):
        cm.run({"x": cm.device.to_device(x)})


# --- device-resident runs ---------------------------------------------------------------

@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_run_device(prec, dev):
    x = rnd(1, 3, 5, 7)
    cm = clss.Model(conv_chain_model(x, n=2), precision=prec)
    host = cm.run({"x": x})["y"]
    xd = dev.to_device(x, prec)
    out = cm.run_device({"x": xd})
    assert isinstance(out["y"], cla.Array) and out["y"].dtype == (np.float32 if prec == "fp32" else np.float16)
    first = out["y"]
    out2 = cm.run_device({"x": dev.to_device(2 * x, prec)})
    assert out2["y"] is not first            # outputs are fresh per run: the first stays valid
    np.testing.assert_array_equal(dev.to_host(first), host)
    dst = dev.empty(first.shape, prec)
    cm.run_device({"x": xd}, out={"y": dst})
    np.testing.assert_array_equal(dev.to_host(dst), host)
    with pytest.raises(InputError, match="input 'x': expected"):
        cm.run_device({"x": dev.to_device(x, "fp16" if prec == "fp32" else "fp32")})
    with pytest.raises(InputError, match="pyopencl arrays"):
        cm.run_device({"x": x})
    with pytest.raises(InputError, match="out\\['y'\\]"):
        cm.run_device({"x": xd}, out={"y": dev.empty((1, 2), prec)})


def test_fp16_weights_converted_once(dev):
    x = rnd(1, 3, 5, 7)
    cm = clss.Model(conv_chain_model(x, n=2), precision="fp16")
    consts = cm._exec.const_dev
    assert consts and all(a.dtype == np.float16 for a in consts.values())
    before = {k: id(v) for k, v in consts.items()}
    cm.run({"x": x})
    cm.run({"x": x})
    assert {k: id(v) for k, v in cm._exec.const_dev.items()} == before


# --- passes ------------------------------------------------------------------------------

@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_conv_bn_act_residual_fusion(prec):
    x = rnd(1, 5, 9, 11)
    c = 5
    g = np.random.default_rng(3)
    bn = {"g": (g.random(c) + 0.5).astype(np.float32), "be": rnd(c, seed=4, scale=0.1),
          "mu": rnd(c, seed=5, scale=0.1), "var": (g.random(c) + 0.5).astype(np.float32)}
    nodes = [helper.make_node("Conv", ["x", "w0"], ["c0"], pads=[1, 1, 1, 1]),
             helper.make_node("BatchNormalization", ["c0", "g", "be", "mu", "var"], ["n0"], epsilon=1e-3),
             helper.make_node("LeakyRelu", ["n0"], ["a0"], alpha=0.2),
             helper.make_node("Conv", ["a0", "w1", "b1"], ["c1"], pads=[1, 1, 1, 1]),
             helper.make_node("Add", ["x", "c1"], ["s"]),
             helper.make_node("Relu", ["s"], ["r"]),
             helper.make_node("BatchNormalization", ["r", "g", "be", "mu", "var"], ["y"])]
    m = make_model(nodes, {"x": x}, ["y"], initializers={
        "w0": conv_w(c, 5, 3, 0), "w1": conv_w(c, c, 3, 1), "b1": rnd(c, seed=2, scale=0.1), **bn})
    cm = assert_matches(m, {"x": x}, prec)
    ops = cm.execution_ops()
    assert ops["Conv+leaky_relu"] == 1 and ops["Conv+Add+relu"] == 1 and ops["Conv"] == 1, ops
    assert "BatchNormalization" not in ops and sum(ops.values()) == 3


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_pointwise_chain_mlp(prec):
    x = rnd(1, 22, 7, 13)
    nodes = [helper.make_node("Conv", ["x", "w0", "b0"], ["h0"]),
             helper.make_node("Relu", ["h0"], ["a0"]),
             helper.make_node("Conv", ["a0", "w1", "b1"], ["h1"]),
             helper.make_node("Tanh", ["h1"], ["a1"]),
             helper.make_node("Conv", ["a1", "w2", "b2"], ["h2"]),
             helper.make_node("Sigmoid", ["h2"], ["y"])]
    inits = {"w0": conv_w(32, 22, 1, 0), "b0": rnd(32, seed=1, scale=0.1), "w1": conv_w(17, 32, 1, 2),
             "b1": rnd(17, seed=3, scale=0.1), "w2": conv_w(1, 17, 1, 4), "b2": rnd(1, seed=5, scale=0.1)}
    cm = assert_matches(make_model(nodes, {"x": x}, ["y"], initializers=inits), {"x": x}, prec)
    assert any(p.startswith("mlp: 1") for p in cm.pass_log), cm.pass_log
    ops = cm.execution_ops()
    assert ops.get("MLP(3 layers)") == 1 or ops == {"Conv+relu": 1, "Conv+tanh": 1, "Conv+sigmoid": 1}, ops


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_binary_relu_fusion(prec):
    # Add/Sub/Mul/Div -> Relu is one kernel (flat, broadcast and bcast8 launches); a sum
    # that another node also reads, and a comparison, stay unfused.
    a, b = rnd(2, 3, 7, 13, seed=1), rnd(2, 3, 7, 13, seed=2)
    row, col = rnd(1, 3, 1, 13, seed=3), rnd(2, 1, 7, 1, seed=4)
    nodes = [helper.make_node("Add", ["a", "b"], ["s0"]), helper.make_node("Relu", ["s0"], ["y0"]),
             helper.make_node("Sub", ["a", "row"], ["s1"]), helper.make_node("Relu", ["s1"], ["y1"]),
             helper.make_node("Mul", ["col", "b"], ["s2"]), helper.make_node("Relu", ["s2"], ["y2"]),
             helper.make_node("Div", ["a", "b"], ["s3"]), helper.make_node("Relu", ["s3"], ["r3"]),
             helper.make_node("Add", ["r3", "s3"], ["y3"]),
             helper.make_node("Max", ["a", "b"], ["s4"]), helper.make_node("Relu", ["s4"], ["y4"])]
    feeds = {"a": a, "b": b, "row": row, "col": col}
    cm = assert_matches(make_model(nodes, feeds, ["y0", "y1", "y2", "y3", "y4"]), feeds, prec)
    assert any(p.startswith("binary_relu: 3") for p in cm.pass_log), cm.pass_log
    ops = cm.execution_ops()
    assert ops["Add+relu"] == 1 and ops["Sub+relu"] == 1 and ops["Mul+relu"] == 1, ops
    assert ops["Div"] == 1 and ops["Relu"] == 2, ops


@pytest.mark.parametrize("mode,direction", [("CRD", "d2s"), ("DCR", "d2s"), ("CRD", "s2d"), ("DCR", "s2d")])
def test_pixel_shuffle_patterns(mode, direction):
    n, c, h, w, r = 1, 3, 5, 7, 2
    if direction == "d2s":
        x = rnd(n, c * r * r, h, w)
        mid = (n, c, r, r, h, w) if mode == "CRD" else (n, r, r, c, h, w)
        perm = (0, 1, 4, 2, 5, 3) if mode == "CRD" else (0, 3, 4, 1, 5, 2)
        out = (n, c, h * r, w * r)
    else:
        x = rnd(n, c, h * r, w * r)
        mid = (n, c, h, r, w, r)
        perm = (0, 1, 3, 5, 2, 4) if mode == "CRD" else (0, 3, 5, 1, 2, 4)
        out = (n, c * r * r, h, w)
    nodes = [helper.make_node("Relu", ["x"], ["a"]),
             helper.make_node("Reshape", ["a", "s1"], ["t1"]),
             helper.make_node("Transpose", ["t1"], ["t2"], perm=list(perm)),
             helper.make_node("Reshape", ["t2", "s2"], ["y"])]
    m = make_model(nodes, {"x": x}, ["y"], initializers={"s1": np.array(mid, np.int64),
                                                         "s2": np.array(out, np.int64)})
    cm = assert_matches(m, {"x": x})
    ops = cm.execution_ops()
    want = "DepthToSpace" if direction == "d2s" else "SpaceToDepth"
    assert ops[want] == 1 and "Transpose" not in ops, ops


def test_gemm_and_matmul():
    a = rnd(5, 7)
    nodes = [helper.make_node("Gemm", ["a", "B", "C"], ["g"], alpha=0.5, beta=2.0, transB=1),
             helper.make_node("MatMul", ["g", "D"], ["m"]),
             helper.make_node("Gemm", ["m", "E", "F"], ["y"]),
             helper.make_node("MatMul", ["a3", "b3"], ["z"])]
    inits = {"B": rnd(6, 7, seed=1), "C": rnd(6, seed=2), "D": rnd(6, 4, seed=3),
             "E": rnd(4, 3, seed=4), "F": rnd(5, 3, seed=5)}
    feeds = {"a": a, "a3": rnd(2, 3, 5, seed=6), "b3": rnd(2, 5, 4, seed=7)}
    cm = assert_matches(make_model(nodes, feeds, ["y", "z"], initializers=inits), feeds)
    assert {"Gemm", "MatMul"}.isdisjoint(cm.execution_ops())


def test_constant_folding_and_identity():
    """Shape -> Gather -> Concat -> Reshape (as exporters write a flatten), a
    Constant, arithmetic on constants and Identity chains all vanish at load."""
    x = rnd(2, 3, 4, 5)
    nodes = [helper.make_node("Shape", ["x"], ["sh"]),
             helper.make_node("Gather", ["sh", "i0"], ["n"], axis=0),
             helper.make_node("Concat", ["n", "m1"], ["shape"], axis=0),
             helper.make_node("Identity", ["x"], ["xi"]),
             helper.make_node("Reshape", ["xi", "shape"], ["flat"]),
             helper.make_node("Constant", [], ["k"], value=numpy_helper.from_array(rnd(60, seed=1), "k")),
             helper.make_node("Mul", ["k", "two"], ["k2"]),
             helper.make_node("Add", ["flat", "k2"], ["s"]),
             helper.make_node("Identity", ["s"], ["y"]),
             helper.make_node("Identity", ["y"], ["y2"])]
    m = make_model(nodes, {"x": x}, ["y", "y2"], initializers={
        "i0": np.array([0], np.int64), "m1": np.array([-1], np.int64), "two": np.array(2.0, np.float32)})
    cm = assert_matches(m, {"x": x})
    ops = cm.execution_ops()
    assert set(ops) <= {"view (no kernel)", "Add", "Copy"} and ops["Add"] == 1, ops


def test_dropout_and_opset11_softmax():
    x = rnd(2, 3, 4)
    nodes = [helper.make_node("Dropout", ["x"], ["d"]),
             helper.make_node("Softmax", ["d"], ["y"], axis=1)]  # opset 11: softmax over 3*4 values
    m = make_model(nodes, {"x": x}, ["y"], opset=11)
    assert_matches(m, {"x": x})


# --- memory plan ----------------------------------------------------------------------------

def test_memory_plan_reuses_buffers():
    x = rnd(1, 6, 9, 10)
    cm = assert_matches(conv_chain_model(x, n=6), {"x": x})
    p = cm.plan
    one = 6 * 9 * 10 * 4
    assert len(p.slots) <= 2 and p.peak_bytes <= 2 * one < p.unshared_bytes, p.summary()
    mem = cm.memory()
    assert mem["intermediate_peak_bytes"] == p.peak_bytes and mem["output_bytes"] == one
    # Twice more: the shared buffers give the same answer every run.
    a, b = cm.run({"x": x})["y"], cm.run({"x": x})["y"]
    np.testing.assert_array_equal(a, b)


def test_plan_keeps_skip_connections_alive():
    """A U-Net-like skip: the early tensor must survive every later layer."""
    x = rnd(1, 4, 8, 8)
    nodes = [helper.make_node("Conv", ["x", "w0"], ["e0"], pads=[1] * 4),
             helper.make_node("MaxPool", ["e0"], ["p"], kernel_shape=[2, 2], strides=[2, 2]),
             helper.make_node("Conv", ["p", "w1"], ["e1"], pads=[1] * 4),
             helper.make_node("Relu", ["e1"], ["e2"]),
             helper.make_node("Resize", ["e2", "", "sc"], ["u"], mode="nearest"),
             helper.make_node("Concat", ["u", "e0"], ["cat"], axis=1),
             helper.make_node("Conv", ["cat", "w2"], ["y"], pads=[1] * 4)]
    inits = {"w0": conv_w(4, 4, 3, 0), "w1": conv_w(4, 4, 3, 1), "w2": conv_w(3, 8, 3, 2),
             "sc": np.array([1, 1, 2, 2], np.float32)}
    for prec in ("fp32", "fp16"):
        assert_matches(make_model(nodes, {"x": x}, ["y"], initializers=inits), {"x": x}, prec)


# --- CLI ------------------------------------------------------------------------------------

def test_cli_info_and_run(tmp_path, capsys):
    from clss.cli import main
    x = rnd(1, 3, 5, 7)
    p = tmp_path / "chain.onnx"
    onnx.save(conv_chain_model(x, n=2), str(p))
    sym = tmp_path / "sym.onnx"
    onnx.save(_symbolic_model(), str(sym))
    assert main(["info", str(p), "--json", str(tmp_path / "i.json")]) == 0
    out = capsys.readouterr().out
    assert "Conv 2, Relu 2" in out and "Conv+relu 2" in out and "parameters: 498" in out
    assert "FLOPs per inference" in out and "planned peak device memory" in out
    assert main(["info", str(sym)]) == 2
    assert "symbolic dimension 'H'" in capsys.readouterr().err
    assert main(["info", str(sym), "--input-shape", "x=1x3x8x8"]) == 0
    capsys.readouterr()
    np.save(tmp_path / "x.npy", x)
    rc = main(["run", str(p), "--input", f"x={tmp_path / 'x.npy'}", "--output-dir", str(tmp_path / "o"),
               "--compare-ort", "--repeat", "1", "--json", str(tmp_path / "r.json")])
    out = capsys.readouterr().out
    assert rc == 0 and "PASS" in out and "onnxruntime CPU" in out, out
    np.testing.assert_allclose(np.load(tmp_path / "o" / "y.npy"), run_ort(conv_chain_model(x, n=2), {"x": x})[0],
                               rtol=1e-4, atol=1e-5)
    np.save(tmp_path / "bad.npy", x[..., :6])
    assert main(["run", str(p), "--input", f"x={tmp_path / 'bad.npy'}"]) == 2
    assert "input 'x'" in capsys.readouterr().err


def test_total_memory_refused_before_allocation(monkeypatch):
    """Each tensor fits the max allocation, all of them together not the device."""
    x = rnd(1, 3, 5, 7)
    cm = clss.Model(conv_chain_model(x, n=3))
    need = cm._exec.live_bytes()
    assert need >= 2 * 6 * 5 * 7 * 4
    from clss.device import DeviceInfo
    dev = cm.device
    monkeypatch.setattr(dev, "info", DeviceInfo(**{**dev.info.__dict__, "global_mem": need - 1}))
    with pytest.raises(ModelError, match="needs at least.*no allocation was made"):
        clss.Model(conv_chain_model(x, n=3), device=dev)


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_conv_transpose_fusion(prec):
    x = rnd(2, 4, 5, 6)
    nodes = [helper.make_node("ConvTranspose", ["x", "w", "b"], ["c"], strides=[2, 2], pads=[1, 1, 0, 0],
                             output_padding=[1, 0]),
             helper.make_node("BatchNormalization", ["c", "g", "be", "mu", "var"], ["n"]),
             helper.make_node("Sigmoid", ["n"], ["y"])]
    inits = {"w": rnd(4, 3, 3, 3, seed=1, scale=0.3), "b": rnd(3, seed=2, scale=0.1),
             "g": np.full(3, 1.5, np.float32), "be": rnd(3, seed=3), "mu": rnd(3, seed=4), "var": np.ones(3, np.float32)}
    cm = assert_matches(make_model(nodes, {"x": x}, ["y"], initializers=inits), {"x": x}, prec)
    assert cm.execution_ops() == {"ConvTranspose+sigmoid": 1}


def test_conv_1d_and_auto_pad():
    x = rnd(2, 3, 17)
    nodes = [helper.make_node("Conv", ["x", "w"], ["c"], auto_pad="SAME_UPPER", strides=[2]),
             helper.make_node("Relu", ["c"], ["r"]),
             helper.make_node("ConvTranspose", ["r", "wt"], ["y"], strides=[2], pads=[1, 0])]
    inits = {"w": rnd(4, 3, 3, seed=1, scale=0.4), "wt": rnd(4, 2, 3, seed=2, scale=0.4)}
    cm = assert_matches(make_model(nodes, {"x": x}, ["y"], initializers=inits), {"x": x})
    assert cm.execution_ops()["Conv+relu"] == 1 and cm.execution_ops()["ConvTranspose"] == 1


def test_grid_inputs_stay_float32_in_fp16():
    """A grid fed to GridSample is a coordinate: in half precisions it stays float32 (half
    would move samples by up to 1/8 pixel at 1080p). Data inputs are half as usual."""
    x = rnd(1, 3, 40, 64)
    grid = (rnd(1, 40, 64, 2, seed=1) * 0.9).astype(np.float32)
    node = helper.make_node("GridSample", ["x", "grid"], ["y"], mode="bilinear", align_corners=0)
    model = make_model([node], {"x": x, "grid": grid}, ["y"], opset=16)
    m = clss.Model(model, precision="fp16")
    up = m.upload({"x": x, "grid": grid})
    assert up["x"].dtype == np.float16 and up["grid"].dtype == np.float32
    ref = run_ort(model, {"x": x.astype(np.float16).astype(np.float32), "grid": grid})[0]
    c = compare(m.run_device(up)["y"].get().astype(np.float32), ref, Tolerance(1e-3, 1e-3))
    assert c.passed, c
    with pytest.raises(InputError, match="float32"):
        m.run_device({"x": up["x"], "grid": m.device.to_device(grid, "fp16")})
