"""clss.Model: an ONNX graph run on an OpenCL device.

Load: onnx checker -> opset 11..21 -> static shapes (``input_shapes`` for
symbolic dims) -> size limits -> constant folding -> graph passes (Identity
removal, PixelShuffle patterns, BatchNorm folding, MatMul/Gemm as 1x1 convs,
Conv + activation (+ residual) fusion, 1x1 chains as one MLP kernel) -> a dry
run of every node that lists every unsupported one in one error -> a memory
plan that reuses intermediate buffers by liveness. Weights go to the device
once, in the precision's storage type.

    m = clss.Model("net.onnx", precision="fp16", input_shapes={"x": (1, 27, 64, 64)})
    outs = m.run({"x": x})               # numpy in, float32 numpy out
    douts = m.run_device({"x": x_dev})   # pyopencl arrays in and out, no host copies
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Mapping

import numpy as np
import pyopencl.array as cla

from ..device import Device, get_device, storage_dtype
from .execute import Executor
from .graph import FLOAT_TYPES, InputError, ModelError, UnsupportedModelError, build
from .. import selfcheck
from . import layout
from .passes import fuse_gated_conv, fuse_lstm_cell, lstm_cell_graph, run_passes

__all__ = ["Model", "ModelError", "InputError", "UnsupportedModelError"]


PLANS_KEPT = 2


class Model:
    """An ONNX model loaded for one device and precision.

    model: path, bytes or onnx.ModelProto. device: a clss Device, an index or
    name substring (see `clss devices`), or None for the default. precision:
    "fp32", "fp16" (half storage, float arithmetic) or "fp16-native".
    input_shapes: {input name: shape} for inputs with symbolic dimensions
    (a shape is a tuple or a string like "1x3x64x64")."""

    def __init__(self, model, device=None, precision: str = "fp32", input_shapes: dict | None = None,
                 *, fuse: bool = True):
        from ..ops import load_all
        self.device: Device = get_device(device)
        self.device.require(precision)
        self.precision = precision
        load_all()
        storage = storage_dtype(precision)
        graph, self.onnx_model, self.input_shapes = build(
            model, input_shapes, max_alloc=self.device.info.max_alloc, storage_itemsize=storage.itemsize)
        self.input_names = list(graph.inputs)
        self.output_names = list(graph.outputs)
        self.output_shapes = {t: tuple(graph.shapes[t]) for t in graph.outputs}
        self._in_dtypes = {t: _host_dtype(graph.elem_types.get(t), graph.dtypes[t]) for t in graph.inputs}
        self._out_dtypes = {t: _host_dtype(graph.elem_types.get(t), graph.dtypes.get(t, np.dtype("f4")))
                            for t in graph.outputs}
        self.pass_log = run_passes(graph, conv_fusion=fuse, mlp_fusion=fuse)
        if fuse and selfcheck.enabled(self.device, precision, LSTM_CELL):
            n = fuse_lstm_cell(graph)
            if n:
                self.pass_log.append(f"lstm_cell: {n}")
        if fuse and layout.enabled(self.device, precision):
            from ..ops.conv import vector_width
            if selfcheck.enabled(self.device, precision, GATED_CONV):
                n = fuse_gated_conv(graph, vector_width(self.device))
                if n:
                    self.pass_log.append(f"gated_conv: {n}")
            n = layout.apply(graph, vector_width(self.device),
                             thin=selfcheck.enabled(self.device, precision, "conv.thin"))
            if n:
                self.pass_log.append(f"blocked_layout: {n}")
        self.graph = graph
        self._exec = Executor(graph, self.device, precision)
        self._exec.trace()
        self._launch_plan = None        # (bound buffers, commands, outputs): see run_device
        self._launch_plans: list = []   # the last PLANS_KEPT plans, most recent last

    # -- introspection ----------------------------------------------------------------
    @property
    def opset(self) -> int:
        return self.graph.opset

    @property
    def plan(self):
        """The memory plan (clss.model.plan.Plan): peak_bytes, buffers, ..."""
        return self._exec.plan

    def memory(self) -> dict:
        """Device bytes: weights (constants uploaded once), intermediates (the
        planned shared buffers: the peak), outputs (fresh per run), inputs."""
        p = self._exec.plan
        st = storage_dtype(self.precision).itemsize
        ins = sum(int(np.prod(s)) * (st if self._in_dtypes[t].kind == "f" else self._in_dtypes[t].itemsize)
                  for t, s in self.input_shapes.items())
        return {"weights_bytes": self._exec.weight_bytes,
                "intermediate_peak_bytes": p.peak_bytes, "intermediate_buffers": len(p.slots),
                "intermediate_unshared_bytes": p.unshared_bytes, "output_bytes": p.output_bytes,
                "unplanned_bytes": p.unplanned_bytes, "input_bytes": int(ins)}

    def execution_ops(self) -> Counter:
        """What runs, after the passes: fused forms spelled out (Conv+Add+relu, MLP(3))."""
        c = Counter()
        for n in self.graph.nodes:
            c[_label(n)] += 1
        return c

    def __repr__(self) -> str:
        return (f"<clss.Model {len(self.graph.nodes)} steps, inputs {self.input_shapes}, "
                f"{self.precision} on {self.device.info.name}>")

    # -- running ----------------------------------------------------------------------
    def run(self, inputs: Mapping) -> dict:
        """numpy arrays in (float32; float16 also accepted in the half precisions),
        numpy arrays out (float outputs as float32)."""
        douts = self._run(self.upload(inputs), None)
        return {k: _to_host(v, self._out_dtypes[k]) for k, v in douts.items()}

    def upload(self, inputs: Mapping) -> dict:
        """numpy inputs (checked as for run()) -> the device arrays run_device() takes:
        the precision's storage type, except GridSample grids, which stay float32."""
        feeds = self._check_host(inputs)
        return {k: self.device.to_device(v, "fp32" if k in self._exec.fp32_inputs else self.precision)
                for k, v in feeds.items()}

    def run_device(self, inputs: Mapping, out: Mapping | None = None, events: list | None = None) -> dict:
        """pyopencl arrays in and out, on this model's device and queue: float
        tensors in the precision's storage type (float32, or float16 in the half
        precisions; graph inputs used only as GridSample grids stay float32: see
        upload()), C-contiguous, offset 0. Returns fresh output arrays per
        call, or writes into ``out`` (name -> array) where given. Work is queued,
        not waited for (the device queue is in order): no finish, no host read.
        ``events``: a list that gets the event of every command enqueued.

        With ``out`` naming every output, the run is a launch plan: the first call
        with a set of input and output buffers records every launch with its
        arguments bound (clss.device.Launch); later calls with the same buffers
        replay it, one enqueue per launch and nothing else (a frame step's networks).
        The last PLANS_KEPT plans are kept: a caller that alternates between two
        buffer sets (a frame step's double-buffered stack) replays both instead of recording
        again every call (the intermediates are the load-time memory plan's, shared)."""
        feeds = self._check_device(inputs)
        if out is not None:
            self._check_out(out)
        if out is None or set(out) != set(self.output_names):
            return self._run(dict(feeds), out, events)
        # The buffers the plan is bound to (held, so that none is freed and its
        # address reused by another array while the plan refers to it).
        key = [feeds[k].base_data for k in self.input_names] + [out[k].base_data for k in self.output_names]
        plan = next((p for p in reversed(self._launch_plans) if len(p[0]) == len(key)
                     and all(a is b for a, b in zip(p[0], key))), None)
        if plan is None:
            record = []
            res = self._run(dict(feeds), out, events, record)
            plan = (key, record, {k: out[k] for k in self.output_names})
            self._launch_plans = (self._launch_plans + [plan])[-PLANS_KEPT:]
            self._launch_plan = plan
            return res
        self._launch_plan = plan
        for cmd in plan[1]:
            e = cmd()
            if events is not None and e is not None:
                events.append(e)
        return dict(plan[2])

    __call__ = run

    def _run(self, env: dict, out: Mapping | None, events=None, record=None) -> dict:
        res = self._exec.run(env, dict(out) if out else None, record, events)
        for k, a in (out or {}).items():
            src = res[k]
            if src.base_data is not a.base_data:    # not written in place: copy (recorded too)
                self._exec.pdev.recording, self._exec.pdev.events = record, events
                try:
                    self._exec.pdev.copy(a, src)
                finally:
                    self._exec.pdev.recording = self._exec.pdev.events = None
            res[k] = a
        return res

    # -- input checks -----------------------------------------------------------------
    def _names(self, inputs: Mapping):
        if not isinstance(inputs, Mapping):
            raise InputError(f"inputs must be a dict name -> array; the model's inputs are "
                             f"{', '.join(map(repr, self.input_names))}")
        extra = [k for k in inputs if k not in self.input_names]
        if extra:
            raise InputError(f"unknown input {extra[0]!r}; the model's inputs are "
                             f"{', '.join(map(repr, self.input_names))}")
        missing = [k for k in self.input_names if k not in inputs]
        if missing:
            raise InputError(f"missing input {missing[0]!r} ({self._expect(missing[0])})")

    def _expect(self, name: str, dtype=None) -> str:
        dt = dtype or self._in_dtypes[name]
        return f"expected {dt} array of shape {tuple(self.input_shapes[name])}"

    def _check_host(self, inputs: Mapping) -> dict:
        self._names(inputs)
        feeds = {}
        for name in self.input_names:
            v = inputs[name]
            if isinstance(v, cla.Array):
                raise InputError(f"input {name!r} is a device array; use run_device() for those")
            a = np.asarray(v)
            want = self._in_dtypes[name]
            ok = a.dtype == want or (want == np.float32 and a.dtype == np.float16
                                     and self.precision != "fp32")
            if not ok:
                raise InputError(f"input {name!r}: {self._expect(name)}, got {a.dtype} array of shape "
                                 f"{a.shape}")
            if tuple(a.shape) != tuple(self.input_shapes[name]):
                raise InputError(f"input {name!r}: {self._expect(name)}, got shape {a.shape}")
            feeds[name] = a
        return feeds

    def _device_dtype(self, name):
        want = self._in_dtypes[name]
        if name in self._exec.fp32_inputs:   # GridSample grids stay float32 (model/execute.py)
            return np.dtype(np.float32)
        return storage_dtype(self.precision) if want.kind == "f" else want

    def _check_device(self, inputs: Mapping) -> dict:
        self._names(inputs)
        for name in self.input_names:
            a = inputs[name]
            want = self._device_dtype(name)
            if not isinstance(a, cla.Array):
                raise InputError(f"input {name!r}: run_device() takes pyopencl arrays "
                                 f"({self._expect(name, want)}), got {type(a).__name__}; use run() "
                                 "for numpy arrays")
            self._check_array(f"input {name!r}", a, want, self.input_shapes[name])
        return inputs

    def _check_array(self, what, a, want, shape):
        if a.dtype != want or tuple(a.shape) != tuple(shape):
            raise InputError(f"{what}: expected {want} array of shape {tuple(shape)} "
                             f"(precision {self.precision}), got {a.dtype} array of shape {a.shape}")
        if a.offset != 0 or not a.flags.c_contiguous:
            raise InputError(f"{what}: must be C-contiguous with offset 0 (copy it first)")
        if a.context != self.device.context:
            raise InputError(f"{what}: lives in another OpenCL context than the model's device "
                             f"({self.device.info.name})")

    def _check_out(self, out: Mapping) -> None:
        for k, a in out.items():
            if k not in self.output_names:
                raise InputError(f"out names {k!r}, which is not an output; outputs are "
                                 f"{', '.join(map(repr, self.output_names))}")
            want = self._out_dtypes[k]
            want = storage_dtype(self.precision) if want.kind == "f" else want
            if not isinstance(a, cla.Array):
                raise InputError(f"out[{k!r}] must be a pyopencl array")
            self._check_array(f"out[{k!r}]", a, want, self.output_shapes[k])


