"""clss.Model with value inputs: graph inputs whose values decide shapes or how a kernel
is set up (Resize scales and sizes, a Reshape shape, Slice starts, an Expand shape, Pad
pads). Their values are read from the feeds, the model is planned for them and again
when they change (a few plans kept), and a shape that follows data is refused by name.
Numerics against onnxruntime, fp32 and fp16."""
from __future__ import annotations

import numpy as np
import pyopencl.array as cla
import pytest
from onnx import TensorProto, helper

import clss
from clss.model import InputError, ModelError, UnsupportedModelError
from clss.model import VALUE_PLANS_KEPT
from clss.tolerance import Tolerance, compare
from clss.verify.twin import make_model, run_ort

TOL = {"fp32": Tolerance(1e-5, 1e-4), "fp16": Tolerance(3e-3, 3e-3)}
PRECS = ("fp32", "fp16")


def rnd(*shape, seed=0):
    return np.random.default_rng(seed).standard_normal(shape).astype(np.float32)


def check(cm, model, feeds, prec):
    """clss against onnxruntime (fed the fp16-rounded float data in fp16)."""
    outs = cm.run(feeds)
    ref_feeds = feeds if prec == "fp32" else {
        k: v.astype(np.float16).astype(np.float32) if v.dtype == np.float32 and v.ndim > 1 else v
        for k, v in feeds.items()}
    refs = run_ort(model, ref_feeds)
    for name, r in zip(cm.output_names, refs):
        assert outs[name].shape == r.shape, (name, outs[name].shape, r.shape)
        c = compare(outs[name], r, TOL[prec])
        assert c.passed, f"{name} {prec}: max abs {c.max_abs:.3g}, err/tol {c.ratio:.3g} {c.detail}"
    return outs


def run_values(model, data: dict, name: str, values: list, prec: str, **kw):
    """Run `model` with each of `values` for input `name` (data inputs fixed): every run
    checked against onnxruntime; returns the Model and its plan per value."""
    cm = clss.Model(model, precision=prec, **kw)
    assert name in cm.value_inputs and name in cm.input_names
    plans = []
    for v in values:
        check(cm, model, {**data, name: v}, prec)
        plans.append(cm._spec)
        np.testing.assert_array_equal(cm.input_values[name], v)
    return cm, plans


def replanned(plans):
    """Distinct plans for distinct values, the same plan for a value seen before."""
    assert plans[0] is not plans[1]
    assert plans[2] is plans[0]


# --- the ops ---------------------------------------------------------------------------

@pytest.mark.parametrize("prec", PRECS)
@pytest.mark.parametrize("mode", ["nearest", "linear"])
def test_resize_scales_input(prec, mode):
    x = rnd(1, 3, 6, 8)
    scales = np.array([1, 1, 2, 2], np.float32)
    m = make_model([helper.make_node("Resize", ["x", "", "scales"], ["y"], mode=mode)],
                   {"x": x, "scales": scales}, ["y"], opset=17)
    cm, plans = run_values(m, {"x": x}, "scales",
                           [scales, np.array([1, 1, 1.5, 3], np.float32), scales], prec)
    replanned(plans)
    assert plans[1].output_shapes["y"] == (1, 3, 9, 24)
    assert cm.output_shapes == {"y": (1, 3, 12, 16)}   # the current plan's


@pytest.mark.parametrize("prec", PRECS)
def test_resize_sizes_input(prec):
    x = rnd(1, 2, 5, 7)
    sizes = np.array([1, 2, 10, 14], np.int64)
    m = make_model([helper.make_node("Resize", ["x", "", "", "sizes"], ["y"], mode="linear")],
                   {"x": x, "sizes": sizes}, ["y"], opset=13)
    _, plans = run_values(m, {"x": x}, "sizes", [sizes, np.array([1, 2, 3, 21], np.int64), sizes], prec)
    replanned(plans)
    assert plans[1].output_shapes["y"] == (1, 2, 3, 21)


