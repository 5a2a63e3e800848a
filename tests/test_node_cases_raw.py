"""The ONNX backend node cases (onnx 1.22.0) as shipped, through clss.Model: graph inputs
stay inputs (Resize scales, a Reshape shape, Clip bounds, BatchNorm statistics, ... are
fed at run: clss.Model plans for the values of the ones that decide shapes, see
docs/model.md "Inputs that determine shapes"), and the ``_expanded`` variants (a
function written out as nodes: Softmax as ReduceMax, Sub, Exp, ReduceSum, Div; a
LayerNormalization with its Shape, ConstantOfShape and Reshape nodes) run too. Each is
checked against the case's expected outputs and against onnxruntime.

Which cases: every one whose node op types are all ones clss runs (a handler, an op the
passes lower), folds (Shape, Size, ConstantOfShape, Range: computed at load from shapes
and value inputs) or is getting (INCOMING: the ops of issue 49's part 1). Skipped, with
the reason, as test_node_cases_model.py does: cases on integer, float64, bfloat16/float8
or sequence data, opsets below 11. Cases on float16 data run in precision fp16.

A case refused with an UnsupportedModelError fails unless its name is in a deviations
table with the reason (the families' NODE_DEVIATIONS, test_node_cases_model's
MODEL_DEVIATIONS, RAW_DEVIATIONS below). `python tests/node_case_report.py` prints the
count: how many run, how many are wrong, refused (by op) or skipped.
"""
from __future__ import annotations

import glob
import os
import re

import numpy as np
import onnx
import pytest

import clss
from clss.model.graph import LOWERED_OPS, MAX_OPSET, MIN_OPSET, ModelError, UnsupportedModelError
from clss.ops import ONNX_HANDLERS, load_all
from clss.tolerance import DEFAULT_TOL, Tolerance, compare
from node_cases import NODE_DIR, load_case_data
from test_node_cases_model import _check

FAMILIES = load_all()
FAMILY_DEVIATIONS = {k: v for m in FAMILIES.values() for k, v in getattr(m, "NODE_DEVIATIONS", {}).items()}
NODE_TOL = Tolerance(1e-5, 1e-4)

# The ops issue 49's part 1 adds (some are in ONNX_HANDLERS already).
INCOMING = frozenset({
    "ReduceMean", "ReduceSum", "ReduceMax", "ReduceMin", "ReduceL1", "ReduceL2", "ReduceLogSum",
    "ReduceLogSumExp", "ReduceSumSquare", "ReduceProd", "Softmax", "LogSoftmax", "HardSwish", "HardSigmoid",
    "Gelu", "Erf", "Log", "Reciprocal", "Softplus", "Softsign", "Pow", "LayerNormalization",
    "InstanceNormalization", "GroupNormalization", "MatMul", "Gemm", "Clip", "Tile"})
# Ops with no kernel that clss computes at load when their inputs are known (constants,
# shapes, value inputs): the expanded functions use them on shapes.
FOLDED = frozenset({"Shape", "Size", "ConstantOfShape", "Range"})
RUN_OPS = frozenset(ONNX_HANDLERS) | LOWERED_OPS | INCOMING | FOLDED

# Data inputs that are legitimately not float: (op, input position).
NON_FLOAT_INPUTS = {("Where", 0), ("ScatterElements", 1)}

MODEL_DEVIATIONS = {
    "test_training_dropout": "training-mode Dropout is random; clss runs inference graphs",
    "test_training_dropout_default": "training-mode Dropout is random; clss runs inference graphs",
    "test_training_dropout_default_mask": "training-mode Dropout is random; clss runs inference graphs",
    "test_training_dropout_mask": "training-mode Dropout is random; clss runs inference graphs",
}
# Deviations only the cases as shipped have.
RAW_DEVIATIONS: dict[str, str] = {
    "test_range_float_type_positive_delta": "written at opset 27, where Range changed: past the opsets clss knows "
                                            "(11-25), the model is refused naming the node",
    "test_range_float16_type_positive_delta": "written at opset 27, where Range changed: past the opsets clss knows "
                                              "(11-25), the model is refused naming the node",
}


def deviation(name: str) -> str | None:
    """The listed reason a case may fail, if any; an expanded case shares its op's."""
    base = re.sub(r"_expanded(_ver\d+)?$", "", name)
    for n in (name, base):
        r = RAW_DEVIATIONS.get(n) or MODEL_DEVIATIONS.get(n) or FAMILY_DEVIATIONS.get(n)
        if r:
            return r
    return None


def raw_cases() -> list[str]:
    """Every case directory whose node op types are all in RUN_OPS (expanded included)."""
    out = []
    for d in sorted(glob.glob(os.path.join(NODE_DIR, "test_*"))):
        m = onnx.load(os.path.join(d, "model.onnx"), load_external_data=False)
        if m.graph.node and all(n.op_type in RUN_OPS and n.domain in ("", "ai.onnx") for n in m.graph.node):
            out.append(d)
    return out


CASES = raw_cases()


def _differs_from_adapted(case_dir) -> bool:
    """Whether the case as shipped is not what test_node_cases_model.py runs already: an
    expanded function, a multi-node case, or a graph input the adapted harness turns into an
    initializer (a Resize scales, a Reshape shape, Clip bounds: the value inputs)."""
    name = os.path.basename(case_dir)
    if "_expanded" in name:
        return True
    m = onnx.load(os.path.join(case_dir, "model.onnx"), load_external_data=False)
    if len(m.graph.node) != 1:
        return True
    from test_node_cases_model import _const_positions
    n = m.graph.node[0]
    inputs = {v.name for v in m.graph.input}
    return any(t in inputs for i, t in enumerate(n.input) if t and i in _const_positions(n.op_type))