def _host_dtype(elem_type, fallback: np.dtype) -> np.dtype:
    if elem_type in FLOAT_TYPES:
        return np.dtype(np.float32)
    return np.dtype(fallback)


def _to_host(a: cla.Array, want: np.dtype) -> np.ndarray:
    h = a.get()
    return h.astype(want, copy=False) if h.dtype != want else h


def _label(n) -> str:
    if n.op == "clss.Conv":
        s = "ConvTranspose" if n.attrs.get("transpose") else "Conv"
        if n.inputs[3]:
            s += "+Add"
        if n.attrs["activation"] != "none":
            s += "+" + n.attrs["activation"]
        if n.attrs.get("gated"):        # passes.fuse_gated_conv: times a gate conv's sigmoid
            s += "*sigmoid"
        return s
    if n.op == "clss.MLP":
        return f"MLP({len(n.attrs['layers'])} layers)"
    if n.op == "clss.BinaryRelu":
        return n.attrs["op"].capitalize() + "+relu"
    if n.op == "clss.View":
        return "view (no kernel)"
    return n.op.replace("clss.", "")


# --- the blocked layout's fast path (clss/model/layout.py) -------------------------------
# Registered here, where Model is: its check runs a small graph through a Model.

def _blocked_layout_check(dev, prec: str) -> list:
    from ..ops.base import rng
    m = Model(layout.check_graph(), device=dev, precision=prec)
    x = rng("blocked layout selfcheck input").standard_normal((1, 9, 6, 22)).astype(np.float32)
    out = m.run({"x": x})
    return [out["y"], out["y2"]]


