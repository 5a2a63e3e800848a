"""The ONNX backend node test cases (shipped with onnx 1.22.0) through the kernels.

Every single-node case whose op type has a registered handler runs in fp32 and
is compared with the case's expected outputs. A case the kernels do not cover
must be listed, with its reason, in the family's NODE_DEVIATIONS (clss/ops/<family>.py);
an unlisted Unsupported is a failure. Cases on float16 data run in precision
fp16; cases on other non-float32 tensors (double, integer and bool data; the
kernels are float32/float16 only) are skipped as one documented category.
"""
from __future__ import annotations

import os

import numpy as np
import pytest

from clss.ops import ONNX_HANDLERS, Unsupported, load_all
from clss.ops.base import node_attrs
from clss.tolerance import DEFAULT_TOL, Tolerance, compare

onnx = pytest.importorskip("onnx")
from node_cases import NODE_DIR, load_case_data, single_node_cases  # noqa: E402

FAMILIES = load_all()
DEVIATIONS = {k: v for m in FAMILIES.values() for k, v in getattr(m, "NODE_DEVIATIONS", {}).items()}
# onnx's own backend runner uses rtol=1e-3, atol=1e-7; ours is tighter in scale terms.
NODE_TOL = Tolerance(1e-5, 1e-4)
# Data inputs that are legitimately not float: Where's condition, ScatterElements' indices.
NON_FLOAT_INPUTS = {"Where": {0}, "ScatterElements": {1}}


CASES = single_node_cases(ONNX_HANDLERS)


def test_node_cases_found():
    assert len(CASES) > 100, f"only {len(CASES)} node cases matched {NODE_DIR}"


@pytest.mark.parametrize("case_dir", CASES, ids=[os.path.basename(c) for c in CASES])
def test_node_case(case_dir, any_dev):
    name = os.path.basename(case_dir)
    model = onnx.load(os.path.join(case_dir, "model.onnx"))
    node = model.graph.node[0]
    handler = ONNX_HANDLERS[node.op_type]
    if name in DEVIATIONS:  # before loading: some listed cases hold non-tensor inputs
        pytest.xfail(DEVIATIONS[name])
    feeds, expected = load_case_data(case_dir, model)
    inputs = [feeds.get(n) if n else None for n in node.input]
    floats = {x.dtype for i, x in enumerate(inputs) if x is not None and i not in handler.const_inputs
              and i not in NON_FLOAT_INPUTS.get(node.op_type, ())}
    other = floats - {np.dtype(np.float32), np.dtype(np.float16)}
    if other:
        pytest.skip(f"{sorted(map(str, other))[0]} tensors: the kernels are float32/float16 only")
    # float16 data: half storage (precision fp16) and its tolerance
    prec, tol = ("fp16", DEFAULT_TOL["fp16"]) if np.dtype(np.float16) in floats else ("fp32", NODE_TOL)
    dev_inputs = [None if x is None else (x if i in handler.const_inputs else any_dev.to_device(x, prec))
                  for i, x in enumerate(inputs)]
    attrs = node_attrs(node)
    if node.op_type == "Split":  # opset 18 splits into as many parts as the node has outputs
        attrs.setdefault("num_outputs", len(node.output))
    try:
        outs = handler.fn(any_dev, prec, attrs, dev_inputs)
    except Unsupported as e:
        pytest.fail(f"{name}: Unsupported ({e}) and not listed in NODE_DEVIATIONS")
    outs = [any_dev.to_host(o) for o in outs]
    assert len(outs) >= len(expected)
    for i, (o, r) in enumerate(zip(outs, expected)):
        assert o.shape == r.shape, f"output {i}: shape {o.shape} != expected {r.shape}"
        if r.dtype.kind in "biu":
            assert np.array_equal(o.astype(r.dtype), r), f"output {i}: integer/bool values differ"
            continue
        c = compare(o.astype(np.float32), r.astype(np.float32), tol)
        assert c.passed, f"output {i}: max abs {c.max_abs:.3g} err/tol {c.ratio:.3g} {c.detail}"
