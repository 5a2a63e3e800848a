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

from collections import Counter, OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import pyopencl.array as cla

from ..device import Device, get_device, storage_dtype
from ..errors import UserError
from .execute import Executor
from .graph import (FLOAT_TYPES, Graph, InputError, ModelError, UnsupportedModelError, ValueUse,
                    find_value_inputs, finish, prepare, unknown_ops, with_values)
from .graph import _np_dtype
from .. import selfcheck
from . import layout
from .passes import (fuse_conv_depth_to_space, fuse_gated_conv, fuse_lstm_cell, lstm_cell_graph,
                     run_passes)

__all__ = ["Model", "ModelError", "InputError", "UnsupportedModelError"]


PLANS_KEPT = 2
# Plans kept for the values of a model's value inputs (the current one included).
VALUE_PLANS_KEPT = 4


@dataclass
class Specialisation:
    """The model built and planned for one set of value-input values (none for most
    models): the static graph, the passes' log, the executor with its memory plan and
    uploaded weights, and run_device's launch plans."""
    values: dict
    graph: Graph
    onnx_model: object
    pass_log: list
    executor: Executor
    output_shapes: dict
    out_dtypes: dict
    launch_plans: list = field(default_factory=list)   # the last PLANS_KEPT, most recent last
    launch_plan: object = None