# The parametrised test runs the cases that differ from test_node_cases_model.py's (which
# runs the rest, on every device), on the default device; node_case_report.py counts all.
DIFFERING = [c for c in CASES if _differs_from_adapted(c)]


def _ok_float(dt: np.dtype) -> bool:
    return dt in (np.dtype(np.float32), np.dtype(np.float16))


def adapt(case_dir):
    """(model, feeds, expected, precision), or a skip reason. The model as shipped, its
    IR version at most 10 (onnxruntime's)."""
    m = onnx.load(os.path.join(case_dir, "model.onnx"))
    if any(v.type.WhichOneof("value") != "tensor_type" for v in list(m.graph.input) + list(m.graph.output)):
        return "optional/sequence values: clss runs tensors only"
    if next(o.version for o in m.opset_import if o.domain in ("", "ai.onnx")) < MIN_OPSET:
        return f"opset < {MIN_OPSET}: clss runs opsets {MIN_OPSET}-{MAX_OPSET}"
    feeds, expected = load_case_data(case_dir, m)
    floats = set()
    for e in expected:   # ml_dtypes' bfloat16, float8, int4, ... are not numpy's own
        if not (e.dtype.kind in "biu" and e.dtype.type.__module__ == "numpy"):
            floats.add(e.dtype)
    # Inputs whose values clss plans for may be of any numeric type; the others are data.
    value_inputs = _value_inputs(m)
    uses: dict[str, set] = {}
    for n in m.graph.node:
        for i, t in enumerate(n.input):
            uses.setdefault(t, set()).add((n.op_type, i))
    for name, x in feeds.items():
        if name in value_inputs:
            if x.dtype.kind == "f" and not _ok_float(x.dtype) and x.dtype != np.float64:
                floats.add(x.dtype)
            continue
        if x.dtype.kind == "f" or not (uses.get(name) and uses[name] <= NON_FLOAT_INPUTS):
            floats.add(x.dtype)
    for n in m.graph.node:   # an expanded function that computes in float64 inside
        to = next((a.i for a in n.attribute if a.name == "to"), None) if n.op_type == "Cast" else None
        if to == onnx.TensorProto.DOUBLE:
            floats.add(np.dtype(np.float64))
    other = {d for d in floats if not _ok_float(d)}
    if other:
        return f"{sorted(map(str, other))[0]} tensors: the kernels are float32/float16 only"
    m.ir_version = min(m.ir_version, 10)
    return m, feeds, expected, "fp16" if np.dtype(np.float16) in floats else "fp32"


def _value_inputs(m) -> set:
    """The graph inputs clss plans for (clss.model.graph.find_value_inputs); none when
    the model does not even load that far (the run says why)."""
    from clss.model.graph import find_value_inputs, prepare
    try:
        p, opset, _ = prepare(m)
        return set(find_value_inputs(p, opset))
    except (ModelError, UnsupportedModelError):
        return set()


def run_case(case_dir, dev=None) -> tuple[str, str]:
    """(outcome, detail): "pass", "skip", "refused" (UnsupportedModelError; detail: the op
    types it names, comma-separated, then the message), "error" (any other error at load
    or run), "wrong" (vs the expected outputs), "wrong-ort" (right vs expected, not vs
    onnxruntime), "pass-no-ort" (onnxruntime cannot run the case)."""
    got = adapt(case_dir)
    if isinstance(got, str):
        return "skip", got
    model, feeds, expected, prec = got
    tol = NODE_TOL if prec == "fp32" else DEFAULT_TOL[prec]
    try:
        cm = clss.Model(model, device=dev, precision=prec)
        outs = cm.run(feeds)
    except UnsupportedModelError as e:
        ops = sorted({n[1] for n in e.nodes})
        return "refused", ",".join(ops) + "\n" + str(e)
    except Exception as e:   # noqa: BLE001 (a report of every case)
        return "error", f"{type(e).__name__}: {e}"
    names = cm.output_names
    try:
        _check(outs, expected, names, "vs expected", tol)
    except AssertionError as e:
        return "wrong", str(e)
    from clss.verify.twin import run_ort
    try:
        refs = run_ort(model, feeds)
    except Exception as e:  # noqa: BLE001 (onnxruntime lacks a few (op, opset) pairs)
        return "pass-no-ort", f"onnxruntime cannot run it: {str(e)[:200]}"
    try:
        _check(outs, refs, names, "vs onnxruntime", tol)
    except AssertionError as e:
        return "wrong-ort", str(e)
    return "pass", ""


def test_raw_cases_found():
    names = {os.path.basename(c) for c in CASES}
    assert len(CASES) > 500, f"only {len(CASES)} node cases matched"
    # the expanded functions and the shape-input cases are in
    assert {"test_softmax_axis_0_expanded", "test_layer_normalization_2d_axis0_expanded",
            "test_resize_upsample_scales_linear", "test_reshape_extended_dims",
            "test_slice_start_out_of_bounds", "test_expand_dim_changed", "test_clip"} <= names


@pytest.mark.parametrize("case_dir", DIFFERING, ids=[os.path.basename(c) for c in DIFFERING])
def test_raw_node_case(case_dir, dev):
    name = os.path.basename(case_dir)
    outcome, detail = run_case(case_dir, dev)
    if outcome == "skip":
        pytest.skip(detail)
    if outcome == "pass-no-ort":
        pytest.skip(detail)
    if outcome == "pass":
        return
    reason = deviation(name)
    if reason and outcome in ("refused", "wrong", "error"):
        pytest.xfail(reason)
    if outcome == "refused":
        pytest.fail(f"{name}: refused: {detail.partition(chr(10))[2]} (not listed in the deviations)")
    pytest.fail(f"{name}: {outcome}: {detail}")
