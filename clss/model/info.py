"""What `clss info` reports about a loaded model: op histograms, parameter
count, FLOPs per inference at the resolved shapes, planned device memory.

FLOPs: a multiply-add counts 2 (Conv, ConvTranspose, MatMul, Gemm); other
arithmetic 1 per output element (a few per element for Softmax and
normalisations; 2 per tap for Resize/GridSample interpolation); pure data
movement (Concat, Slice, Pad, DepthToSpace, Reshape, ...) 0. Counted on the
ONNX graph as written (before clss's passes), so it is a property of the model.
"""
from __future__ import annotations

from collections import Counter

import numpy as np
import onnx
from onnx import helper

MOVEMENT = {"Concat", "Slice", "Pad", "Split", "Reshape", "Flatten", "Squeeze", "Unsqueeze", "Transpose",
            "DepthToSpace", "SpaceToDepth", "Identity", "Dropout", "Constant", "Shape", "Gather", "Cast",
            "ConstantOfShape", "Expand", "Tile", "Range", "Size", "ArgMax", "ScatterElements", "Where"}
PER_ELEMENT = {"Softmax": 3, "LogSoftmax": 3, "BatchNormalization": 2, "Clip": 1, "Sigmoid": 1, "Tanh": 1}


def _shapes(m: onnx.ModelProto) -> dict[str, tuple]:
    out = {}
    g = m.graph
    for vi in list(g.input) + list(g.value_info) + list(g.output):
        t = vi.type.tensor_type
        if t.HasField("shape") and all(d.HasField("dim_value") for d in t.shape.dim):
            out[vi.name] = tuple(d.dim_value for d in t.shape.dim)
    for t in g.initializer:
        out[t.name] = tuple(t.dims)
    return out


def _n(shape) -> int:
    return int(np.prod(shape, dtype=np.int64)) if shape is not None else 0


def node_flops(node: onnx.NodeProto, shapes: dict) -> int:
    op = node.op_type
    ins = [shapes.get(t) for t in node.input]
    out = shapes.get(node.output[0]) if node.output else None
    attrs = {a.name: helper.get_attribute_value(a) for a in node.attribute}
    if op == "Conv" and out and ins[1]:
        return 2 * _n(out) * _n(ins[1][1:])
    if op == "ConvTranspose" and ins[0] and ins[1]:
        return 2 * _n(ins[0]) * _n(ins[1][1:])
    if op == "MatMul" and out and ins[0]:
        return 2 * _n(out) * ins[0][-1]
    if op == "Gemm" and out and ins[0]:
        k = ins[0][0] if attrs.get("transA", 0) else ins[0][-1]
        return 2 * _n(out) * k
    if op in ("MaxPool", "AveragePool") and out:
        return _n(out) * _n(attrs.get("kernel_shape", ()))
    if op in ("GlobalAveragePool", "GlobalMaxPool") and ins[0]:
        return _n(ins[0])
    if op == "Resize" and out:
        mode = attrs.get("mode", b"nearest")
        mode = mode.decode() if isinstance(mode, bytes) else mode
        taps = {"nearest": 0, "linear": 4, "cubic": 16}.get(mode, 4)
        return 2 * taps * _n(out)
    if op == "GridSample" and out:
        mode = attrs.get("mode", b"bilinear")
        mode = mode.decode() if isinstance(mode, bytes) else mode
        taps = {"nearest": 0, "bilinear": 4, "linear": 4, "bicubic": 16, "cubic": 16}.get(mode, 4)
        return 2 * taps * _n(out)
    if op in MOVEMENT:
        return 0
    return PER_ELEMENT.get(op, 1) * _n(out)


def flops(m: onnx.ModelProto, known: dict | None = None) -> int:
    """FLOPs of one inference of a shape-resolved model (see module doc);
    ``known`` adds shapes resolved later (after constant folding)."""
    shapes = {**(known or {}), **_shapes(m)}
    return int(sum(node_flops(n, shapes) for n in m.graph.node))


