"""The ONNX backend node cases (onnx 1.22.0) through clss.Model, against the
cases' expected outputs and against onnxruntime on the same model.

Every single-node case whose op type clss runs (a registered handler, or an op
the model passes lower: BatchNormalization, Gemm, MatMul, Reshape, ...) is
collected. The harness adapts each case the way a deployed model differs
from a conformance test, and nothing else:
* inputs the kernels need at load (Resize scales, Pad pads, Reshape shape,
  BatchNorm statistics, Gemm's B and C) become initializers;
* cases written at opsets 22-25 run with their import set to 21 when the op's
  schema at 21 has the same inputs and attributes (22-25 only widened types);
* IR version 10, for onnxruntime.
Cases on non-float32 data are skipped as one category (the kernels are
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
from clss.model_graph import MAX_OPSET, MIN_OPSET, UnsupportedModelError
from clss.ops import ONNX_HANDLERS, load_all
from clss.ops.base import Tolerance, compare
from node_cases import load_case_data, single_node_cases

FAMILIES = load_all()
FAMILY_DEVIATIONS = {k: v for m in FAMILIES.values() for k, v in getattr(m, "NODE_DEVIATIONS", {}).items()}
NODE_TOL = Tolerance(1e-5, 1e-4)

# Ops clss.Model runs without a handler of that name (lowered by model_passes),
# with the inputs that must be constant at load.
LOWERED = {"Identity": (), "Dropout": (1, 2), "Reshape": (1,), "Flatten": (), "Squeeze": (1,),
           "Unsqueeze": (1,), "Transpose": (), "BatchNormalization": (1, 2, 3, 4), "Gemm": (1, 2),
           "MatMul": (), "Constant": ()}
# Data inputs that are legitimately not float.
NON_FLOAT_INPUTS = {"Where": {0}, "ScatterElements": {1}}

_TRANSPOSE = ("a general Transpose (no kernel): clss runs Transpose as a view when it only moves "
              "size-1 axes, and inside the PixelShuffle/PixelUnshuffle Reshape-Transpose-Reshape patterns")
MODEL_DEVIATIONS = {
    "test_batchnorm_epsilon_training_mode": "training-mode BatchNormalization: clss runs inference graphs",
    "test_batchnorm_example_training_mode": "training-mode BatchNormalization: clss runs inference graphs",
    "test_gemm_all_attributes": "Gemm transA=1 would need a general Transpose kernel",
    "test_gemm_transposeA": "Gemm transA=1 would need a general Transpose kernel",
    "test_matmul_bcast": "MatMul batch dims broadcast against each other ([3,1] x [1,2]); clss lowers "
                         "MatMul to convolutions, which need one side's batch to be 1 or both equal",
    **{f"test_transpose_all_permutations_{i}": _TRANSPOSE for i in range(1, 6)},
    "test_transpose_default": _TRANSPOSE,
    "test_training_dropout": "training-mode Dropout is random; clss runs inference graphs",
    "test_training_dropout_default": "training-mode Dropout is random; clss runs inference graphs",
    "test_training_dropout_default_mask": "training-mode Dropout is random; clss runs inference graphs",
    "test_training_dropout_mask": "training-mode Dropout is random; clss runs inference graphs",
    "test_training_dropout_zero_ratio": "training-mode Dropout: clss runs inference graphs",
    "test_training_dropout_zero_ratio_mask": "training-mode Dropout: clss runs inference graphs",
}


def _const_positions(op: str) -> set:
    h = ONNX_HANDLERS.get(op)
    if h is not None:
        return set(h.const_inputs)
    return set(LOWERED.get(op, ()))


CASES = single_node_cases(set(ONNX_HANDLERS) | set(LOWERED))


def _lower_opset(m: onnx.ModelProto, op: str):
    """Opset import down to 21 when the op's schema there takes the same inputs
    and attributes; None when it does not."""
    imp = next(o for o in m.opset_import if o.domain in ("", "ai.onnx"))
    if imp.version <= MAX_OPSET:
        return m
    new, old = onnx.defs.get_schema(op, imp.version), onnx.defs.get_schema(op, MAX_OPSET)
    if (set(new.attributes) != set(old.attributes)
            or [i.name for i in new.inputs] != [i.name for i in old.inputs]
            or [o.name for o in new.outputs] != [o.name for o in old.outputs]):
        return None
    imp.version = MAX_OPSET
    try:  # e.g. AveragePool's ceil_mode output size was corrected at opset 22
        onnx.shape_inference.infer_shapes(m, check_type=True, strict_mode=True)
    except Exception:
        return None
    return m


def adapt(case_dir):
    """(model, feeds, expected) ready for clss.Model and onnxruntime, or a skip reason."""
    m = onnx.load(os.path.join(case_dir, "model.onnx"))
    node = m.graph.node[0]
    if any(v.type.WhichOneof("value") != "tensor_type" for v in list(m.graph.input) + list(m.graph.output)):
        return "optional/sequence values: clss runs tensors only"
    if next(o.version for o in m.opset_import if o.domain in ("", "ai.onnx")) < MIN_OPSET:
        return f"opset < {MIN_OPSET}: clss runs opsets {MIN_OPSET}-{MAX_OPSET}"
    feeds, expected = load_case_data(case_dir, m)
    consts = _const_positions(node.op_type)
    for i, name in enumerate(node.input):
        if not name or name not in feeds:
            continue
        x = feeds[name]
        if i not in consts and i not in NON_FLOAT_INPUTS.get(node.op_type, ()) and x.dtype != np.float32:
            return f"{x.dtype} tensors: the kernels are float32/float16 only"
    for e in expected:
        if e.dtype.kind == "f" and e.dtype != np.float32:
            return f"{e.dtype} outputs: the kernels are float32/float16 only"
    for i, name in enumerate(node.input):
        if name and i in consts and name in feeds:
            m.graph.initializer.append(numpy_helper.from_array(feeds.pop(name), name))
            keep = [v for v in m.graph.input if v.name != name]
            del m.graph.input[:]
            m.graph.input.extend(keep)
    if _lower_opset(m, node.op_type) is None:
        return "the op's opset > 21 schema differs from opset 21; clss runs opsets 11-21"
    m.ir_version = min(m.ir_version, 10)
    return m, feeds, expected


def _check(outs, refs, names, what):
    assert len(outs) >= len(refs)
    for name, r in zip(names, refs):
        o = outs[name]
        assert o.shape == r.shape, f"{what}: output {name!r} shape {o.shape} != {r.shape}"
        if r.dtype.kind in "biu":
            assert np.array_equal(o.astype(r.dtype), r), f"{what}: output {name!r} integer values differ"
            continue
        c = compare(o, r.astype(np.float32), NODE_TOL)
        assert c.passed, f"{what}: output {name!r} max abs {c.max_abs:.3g} err/tol {c.ratio:.3g} {c.detail}"


def test_node_cases_found():
    assert len(CASES) > 150, f"only {len(CASES)} node cases matched"


@pytest.mark.parametrize("case_dir", CASES, ids=[os.path.basename(c) for c in CASES])
def test_model_node_case(case_dir, any_dev):
    name = os.path.basename(case_dir)
    got = adapt(case_dir)
    if isinstance(got, str):
        pytest.skip(got)
    model, feeds, expected = got
    reason = MODEL_DEVIATIONS.get(name) or FAMILY_DEVIATIONS.get(name)
    try:
        cm = clss.Model(model, device=any_dev)
    except UnsupportedModelError as e:
        if reason:
            pytest.xfail(reason)
        pytest.fail(f"{name}: {e} (not listed in NODE_DEVIATIONS)")
    outs = cm.run(feeds)
    names = cm.output_names
    try:
        _check(outs, expected, names, "vs expected")
    except AssertionError:
        if reason:
            pytest.xfail(reason)
        raise
    from clss.ops.twin import run_ort
    try:
        refs = run_ort(model, feeds)
    except Exception as e:  # onnxruntime lacks a few (op, opset) pairs
        pytest.skip(f"onnxruntime cannot run it: {str(e)[:200]}")
    _check(outs, refs, names, "vs onnxruntime")