@pytest.mark.parametrize("prec", PRECS)
def test_reshape_shape_input(prec):
    x = rnd(2, 3, 4)
    m = make_model([helper.make_node("Reshape", ["x", "shape"], ["r"]),
                    helper.make_node("Relu", ["r"], ["y"])],
                   {"x": x, "shape": np.array([6, 4], np.int64)}, ["y"])
    _, plans = run_values(m, {"x": x}, "shape", [np.array([6, 4], np.int64), np.array([-1, 12], np.int64),
                                                  np.array([6, 4], np.int64)], prec)
    replanned(plans)
    assert plans[1].output_shapes["y"] == (2, 12)


@pytest.mark.parametrize("prec", PRECS)
def test_slice_starts_input(prec):
    x = rnd(1, 4, 9, 10)
    starts = np.array([1, 2], np.int64)
    m = make_model([helper.make_node("Slice", ["x", "starts", "ends", "axes"], ["s"]),
                    helper.make_node("Sigmoid", ["s"], ["y"])],
                   {"x": x, "starts": starts}, ["y"],
                   initializers={"ends": np.array([9, 10], np.int64), "axes": np.array([2, 3], np.int64)})
    _, plans = run_values(m, {"x": x}, "starts", [starts, np.array([-4, 0], np.int64), starts], prec)
    replanned(plans)
    assert plans[0].output_shapes["y"] == (1, 4, 8, 8) and plans[1].output_shapes["y"] == (1, 4, 4, 10)


@pytest.mark.parametrize("prec", PRECS)
def test_expand_shape_from_input(prec):
    """The Expand shape is computed from the input: Concat([1], Cast(n), [1, 1]) * 1."""
    x = rnd(1, 1, 3, 5)
    n = np.array([4], np.int32)
    nodes = [helper.make_node("Cast", ["n"], ["n64"], to=TensorProto.INT64),
             helper.make_node("Concat", ["one", "n64", "ones"], ["cat"], axis=0),
             helper.make_node("Mul", ["cat", "one"], ["shape"]),
             helper.make_node("Expand", ["x", "shape"], ["e"]),
             helper.make_node("Add", ["e", "e"], ["y"])]
    m = make_model(nodes, {"x": x, "n": n}, ["y"],
                   initializers={"one": np.array([1], np.int64), "ones": np.array([1, 1], np.int64)})
    cm, plans = run_values(m, {"x": x}, "n", [n, np.array([2], np.int32), n], prec)
    replanned(plans)
    assert plans[0].output_shapes["y"] == (1, 4, 3, 5) and plans[1].output_shapes["y"] == (1, 2, 3, 5)
    use = cm.value_inputs["n"][0]
    assert (use.op, use.index) == ("Expand", 1) and len(use.via) == 3   # Mul, Concat, Cast


@pytest.mark.parametrize("prec", PRECS)
def test_pad_pads_input(prec):
    x = rnd(1, 2, 4, 5)
    pads = np.array([0, 0, 1, 2, 0, 0, 2, 1], np.int64)
    m = make_model([helper.make_node("Pad", ["x", "pads", "cval"], ["y"], mode="constant")],
                   {"x": x, "pads": pads}, ["y"], initializers={"cval": np.array(0.5, np.float32)})
    _, plans = run_values(m, {"x": x}, "pads", [pads, np.array([0, 0, 0, 0, 0, 0, 3, 3], np.int64), pads],
                          prec)
    replanned(plans)
    assert plans[1].output_shapes["y"] == (1, 2, 7, 8)


