"""The ONNX backend node cases (onnx 1.22.0) through clss.Model, against the
cases' expected outputs and against onnxruntime on the same model.

Every single-node case whose op type clss runs (a registered handler, or an op
the model passes lower: BatchNormalization, Gemm, MatMul, Reshape, ...) is
collected. The harness adapts each case the way a deployed model differs
from a conformance test, and nothing else:
* inputs the kernels need at load (Resize scales, Pad pads, Reshape shape,
  BatchNorm statistics, Gemm's B and C) become initializers;
* IR version 10, for onnxruntime.
Each case runs at the opset it was written for (11 to 25; 22-25 only widened
types). Cases on float16 data run in precision fp16 (its default tolerance); cases on
other non-float32 data are skipped as one category (the kernels are
float32/float16); cases the kernels cannot run are listed with a reason in the
families' NODE_DEVIATIONS or in MODEL_DEVIATIONS below.
"""
from __future__ import annotations

import os

import numpy as np
import onnx
import pytest
from onnx import numpy_helper

import clss
from clss.model.graph import MAX_OPSET, MIN_OPSET, UnsupportedModelError
from clss.model.graph import LOWERED_OPS
from clss.ops import ONNX_HANDLERS, load_all
from clss.tolerance import DEFAULT_TOL, Tolerance, compare
from node_cases import load_case_data, single_node_cases

FAMILIES = load_all()
FAMILY_DEVIATIONS = {k: v for m in FAMILIES.values() for k, v in getattr(m, "NODE_DEVIATIONS", {}).items()}
NODE_TOL = Tolerance(1e-5, 1e-4)

# Inputs that must be constant at load for the ops clss.Model runs without a
# handler of that name (model.graph.LOWERED_OPS).
LOWERED_CONST_INPUTS = {"Dropout": (1, 2), "Reshape": (1,), "Squeeze": (1,), "Unsqueeze": (1,),
                        "BatchNormalization": (1, 2, 3, 4), "Gemm": (1, 2)}
# Data inputs that are legitimately not float.
NON_FLOAT_INPUTS = {"Where": {0}, "ScatterElements": {1}}

MODEL_DEVIATIONS = {
    "test_training_dropout": "training-mode Dropout is random; clss runs inference graphs",
    "test_training_dropout_default": "training-mode Dropout is random; clss runs inference graphs",
    "test_training_dropout_default_mask": "training-mode Dropout is random; clss runs inference graphs",
    "test_training_dropout_mask": "training-mode Dropout is random; clss runs inference graphs",
}


def _const_positions(op: str) -> set:
    h = ONNX_HANDLERS.get(op)
    if h is not None:
        return set(h.const_inputs)
    return set(LOWERED_CONST_INPUTS.get(op, ()))


CASES = single_node_cases(set(ONNX_HANDLERS) | LOWERED_OPS)


def adapt(case_dir):
    """(model, feeds, expected, precision) ready for clss.Model and onnxruntime,
    or a skip reason. Cases on float16 data run in precision fp16 (half storage)."""
    m = onnx.load(os.path.join(case_dir, "model.onnx"))
    node = m.graph.node[0]
    if any(v.type.WhichOneof("value") != "tensor_type" for v in list(m.graph.input) + list(m.graph.output)):
        return "optional/sequence values: clss runs tensors only"
    if next(o.version for o in m.opset_import if o.domain in ("", "ai.onnx")) < MIN_OPSET:
        return f"opset < {MIN_OPSET}: clss runs opsets {MIN_OPSET}-{MAX_OPSET}"
    feeds, expected = load_case_data(case_dir, m)
    consts = _const_positions(node.op_type)
    floats = set()
    for i, name in enumerate(node.input):
        if not name or name not in feeds:
            continue
        x = feeds[name]
        if i not in consts and i not in NON_FLOAT_INPUTS.get(node.op_type, ()):
            floats.add(x.dtype)
    for e in expected:   # ml_dtypes' bfloat16, float8, int4, ... are not numpy's own
        if not (e.dtype.kind in "biu" and e.dtype.type.__module__ == "numpy"):
            floats.add(e.dtype)
    other = floats - {np.dtype(np.float32), np.dtype(np.float16)}
    if other:
        return f"{sorted(map(str, other))[0]} tensors: the kernels are float32/float16 only"
    for i, name in enumerate(node.input):
        if name and i in consts and name in feeds:
            m.graph.initializer.append(numpy_helper.from_array(feeds.pop(name), name))
            keep = [v for v in m.graph.input if v.name != name]
            del m.graph.input[:]
            m.graph.input.extend(keep)
    m.ir_version = min(m.ir_version, 10)
    return m, feeds, expected, "fp16" if np.dtype(np.float16) in floats else "fp32"


def _check(outs, refs, names, what, tol=NODE_TOL):
    assert len(outs) >= len(refs)
    for name, r in zip(names, refs):
        o = outs[name]
        assert o.shape == r.shape, f"{what}: output {name!r} shape {o.shape} != {r.shape}"
        if r.dtype.kind in "biu":
            assert np.array_equal(o.astype(r.dtype), r), f"{what}: output {name!r} integer values differ"
            continue
        c = compare(o, r.astype(np.float32), tol)
        assert c.passed, f"{what}: output {name!r} max abs {c.max_abs:.3g} err/tol {c.ratio:.3g} {c.detail}"


def test_node_cases_found():
    assert len(CASES) > 150, f"only {len(CASES)} node cases matched"


# On the second compiler the node cases run through the kernels in the default tier
# (tests/test_node_cases_kernels.py); through clss.Model there, in the slow tier (conftest).
@pytest.mark.slow_on_other_devices
@pytest.mark.parametrize("case_dir", CASES, ids=[os.path.basename(c) for c in CASES])
def test_model_node_case(case_dir, any_dev):
    name = os.path.basename(case_dir)
    got = adapt(case_dir)
    if isinstance(got, str):
        pytest.skip(got)
    model, feeds, expected, prec = got
    tol = NODE_TOL if prec == "fp32" else DEFAULT_TOL[prec]
    reason = MODEL_DEVIATIONS.get(name) or FAMILY_DEVIATIONS.get(name)
    try:
        cm = clss.Model(model, device=any_dev, precision=prec)
    except UnsupportedModelError as e:
        if reason:
            pytest.xfail(reason)
        pytest.fail(f"{name}: {e} (not listed in NODE_DEVIATIONS)")
    outs = cm.run(feeds)
    names = cm.output_names
    try:
        _check(outs, expected, names, "vs expected", tol)
    except AssertionError:
        if reason:
            pytest.xfail(reason)
        raise
    from clss.verify.twin import run_ort
    try:
        refs = run_ort(model, feeds)
    except Exception as e:  # onnxruntime lacks a few (op, opset) pairs
        pytest.skip(f"onnxruntime cannot run it: {str(e)[:200]}")
    _check(outs, refs, names, "vs onnxruntime", tol)
