"""The ONNX backend node test cases shipped with onnx 1.22.0: discovery and loading,
shared by test_node_cases_kernels.py (the kernels) and test_node_cases_model.py (clss.Model)."""
from __future__ import annotations

import glob
import os

import onnx
from onnx import numpy_helper

NODE_DIR = os.path.join(os.path.dirname(onnx.__file__), "backend", "test", "data", "node")


def single_node_cases(ops) -> list[str]:
    """Directories of the non-expanded cases whose one node has an op type in ``ops``."""
    out = []
    if not os.path.isdir(NODE_DIR):
        return out
    for d in sorted(glob.glob(os.path.join(NODE_DIR, "test_*"))):
        base = os.path.basename(d)
        if base.endswith("_expanded") or "_expanded_" in base:
            continue
        m = onnx.load(os.path.join(d, "model.onnx"), load_external_data=False)
        if len(m.graph.node) == 1 and m.graph.node[0].op_type in ops and not m.graph.node[0].domain:
            out.append(d)
    return out


def load_case_data(d, model):
    """(feeds by graph input name, expected outputs) of the case's first data set."""
    data = sorted(glob.glob(os.path.join(d, "test_data_set_*")))[0]
    ins = [numpy_helper.to_array(onnx.load_tensor(f)) for f in sorted(glob.glob(os.path.join(data, "input_*.pb")))]
    outs = [numpy_helper.to_array(onnx.load_tensor(f)) for f in sorted(glob.glob(os.path.join(data, "output_*.pb")))]
    return dict(zip([i.name for i in model.graph.input], ins)), outs