@pytest.mark.parametrize("prec", PRECS)
def test_scale_factor_through_a_chain(prec):
    """A scalar factor made into Resize scales (Concat with [1, 1], Div, Cast): one input
    decides both spatial scales; a graph output the input also feeds."""
    x = rnd(1, 2, 4, 6)
    nodes = [helper.make_node("Cast", ["f"], ["f32"], to=TensorProto.FLOAT),
             helper.make_node("Div", ["f32", "two"], ["half"]),
             helper.make_node("Concat", ["ones", "half", "half"], ["scales"], axis=0),
             helper.make_node("Resize", ["x", "", "scales"], ["y"], mode="nearest")]
    m = make_model(nodes, {"x": x, "f": np.array([4], np.int64)}, ["y", "scales"],
                   initializers={"two": np.array([2], np.float32), "ones": np.array([1, 1], np.float32)})
    cm, plans = run_values(m, {"x": x}, "f", [np.array([4], np.int64), np.array([6], np.int64),
                                               np.array([4], np.int64)], prec)
    replanned(plans)
    assert plans[1].output_shapes == {"y": (1, 2, 12, 18), "scales": (4,)}


@pytest.mark.parametrize("prec", PRECS)
def test_ops_without_kernels_fold_from_value_inputs(prec):
    """ConstantOfShape and Range have no kernel: computed from a value input, they fold
    when the model is planned (the load does not refuse them)."""
    x = rnd(1, 2, 3, 5)
    nodes = [helper.make_node("ConstantOfShape", ["shape"], ["c"],
                              value=helper.make_tensor("v", TensorProto.FLOAT, [1], [1.5])),
             helper.make_node("Range", ["zero", "n", "one"], ["r"]),
             helper.make_node("Cast", ["r"], ["rf"], to=TensorProto.FLOAT),
             helper.make_node("Mul", ["x", "c"], ["xc"]),
             helper.make_node("Add", ["xc", "rf"], ["y"])]
    m = make_model(nodes, {"x": x, "shape": np.array([1, 2, 1, 1], np.int64), "n": np.array(5, np.int64)},
                   ["y"], initializers={"zero": np.array(0, np.int64), "one": np.array(1, np.int64)})
    cm, plans = run_values(m, {"x": x, "n": np.array(5, np.int64)}, "shape",
                           [np.array([1, 2, 1, 1], np.int64), np.array([1, 1, 3, 1], np.int64),
                            np.array([1, 2, 1, 1], np.int64)], prec)
    replanned(plans)
    assert set(cm.value_inputs) == {"shape", "n"}
    assert "Range" not in cm.execution_ops() and "ConstantOfShape" not in cm.execution_ops()


# --- plans: kept, replaced, given at load --------------------------------------------------

def _scales_model():
    x = rnd(1, 1, 4, 4)
    m = make_model([helper.make_node("Resize", ["x", "", "scales"], ["y"], mode="nearest")],
                   {"x": x, "scales": np.ones(4, np.float32)}, ["y"], opset=17)
    return m, x


def test_plans_kept_lru():
    m, x = _scales_model()
    cm = clss.Model(m)
    vals = [np.array([1, 1, s, s], np.float32) for s in range(1, VALUE_PLANS_KEPT + 2)]
    first = None
    for v in vals[:VALUE_PLANS_KEPT]:
        cm.run({"x": x, "scales": v})
        first = first or cm._spec
    cm.run({"x": x, "scales": vals[0]})          # the oldest used again: kept, now the newest
    assert cm._spec is first and len(cm._specs) == VALUE_PLANS_KEPT
    cm.run({"x": x, "scales": vals[-1]})         # one more: the least recently used goes
    assert len(cm._specs) == VALUE_PLANS_KEPT
    cm.run({"x": x, "scales": vals[0]})
    assert cm._spec is first
    # float16 scales in the half precisions, and float32 ones of the same values: one plan
    cm16 = clss.Model(m, precision="fp16")
    cm16.run({"x": x, "scales": vals[1]})
    p = cm16._spec
    cm16.run({"x": x, "scales": vals[1].astype(np.float16)})
    assert cm16._spec is p


