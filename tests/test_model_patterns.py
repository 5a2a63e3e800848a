"""Graph patterns matched back into one kernel (clss/model/patterns.py): a LayerNorm written
out op by op (TorchScript below opset 17, hand-written LayerNorms, NCHW's channel LayerNorm)
and Pow by an integer constant. Each fused graph against onnxruntime, fp32 (2e-5/2e-4 of
the range) and fp16 (5e-3/5e-3), and the shapes that must not fuse."""
import numpy as np
import pytest
from onnx import TensorProto as T, helper as h, numpy_helper as nh

import clss
from clss.tolerance import Tolerance, compare
from clss.verify.twin import run_ort
from helpers import PRECISIONS

TOL = {"fp32": Tolerance(2e-5, 2e-4), "fp16": Tolerance(5e-3, 5e-3)}


def ln_model(shape, axes, *, affine=True, pow_int=False, recip=False, opset=17, weight_shape=None):
    g = np.random.default_rng(len(shape) * 10 + len(axes))
    wshape = weight_shape or [shape[a] if a in axes else 1 for a in range(len(shape))]
    two = np.array(2, np.int64) if pow_int else np.array(2.0, np.float32)
    inits = [nh.from_array(np.array(axes, np.int64), "ax"), nh.from_array(two, "two"),
             nh.from_array(np.array(1e-6, np.float32), "eps"),
             nh.from_array(g.standard_normal(wshape).astype(np.float32), "w"),
             nh.from_array(g.standard_normal(wshape).astype(np.float32), "b")]

    def mean(i, o):
        if opset >= 18:
            return h.make_node("ReduceMean", [i, "ax"], [o], keepdims=1)
        return h.make_node("ReduceMean", [i], [o], keepdims=1, axes=axes)
    nodes = [mean("x", "m"), h.make_node("Sub", ["x", "m"], ["d"]), h.make_node("Pow", ["d", "two"], ["p"]),
             mean("p", "v"), h.make_node("Add", ["v", "eps"], ["ve"]), h.make_node("Sqrt", ["ve"], ["s"])]
    if recip:
        nodes += [h.make_node("Reciprocal", ["s"], ["r"]), h.make_node("Mul", ["d", "r"], ["n"])]
    else:
        nodes += [h.make_node("Div", ["d", "s"], ["n"])]
    if affine:
        nodes += [h.make_node("Mul", ["n", "w"], ["nw"]), h.make_node("Add", ["nw", "b"], ["y"])]
    else:
        nodes += [h.make_node("Relu", ["n"], ["y"])]
    gr = h.make_graph(nodes, "ln", [h.make_tensor_value_info("x", T.FLOAT, shape)],
                      [h.make_tensor_value_info("y", T.FLOAT, None)], inits)
    m = h.make_model(gr, opset_imports=[h.make_opsetid("", opset)])
    m.ir_version = 9
    return m


def _run(model, shape, prec):
    x = np.random.default_rng(7).standard_normal(shape).astype(np.float32) * 3 + 1
    if prec != "fp32":
        x = x.astype(np.float16).astype(np.float32)
    cm = clss.Model(model, precision=prec)
    c = compare(cm.run({"x": x})["y"], run_ort(model, {"x": x})[0], TOL[prec])
    assert c.passed, f"{prec}: err/tol {c.ratio:.3g} {c.detail}"
    return [n.op for n in cm.graph.nodes]


@pytest.mark.parametrize("prec", PRECISIONS)
@pytest.mark.parametrize("shape, axes, kw, fused", [
    ((2, 50, 32), [2], {}, "LayerNormalization"),                              # a transformer's LN
    ((2, 50, 32), [-1], dict(pow_int=True, opset=18), "LayerNormalization"),   # dynamo: int exponent
    ((1, 16, 9, 13), [1], {}, "clss.NormBlock"),                               # LayerNorm2d over C
    ((1, 16, 9, 13), [1], dict(recip=True), "clss.NormBlock"),
    ((2, 5, 7, 11), [1, 2], dict(affine=False), "clss.NormBlock"),
    ((2, 50, 32), [1, 2], dict(affine=False), "LayerNormalization"),
])
def test_written_out_layer_norms_fuse_and_match(shape, axes, kw, fused, prec):
    ops = _run(ln_model(shape, axes, **kw), shape, prec)
    assert ops[0] == fused and "ReduceMean" not in ops


def test_separated_axes_and_a_weight_across_other_axes_do_not_fuse_wrongly():
    shape = (2, 6, 5, 7)
    ops = _run(ln_model(shape, [1, 3], affine=False), shape, "fp32")
    assert "ReduceMean" in ops          # not one block of axes: left as written
    # a weight varying along H (not a normalised axis): the affine part stays unfused
    ops = _run(ln_model(shape, [1], weight_shape=[1, 6, 5, 1]), shape, "fp32")
    assert ops[0] == "clss.NormBlock" and "Mul" in ops and "Add" in ops


def test_layer_norm_writes_its_statistics_only_where_read():
    """Mean and InvStdDev unread: the kernel writes Y alone (clss_stats=0); read: all three."""
    x = np.random.default_rng(2).standard_normal((3, 7, 20)).astype(np.float32)
    s = np.random.default_rng(3).standard_normal(20).astype(np.float32)
    for outs in (["y"], ["y", "mean", "istd"]):
        node = h.make_node("LayerNormalization", ["x", "s"], outs if len(outs) == 3 else ["y", "", ""], axis=-1)
        gr = h.make_graph([node], "ln", [h.make_tensor_value_info("x", T.FLOAT, x.shape)],
                          [h.make_tensor_value_info(o, T.FLOAT, None) for o in outs], [nh.from_array(s, "s")])
        m = h.make_model(gr, opset_imports=[h.make_opsetid("", 17)])
        m.ir_version = 9
        cm = clss.Model(m)
        (ln,) = cm.graph.nodes
        assert ln.attrs.get("clss_stats", 1) == (len(outs) == 3)
        got, refs = cm.run({"x": x}), run_ort(m, {"x": x})
        for o, r in zip(outs, refs):
            assert compare(got[o], r, TOL["fp32"]).passed, o