def _register_blocked_layout():
    from .. import selfcheck
    from ..tolerance import DEFAULT_TOL
    selfcheck.register(selfcheck.FastPath(
        "model.blocked_layout", "conv", {"OUT_BLOCKED": 1}, {"OUT_BLOCKED": 0}, check=_blocked_layout_check,
        tolerance=DEFAULT_TOL.__getitem__,
        what="chains of blocked convs, 2x2 max pools, nearest resizes and channel concats keep the "
             "channel-blocked layout between layers, and concats of NCHW channel ranges (times a "
             "one-channel map) write it directly (clss/model/layout.py) / a layout transform per conv",
        applies=lambda dev: dev.is_cpu))


_register_blocked_layout()


# --- the fused ConvLSTM cell's fast path (passes.fuse_lstm_cell, kernels/lstm.cl) ----------

LSTM_CELL = "model.lstm_cell"


def _lstm_cell_check(dev, prec: str) -> list:
    from ..ops.base import rng
    g = rng("lstm cell selfcheck")
    feeds = {"x": g.standard_normal((1, 8, 5, 13)).astype(np.float32),
             "c": g.standard_normal((1, 16, 5, 13)).astype(np.float32)}
    out = Model(lstm_cell_graph((1, 8, 5, 13), 16, conv=True), device=dev, precision=prec).run(feeds)
    return [out["h"], out["c_out"]]