def test_input_values_at_load():
    m, x = _scales_model()
    s2, s3 = np.array([1, 1, 2, 2], np.float32), np.array([1, 1, 3, 3], np.float32)
    cm = clss.Model(m, input_values={"scales": s2})
    assert cm.input_names == ["x", "scales"] and cm.output_shapes == {"y": (1, 1, 8, 8)}
    assert "Resize" in cm.execution_ops()
    # left out of a run: the load-time values; given: planned for them
    np.testing.assert_allclose(cm.run({"x": x})["y"], run_ort(m, {"x": x, "scales": s2})[0])
    assert cm.run({"x": x, "scales": s3})["y"].shape == (1, 1, 12, 12)
    assert cm.run({"x": x})["y"].shape == (1, 1, 8, 8)
    with pytest.raises(ModelError, match="input_values names 'x', whose values decide no shape"):
        clss.Model(m, input_values={"x": x})
    with pytest.raises(ModelError, match="input_values names 'nope', which the model does not have"):
        clss.Model(m, input_values={"nope": s2})
    with pytest.raises(ModelError, match=r"input_values\['scales'\]: expected float32 array of shape \(4,\)"):
        clss.Model(m, input_values={"scales": np.ones(3, np.float32)})


def test_not_planned_until_the_values_come():
    m, x = _scales_model()
    cm = clss.Model(m)
    assert "not planned yet" in repr(cm)
    with pytest.raises(ModelError, match="depend on the values of 'scales'.*input_values") as e:
        cm.output_shapes
    assert "--input scales=FILE.npy" in e.value.cli
    # the value inputs are checked as the other inputs are
    with pytest.raises(InputError, match="missing input 'scales'"):
        cm.run({"x": x})
    with pytest.raises(InputError, match="input 'scales': expected float32 array of shape"):
        cm.run({"x": x, "scales": np.ones(4, np.int64)})
    # values no plan can be made for: the error says which
    x = rnd(2, 3, 4)
    m = make_model([helper.make_node("Reshape", ["x", "shape"], ["y"])],
                   {"x": x, "shape": np.array([6, 4], np.int64)}, ["y"])
    cm = clss.Model(m)
    with pytest.raises(ModelError, match=r"planning for input_values shape=\[ ?7, -1\]: ") as e:
        cm.run({"x": x, "shape": np.array([7, -1], np.int64)})
    assert "planning for the values of --input shape=" in e.value.cli
    assert cm.run({"x": x, "shape": np.array([4, 6], np.int64)})["y"].shape == (4, 6)


def test_run_device_reads_the_values():
    m, x = _scales_model()
    cm = clss.Model(m, precision="fp16")
    d = cm.upload({"x": x, "scales": np.array([1, 1, 2, 2], np.float32)})
    assert d["scales"].dtype == np.float32 and d["x"].dtype == np.float16
    out = cm.run_device(d)
    assert out["y"].shape == (1, 1, 8, 8)
    d["scales"] = cla.to_device(cm.device.queue, np.array([1, 1, 3, 2], np.float32))
    y = cm.device.empty((1, 1, 12, 8), "fp16")
    res = cm.run_device(d, out={"y": y})
    assert res["y"] is y
    ref = run_ort(m, {"x": x.astype(np.float16).astype(np.float32), "scales": np.array([1, 1, 3, 2], np.float32)})[0]
    np.testing.assert_allclose(y.get().astype(np.float32), ref, atol=1e-3)
    res = cm.run_device(d, out={"y": y})          # the launch plan replays
    assert cm._launch_plan is not None and res["y"] is y
    with pytest.raises(InputError, match="input 'scales': expected float32"):
        cm.run_device({"x": d["x"], "scales": cla.to_device(cm.device.queue, np.ones(4, np.float16))})


# --- what no input's value settles -------------------------------------------------------

def test_shape_from_data_refused_by_name():
    """A Reshape whose shape follows an image's values (its ArgMax): refused at load,
    naming the node, the input and the way between them."""
    x = rnd(1, 3, 64, 64)
    nodes = [helper.make_node("Flatten", ["x"], ["flat"], axis=0, name="flatten"),
             helper.make_node("ArgMax", ["flat"], ["n"], axis=1, keepdims=0, name="argmax"),
             helper.make_node("Concat", ["n", "minus1"], ["shape"], axis=0, name="concat"),
             helper.make_node("Reshape", ["x", "shape"], ["y"], name="reshape")]
    m = make_model(nodes, {"x": x}, ["y"], initializers={"minus1": np.array([-1], np.int64)})
    with pytest.raises(UnsupportedModelError) as e:
        clss.Model(m)
    assert [(n[0], n[1]) for n in e.value.nodes] == [("reshape", "Reshape")]
    msg = str(e.value)
    assert "follows the values of graph input 'x' (12,288 elements)" in msg, msg
    assert "through Concat 'concat', ArgMax 'argmax', Flatten 'flatten'" in msg, msg


