"""Building ONNX twins and running them on onnxruntime, the numerical oracle of the
conformance cases."""
from __future__ import annotations

import hashlib
import os
from typing import Sequence

import numpy as np
import onnx
from onnx import helper

from ..model.graph import fill_output_shapes

# onnx >= 1.23 writes IR 14 by default, which onnxruntime <= 1.31 rejects.
# IR 10 carries every opset clss runs (11-25; onnxruntime 1.32 runs them under it).
IR_VERSION = 10
DEFAULT_OPSET = 18


def _elem_type(dtype) -> int:
    return helper.np_dtype_to_tensor_dtype(np.dtype(dtype))


def make_model(nodes: Sequence[onnx.NodeProto], inputs: dict, outputs, *,
               initializers: dict | None = None, opset: int = DEFAULT_OPSET,
               name: str = "twin") -> onnx.ModelProto:
    """A checked model. ``inputs``: name -> example array (or (shape, dtype));
    ``outputs``: list of names (float32) or dict name -> dtype."""
    def vi(n, spec):
        if isinstance(spec, np.ndarray):
            return helper.make_tensor_value_info(n, _elem_type(spec.dtype), list(spec.shape))
        shape, dtype = spec
        return helper.make_tensor_value_info(n, _elem_type(dtype), shape)
    if not isinstance(outputs, dict):
        outputs = {o: np.float32 for o in outputs}
    graph = helper.make_graph(
        list(nodes), name,
        [vi(n, s) for n, s in inputs.items()],
        [helper.make_tensor_value_info(n, _elem_type(t), None) for n, t in outputs.items()],
        initializer=[onnx.numpy_helper.from_array(np.asarray(v), n)
                     for n, v in (initializers or {}).items()])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)],
                              producer_name="clss")
    model.ir_version = IR_VERSION
    fill_output_shapes(model)
    onnx.checker.check_model(model)
    return model


def node_model(op_type: str, inputs: dict, n_outputs: int = 1, *, out_dtypes=None,
               opset: int = DEFAULT_OPSET, initializers: dict | None = None, **attrs) -> onnx.ModelProto:
    """A one-node twin: graph inputs are ``inputs`` (in order), outputs y0, y1, ...
    Pass None as an input value to leave an optional input empty."""
    names = [("" if v is None else k) for k, v in inputs.items()]
    outs = [f"y{i}" for i in range(n_outputs)]
    node = helper.make_node(op_type, names, outs, **attrs)
    feeds = {k: v for k, v in inputs.items() if v is not None and k not in (initializers or {})}
    dts = out_dtypes or [np.float32] * n_outputs
    return make_model([node], feeds, dict(zip(outs, dts)), initializers=initializers, opset=opset,
                      name=op_type)


_sessions: dict[str, object] = {}


def session(model: onnx.ModelProto | bytes):
    import onnxruntime as ort
    data = model if isinstance(model, bytes) else model.SerializeToString()
    key = hashlib.sha1(data).hexdigest()
    s = _sessions.get(key)
    if s is None:
        so = ort.SessionOptions()
        so.intra_op_num_threads = int(os.environ.get("CLSS_ORT_THREADS", os.cpu_count() or 1))
        so.log_severity_level = 3
        s = ort.InferenceSession(data, so, providers=["CPUExecutionProvider"])
        if len(_sessions) > 256:  # twins are small, but hypothesis makes many
            _sessions.clear()
        _sessions[key] = s
    return s


def run_ort(model, feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
    s = session(model)
    names = {i.name for i in s.get_inputs()}
    return s.run(None, {k: v for k, v in feeds.items() if k in names})