def _register_graph_path(name: str, family: str, option: str, check, what: str, **kw):
    """A fast path of clss.Model's graph rewriting: on (-D<option>=1) / off, checked by
    running a small graph through a Model, at the default tolerance."""
    from ..tolerance import DEFAULT_TOL
    selfcheck.register(selfcheck.FastPath(name, family, {option: 1}, {option: 0}, check=check,
                                          tolerance=DEFAULT_TOL.__getitem__, what=what, **kw))


_register_graph_path(
    LSTM_CELL, "lstm", "LSTM_CELL", _lstm_cell_check,
    "a ConvLSTM cell's Split, Sigmoid, Tanh, Mul and Add nodes as one kernel reading the gates "
    "where their conv left them (blocked or NCHW) / the ten nodes")


# --- gated convolutions (passes.fuse_gated_conv, kernels/conv.cl -DGATED) ----------------

GATED_CONV = "model.gated_conv"


def gated_conv_graph(cin: int = 18, h: int = 5, w: int = 29):
    """NSRD's gated conv twice (16 and 32 channels: one and two vector pairs per work-item
    group) as ONNX: LeakyRelu(Conv_f(x)) * Sigmoid(Conv_g(x)), the second without bias
    and with the Mul's inputs swapped. The fast path's self-check graph."""
    from onnx import TensorProto, helper, numpy_helper

    from ..ops.base import rng
    g = rng("gated conv graph", cin, h, w)
    inits, nodes = [], []
    cv = dict(kernel_shape=[3, 3], pads=[1, 1, 1, 1])
    for k, (c, bias, swap) in enumerate(((16, True, False), (32, False, True))):
        for role in "fg":
            inits.append(numpy_helper.from_array((g.standard_normal((c, cin, 3, 3)) * 0.2).astype(np.float32),
                                                 f"w{role}{k}"))
            if bias:
                inits.append(numpy_helper.from_array((g.standard_normal(c) * 0.1).astype(np.float32), f"b{role}{k}"))
        nodes += [helper.make_node("Conv", ["x", f"wf{k}"] + ([f"bf{k}"] if bias else []), [f"cf{k}"], **cv),
                  helper.make_node("LeakyRelu", [f"cf{k}"], [f"af{k}"], alpha=0.1),
                  helper.make_node("Conv", ["x", f"wg{k}"] + ([f"bg{k}"] if bias else []), [f"cg{k}"], **cv),
                  helper.make_node("Sigmoid", [f"cg{k}"], [f"ag{k}"]),
                  helper.make_node("Mul", [f"ag{k}", f"af{k}"] if swap else [f"af{k}", f"ag{k}"], [f"y{k}"])]
    vi = helper.make_tensor_value_info
    graph = helper.make_graph(nodes, "gated_conv", [vi("x", TensorProto.FLOAT, [1, cin, h, w])],
                              [vi("y0", TensorProto.FLOAT, [1, 16, h, w]), vi("y1", TensorProto.FLOAT, [1, 32, h, w])],
                              inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    return m


def _gated_conv_check(dev, prec: str) -> list:
    from ..ops.base import rng
    x = rng("gated conv selfcheck").standard_normal((1, 18, 5, 29)).astype(np.float32)
    out = Model(gated_conv_graph(), device=dev, precision=prec).run({"x": x})
    return [out["y0"], out["y1"]]


_register_graph_path(
    GATED_CONV, "conv", "GATED", _gated_conv_check,
    "act(conv_f(x)) * sigmoid(conv_g(x)) as one blocked conv whose work-items hold a block of "
    "features and its gates and write their product / two convs and a Mul", applies=lambda dev: dev.is_cpu)