def test_nonzero_of_computed_tensor_refused_by_name():
    """NonZero of a computed tensor: its output's shape is data (clss names the node)."""
    x = rnd(1, 2, 4, 4)
    nodes = [helper.make_node("Relu", ["x"], ["r"], name="relu"),
             helper.make_node("NonZero", ["r"], ["nz"], name="nonzero"),
             helper.make_node("Shape", ["nz"], ["s"], name="shape"),
             helper.make_node("Reshape", ["x", "s"], ["y"], name="reshape")]
    m = make_model(nodes, {"x": x}, ["y"])
    with pytest.raises(UnsupportedModelError, match="'nonzero' \\(NonZero"):
        clss.Model(m)


def test_random_shape_refused_by_name():
    x = rnd(2, 6)
    nodes = [helper.make_node("RandomUniform", [], ["u"], shape=[2], dtype=TensorProto.FLOAT, name="random"),
             helper.make_node("Cast", ["u"], ["shape"], to=TensorProto.INT64, name="cast"),
             helper.make_node("Reshape", ["x", "shape"], ["y"], name="reshape")]
    m = make_model(nodes, {"x": x}, ["y"])
    with pytest.raises(UnsupportedModelError) as e:
        clss.Model(m)
    assert [(n[0], n[1]) for n in e.value.nodes] == [("random", "RandomUniform"), ("reshape", "Reshape")]
    assert ("input 1 ('shape') is computed when the model runs, by RandomUniform node 'random' (random values) "
            "through Cast 'cast'") in str(e.value)


def test_models_without_value_inputs_unchanged():
    x = rnd(1, 2, 4, 4)
    nodes = [helper.make_node("Shape", ["x"], ["s"]),
             helper.make_node("Reshape", ["x", "s"], ["y"])]   # a shape from a shape: no value input
    m = make_model(nodes, {"x": x}, ["y"])
    cm = clss.Model(m)
    assert cm.value_inputs == {} and cm.input_values == {} and cm.output_shapes == {"y": (1, 2, 4, 4)}
    np.testing.assert_array_equal(cm.run({"x": x})["y"], x)


# --- the command line ----------------------------------------------------------------------

def test_cli_run_with_value_input(tmp_path, capsys):
    import onnx

    from clss.cli.main import main
    m, x = _scales_model()
    p = tmp_path / "m.onnx"
    onnx.save(m, str(p))
    np.save(tmp_path / "x.npy", x)
    np.save(tmp_path / "scales.npy", np.array([1, 1, 2, 3], np.float32))
    rc = main(["run", str(p), "--input", f"x={tmp_path / 'x.npy'}", "--input",
               f"scales={tmp_path / 'scales.npy'}", "--compare-ort", "--repeat", "1"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    assert "y: float32 [1, 1, 8, 12]" in out.out and "PASS" in out.out
    # --random-inputs does not make up the values of an input that decides shapes
    rc = main(["run", str(p), "--input", f"x={tmp_path / 'x.npy'}", "--random-inputs"])
    err = capsys.readouterr().err
    assert rc == 2 and "--input scales=FILE.npy" in err, err
    np.save(tmp_path / "bad.npy", np.ones(3, np.float32))
    rc = main(["run", str(p), "--input", f"x={tmp_path / 'x.npy'}", "--input", f"scales={tmp_path / 'bad.npy'}"])
    err = capsys.readouterr().err
    assert rc == 2 and "input 'scales': expected float32 array of shape (4,)" in err, err