def parameters(m: onnx.ModelProto) -> int:
    """Elements of the float initializers that are weights: those read by some
    node at a position its clss handler does not take as a load-time setting
    (Resize scales, Pad pads, Clip bounds are settings, not parameters)."""
    from ..ops import ONNX_HANDLERS
    settings_only: dict[str, bool] = {}
    for n in m.graph.node:
        h = ONNX_HANDLERS.get(n.op_type)
        for i, t in enumerate(n.input):
            setting = h is not None and i in h.const_inputs
            settings_only[t] = settings_only.get(t, True) and setting
    total = 0
    for t in m.graph.initializer:
        if t.data_type in (onnx.TensorProto.FLOAT, onnx.TensorProto.FLOAT16, onnx.TensorProto.DOUBLE) \
                and not settings_only.get(t.name, False):
            total += _n(tuple(t.dims))
    for n in m.graph.node:
        if n.op_type == "Constant":
            for a in n.attribute:
                if a.name == "value" and a.t.data_type == onnx.TensorProto.FLOAT \
                        and not all(settings_only.get(o, False) for o in n.output):
                    total += _n(tuple(a.t.dims))
    return int(total)


def summary(model) -> dict:
    """Everything `clss info` prints, for a loaded clss.Model."""
    m = model.onnx_model
    ops = Counter(n.op_type for n in m.graph.node)
    graph_in = {i.name: i for i in m.graph.input}
    return {
        "producer": f"{m.producer_name} {m.producer_version}".strip(),
        "ir_version": int(m.ir_version),
        "opset": model.opset,
        "inputs": {k: list(v) for k, v in model.input_shapes.items()},
        "input_types": {k: onnx.TensorProto.DataType.Name(graph_in[k].type.tensor_type.elem_type)
                        for k in model.input_shapes},
        "outputs": {k: list(v) for k, v in model.output_shapes.items()},
        "onnx_ops": dict(ops.most_common()),
        "onnx_nodes": int(sum(ops.values())),
        "execution": dict(model.execution_ops().most_common()),
        "passes": list(model.pass_log),
        "parameters": parameters(m),
        "flops": flops(m, model.graph.shapes),
        "precision": model.precision,
        "device": f"{model.device.info.platform} / {model.device.info.name}",
        "memory": model.memory(),
    }


def _mib(b: int) -> str:
    return f"{b / 2**20:.2f} MiB" if b >= 2**20 else f"{b / 2**10:.1f} KiB"


def _hist(d: dict) -> str:
    return ", ".join(f"{k} {v}" for k, v in d.items())


def format_summary(s: dict, name: str = "") -> str:
    mem = s["memory"]
    lines = [f"model: {name}  (opset {s['opset']}, IR {s['ir_version']}"
             + (f", producer {s['producer']})" if s["producer"] else ")")]
    for k, v in s["inputs"].items():
        lines.append(f"  input  {k}: {s['input_types'][k].lower()} {v}")
    for k, v in s["outputs"].items():
        lines.append(f"  output {k}: {v}")
    lines.append(f"ONNX ops ({s['onnx_nodes']} nodes): {_hist(s['onnx_ops'])}")
    steps = sum(v for k, v in s["execution"].items() if not k.startswith("view"))
    lines.append(f"runs as ({steps} kernel steps): {_hist(s['execution'])}")
    if s["passes"]:
        lines.append(f"passes: {'; '.join(s['passes'])}")
    lines.append(f"parameters: {s['parameters']:,}")
    f = s["flops"]
    lines.append(f"FLOPs per inference: {f / 1e9:.4g} GFLOP (multiply-add = 2)" if f >= 1e8 else
                 f"FLOPs per inference: {f / 1e6:.4g} MFLOP (multiply-add = 2)")
    lines.append(f"device memory ({s['precision']}, {s['device']}):")
    lines.append(f"  weights {_mib(mem['weights_bytes'])}; intermediates peak {_mib(mem['intermediate_peak_bytes'])} "
                 f"in {mem['intermediate_buffers']} shared buffers ({_mib(mem['intermediate_unshared_bytes'])} "
                 f"unshared); inputs {_mib(mem['input_bytes'])}; outputs {_mib(mem['output_bytes'])}"
                 + (f"; unplanned {_mib(mem['unplanned_bytes'])}" if mem["unplanned_bytes"] else ""))
    total = (mem["weights_bytes"] + mem["intermediate_peak_bytes"] + mem["input_bytes"] + mem["output_bytes"]
             + mem["unplanned_bytes"])
    lines.append(f"  planned peak device memory: {_mib(total)}")
    return "\n".join(lines)