class Model:
    """An ONNX model loaded for one device and precision.

    model: path, bytes or onnx.ModelProto. device: a clss Device, an index or
    name substring (see `clss devices`), or None for the default. precision:
    "fp32", "fp16" (half storage, float arithmetic) or "fp16-native".
    input_shapes: {input name: shape} for inputs with symbolic dimensions
    (a shape is a tuple or a string like "1x3x64x64").

    Value inputs (``value_inputs``): graph inputs whose values decide shapes or how a
    kernel is set up (Resize scales or sizes, a Reshape shape, Slice starts, Pad pads,
    ...). Their values are read from each run's feeds (run_device: a small read from the
    device) and the model is built and planned for them, again when they change; the
    last VALUE_PLANS_KEPT plans are kept. input_values: {name: array} plans for those
    values at load, and a run that leaves such an input out uses them. graph,
    output_shapes, plan, memory() and pass_log describe the current plan."""

    def __init__(self, model, device=None, precision: str = "fp32", input_shapes: dict | None = None,
                 *, input_values: Mapping | None = None, fuse: bool = True):
        from ..ops import load_all
        self.device: Device = get_device(device)
        self.device.require(precision)
        self.precision = precision
        self._fuse = fuse
        load_all()
        proto, self._opset, self.input_shapes = prepare(model, input_shapes)
        self.input_names = list(self.input_shapes)
        self.output_names = [o.name for o in proto.graph.output]
        types = {i.name: i.type.tensor_type.elem_type for i in proto.graph.input}
        self._elem_types = {t: types[t] for t in self.input_names}
        self._in_dtypes = {t: _host_dtype(et, _np_dtype(et)) for t, et in self._elem_types.items()}
        self.value_inputs: dict[str, list[ValueUse]] = find_value_inputs(proto, self._opset)
        self._specs: OrderedDict = OrderedDict()
        self._spec: Specialisation | None = None
        self._proto = proto if self.value_inputs else None   # what each plan starts from
        self._default_values = self._load_values(input_values)
        if not self.value_inputs:
            self._select({}, proto)
        elif self._default_values:
            self._select(self._default_values)
        else:   # the values come with the first run: what can be checked now, is
            bad = unknown_ops(proto, self._opset, known=set(self.value_inputs))
            if bad:
                raise UnsupportedModelError(bad)

    def _load_values(self, input_values) -> dict:
        """input_values= checked (names, dtypes, shapes) and in the declared types."""
        if not input_values:
            return {}
        if not isinstance(input_values, Mapping):
            raise ModelError("input_values must be a dict name -> array")
        for k in input_values:
            if k not in self.input_names:
                raise ModelError(f"input_values names {k!r}, which the model does not have; its inputs are "
                                 f"{', '.join(map(repr, self.input_names))}")
            if k not in self.value_inputs:
                raise ModelError(f"input_values names {k!r}, whose values decide no shape: it is given at "
                                 f"each run; {self._value_list()}")
        missing = [k for k in self.value_inputs if k not in input_values]
        if missing:
            raise ModelError(f"input_values leaves out {', '.join(map(repr, missing))}: the model is "
                             f"planned for every value input at once; {self._value_list()}")
        out = {}
        for k, v in input_values.items():
            if isinstance(v, cla.Array):
                v = v.get()
            a = np.asarray(v)
            if not self._dtype_ok(k, a.dtype) or tuple(a.shape) != tuple(self.input_shapes[k]):
                raise ModelError(f"input_values[{k!r}]: {self._expect(k)}, got {a.dtype} array of shape "
                                 f"{a.shape}")
            out[k] = self._declared(k, a)
        return out

    def _value_list(self) -> str:
        if not self.value_inputs:
            return "this model has no inputs whose values decide shapes"
        return "the inputs whose values decide shapes are " + "; ".join(
            f"{k!r} ({us[0].describe()})" for k, us in self.value_inputs.items())

    def _declared(self, name: str, a: np.ndarray) -> np.ndarray:
        """A value input's array in its declared ONNX type (the plan's key and constant)."""
        a = np.asarray(a).astype(_np_dtype(self._elem_types[name]), copy=False)
        return np.ascontiguousarray(a).reshape(a.shape)   # (ascontiguousarray makes 0-d arrays 1-d)

    # -- plans per value-input values -----------------------------------------------------
    def _select(self, values: dict, proto=None) -> Specialisation:
        """The plan for these value-input values (declared types): kept, or built now."""
        key = tuple((k, values[k].dtype.str, values[k].shape, values[k].tobytes()) for k in self.value_inputs)
        spec = self._specs.get(key)
        if spec is None:
            try:
                spec = self._specialise(values, proto)
            except UserError as e:
                if values:
                    _prefix(e, "planning for input_values " + _show(values) + ": ",
                            "planning for the values of --input " + _show(values) + ": ")
                raise
            self._specs[key] = spec
            while len(self._specs) > VALUE_PLANS_KEPT:
                self._specs.popitem(last=False)
        else:
            self._specs.move_to_end(key)
        self._spec = spec
        return spec

    def _specialise(self, values: dict, proto=None) -> Specialisation:
        storage = storage_dtype(self.precision)
        proto = with_values(self._proto, values) if proto is None else proto
        graph, onnx_model = finish(proto, self._opset, max_alloc=self.device.info.max_alloc,
                                   storage_itemsize=storage.itemsize)
        output_shapes = {t: tuple(graph.shapes[t]) for t in graph.outputs}
        out_dtypes = {t: _host_dtype(graph.elem_types.get(t), graph.dtypes.get(t, np.dtype("f4")))
                      for t in graph.outputs}
        fuse = self._fuse
        pass_log = run_passes(graph, conv_fusion=fuse, mlp_fusion=fuse)
        if fuse and selfcheck.enabled(self.device, self.precision, LSTM_CELL):
            n = fuse_lstm_cell(graph)
            if n:
                pass_log.append(f"lstm_cell: {n}")
        if fuse and layout.enabled(self.device, self.precision):
            from ..ops.conv import vector_width
            if selfcheck.enabled(self.device, self.precision, GATED_CONV):
                n = fuse_gated_conv(graph, vector_width(self.device))
                if n:
                    pass_log.append(f"gated_conv: {n}")
            n = layout.apply(graph, vector_width(self.device),
                             thin=selfcheck.enabled(self.device, self.precision, "conv.thin"))
            if n:
                pass_log.append(f"blocked_layout: {n}")
        if fuse:        # after the layout: only the convs that stay NCHW store a shuffle
            n = fuse_conv_depth_to_space(graph)
            if n:
                pass_log.append(f"conv_depth_to_space: {n}")
        ex = Executor(graph, self.device, self.precision)
        ex.trace()
        return Specialisation(dict(values), graph, onnx_model, pass_log, ex, output_shapes, out_dtypes)

    def _current(self) -> Specialisation:
        if self._spec is None:
            names = ", ".join(map(repr, self.value_inputs))
            raise ModelError(
                f"this model's shapes depend on the values of {names}; it is planned at the first run, "
                f"or at load with input_values={{...}} ({self._value_list()})",
                cli=f"this model's shapes depend on the values of {names}; it is planned for them when "
                    "they come, as `clss run` gives them: --input "
                    + " --input ".join(f"{k}=FILE.npy" for k in self.value_inputs))
        return self._spec

    @property
    def input_values(self) -> dict:
        """The value inputs' values the current plan is for ({} for most models)."""
        return dict(self._current().values)

    # The current plan's parts (see Specialisation).
    graph = property(lambda self: self._current().graph)
    onnx_model = property(lambda self: self._current().onnx_model)
    pass_log = property(lambda self: self._current().pass_log)
    output_shapes = property(lambda self: self._current().output_shapes)
    _exec = property(lambda self: self._current().executor)
    _out_dtypes = property(lambda self: self._current().out_dtypes)
    _launch_plan = property(lambda self: self._current().launch_plan)
    _launch_plans = property(lambda self: self._current().launch_plans)

    # -- introspection ----------------------------------------------------------------
    @property
    def opset(self) -> int:
        return self._opset

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
                  for t, s in self.input_shapes.items() if t not in self.value_inputs)
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
        steps = f"{len(self._spec.graph.nodes)} steps" if self._spec else "not planned yet"
        return (f"<clss.Model {steps}, inputs {self.input_shapes}, "
                f"{self.precision} on {self.device.info.name}>")

    # -- running ----------------------------------------------------------------------
    def run(self, inputs: Mapping) -> dict:
        """numpy arrays in (float32; float16 also accepted in the half precisions),
        numpy arrays out (float outputs as float32)."""
        feeds = self._check_host(inputs)
        spec = self._select(self._values_of(feeds))
        douts = self._run(spec, self._upload(spec, feeds), None)
        return {k: _to_host(v, spec.out_dtypes[k]) for k, v in douts.items()}

    def upload(self, inputs: Mapping) -> dict:
        """numpy inputs (checked as for run()) -> the device arrays run_device() takes:
        the precision's storage type, except GridSample grids, which stay float32, and
        value inputs, which keep their type (float32 for float ones)."""
        feeds = self._check_host(inputs)
        spec = self._select(self._values_of(feeds))
        out = self._upload(spec, feeds)
        for k in self.value_inputs:
            if k in feeds:
                out[k] = self.device.to_device(feeds[k].astype(self._in_dtypes[k], copy=False), "fp32")
        return out

    def _upload(self, spec: Specialisation, feeds: dict) -> dict:
        fp32 = spec.executor.fp32_inputs
        return {k: self.device.to_device(feeds[k], "fp32" if k in fp32 else self.precision)
                for k in spec.graph.inputs}

    def _values_of(self, feeds: dict) -> dict:
        vals = dict(self._default_values)
        for k in self.value_inputs:
            if k in feeds:
                vals[k] = self._declared(k, feeds[k])
        return vals

    def run_device(self, inputs: Mapping, out: Mapping | None = None, events: list | None = None) -> dict:
        """pyopencl arrays in and out, on this model's device and queue: float
        tensors in the precision's storage type (float32, or float16 in the half
        precisions; graph inputs used only as GridSample grids stay float32, and value
        inputs keep their type: see upload()), C-contiguous, offset 0. Returns fresh
        output arrays per call, or writes into ``out`` (name -> array) where given. Work
        is queued, not waited for (the device queue is in order): no finish, no host
        read, except the value inputs' (see the class): a model that has them reads
        them back at each call, which waits for the queue. ``events``: a list that gets
        the event of every command enqueued.

        With ``out`` naming every output, the run is a launch plan: the first call
        with a set of input and output buffers records every launch with its
        arguments bound (clss.device.Launch); later calls with the same buffers
        replay it, one enqueue per launch and nothing else (a frame step's networks).
        The last PLANS_KEPT plans are kept: a caller that alternates between two
        buffer sets (a frame step's double-buffered stack) replays both instead of recording
        again every call (the intermediates are the load-time memory plan's, shared)."""
        self._names(inputs)
        values = dict(self._default_values)
        for k in self.value_inputs:
            if k in inputs:
                a = inputs[k]
                self._check_device_type(k, a, self._in_dtypes[k])
                values[k] = self._declared(k, a.get())
        spec = self._select(values)
        feeds = self._check_device(inputs, spec)
        if out is not None:
            self._check_out(out)
        if out is None or set(out) != set(self.output_names):
            return self._run(spec, dict(feeds), out, events)
        # The buffers the plan is bound to (held, so that none is freed and its
        # address reused by another array while the plan refers to it).
        key = [feeds[k].base_data for k in spec.graph.inputs] + [out[k].base_data for k in self.output_names]
        plan = next((p for p in reversed(spec.launch_plans) if len(p[0]) == len(key)
                     and all(a is b for a, b in zip(p[0], key))), None)
        if plan is None:
            record = []
            res = self._run(spec, dict(feeds), out, events, record)
            plan = (key, record, {k: out[k] for k in self.output_names})
            spec.launch_plans = (spec.launch_plans + [plan])[-PLANS_KEPT:]
            spec.launch_plan = plan
            return res
        spec.launch_plan = plan
        for cmd in plan[1]:
            e = cmd()
            if events is not None and e is not None:
                events.append(e)
        return dict(plan[2])

    __call__ = run

    def _run(self, spec: Specialisation, env: dict, out: Mapping | None, events=None, record=None) -> dict:
        ex = spec.executor
        env = {k: env[k] for k in spec.graph.inputs}
        res = ex.run(env, dict(out) if out else None, record, events)
        for k, a in (out or {}).items():
            src = res[k]
            if src.base_data is not a.base_data:    # not written in place: copy (recorded too)
                ex.pdev.recording, ex.pdev.events = record, events
                try:
                    ex.pdev.copy(a, src)
                finally:
                    ex.pdev.recording = ex.pdev.events = None
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
        missing = [k for k in self.input_names if k not in inputs and k not in self._default_values]
        if missing:
            raise InputError(f"missing input {missing[0]!r} ({self._expect(missing[0])})")

    def _expect(self, name: str, dtype=None) -> str:
        dt = dtype or self._in_dtypes[name]
        return f"expected {dt} array of shape {tuple(self.input_shapes[name])}"

    def _dtype_ok(self, name: str, dtype) -> bool:
        want = self._in_dtypes[name]
        return dtype == want or (want == np.float32 and dtype == np.float16 and self.precision != "fp32")

    def _check_host(self, inputs: Mapping) -> dict:
        self._names(inputs)
        feeds = {}
        for name in self.input_names:
            if name not in inputs:   # a value input given at load (input_values=)
                continue
            v = inputs[name]
            if isinstance(v, cla.Array):
                raise InputError(f"input {name!r} is a device array; use run_device() for those")
            a = np.asarray(v)
            if not self._dtype_ok(name, a.dtype):
                raise InputError(f"input {name!r}: {self._expect(name)}, got {a.dtype} array of shape "
                                 f"{a.shape}")
            if tuple(a.shape) != tuple(self.input_shapes[name]):
                raise InputError(f"input {name!r}: {self._expect(name)}, got shape {a.shape}")
            feeds[name] = a
        return feeds

    def _device_dtype(self, name, spec: Specialisation):
        want = self._in_dtypes[name]
        if name in spec.executor.fp32_inputs:   # GridSample grids stay float32 (model/execute.py)
            return np.dtype(np.float32)
        return storage_dtype(self.precision) if want.kind == "f" else want

    def _check_device_type(self, name, a, want):
        if not isinstance(a, cla.Array):
            raise InputError(f"input {name!r}: run_device() takes pyopencl arrays "
                             f"({self._expect(name, want)}), got {type(a).__name__}; use run() "
                             "for numpy arrays")
        self._check_array(f"input {name!r}", a, want, self.input_shapes[name])

    def _check_device(self, inputs: Mapping, spec: Specialisation) -> dict:
        for name in spec.graph.inputs:
            self._check_device_type(name, inputs[name], self._device_dtype(name, spec))
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


def _show(values: dict) -> str:
    return ", ".join(f"{k}={np.array2string(np.asarray(v), threshold=16, separator=', ')}"
                     for k, v in values.items())


def _prefix(e: UserError, text: str, cli: str) -> None:
    """Say which values a plan was for, in an error raised while making it."""
    e.args = (text + str(e),) + tuple(e.args[1:])
    e.cli = cli + (e.cli or str(e.args[0])[len(text):])


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
