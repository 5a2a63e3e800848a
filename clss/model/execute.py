"""Running a static graph on the device: how each node is called, the load-time
dry run that validates every node and records its allocations, and the
planned runs that reuse buffers.

Every node, ONNX op or internal "clss.*" op, runs through one calling
convention: fn(dev, prec, attrs, inputs) -> list of device arrays (see
clss/ops/base.py). Handlers allocate with dev.empty; the ``dev`` they get is a
PlannedDevice, which during the dry run records those calls (and turns
launches into no-ops) and during real runs hands back the planned buffers.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ..device import Device, storage_dtype
from ..ops.base import ONNX_HANDLERS, OnnxHandler, Unsupported
from .graph import LOWERED_OPS, NO_KERNEL, Graph, ModelError, Node, UnsupportedModelError, custom_domain_reason
from .plan import Alloc, Plan, assign_slots, check_plan

# --- internal ops -------------------------------------------------------------------

INTERNAL: dict[str, OnnxHandler] = {}


def internal_op(op_type: str, const_inputs=()):
    def deco(fn):
        INTERNAL[op_type] = OnnxHandler(op_type, fn, frozenset(const_inputs), "clss")
        return fn
    return deco


def handler_for(op: str) -> OnnxHandler | None:
    return INTERNAL.get(op) or ONNX_HANDLERS.get(op)


@internal_op("clss.View")
def _view(dev, prec, attrs, inputs):
    """Reshape/Flatten/Squeeze/Unsqueeze and size-1 transposes: the same bytes
    under a new shape (a view; the planner keeps the buffer alive for it)."""
    return [inputs[0].reshape(tuple(attrs["shape"]))]


@internal_op("clss.Copy")
def _copy(dev, prec, attrs, inputs):
    """A graph output that is another graph output, input or constant."""
    x = inputs[0]
    out = dev.empty(x.shape, prec, dtype=x.dtype)
    dev.copy(out, x)
    return [out]


@internal_op("clss.SpaceToDepth")
def _s2d(dev, prec, attrs, inputs):
    """pixel_unshuffle (CRD), which ONNX SpaceToDepth (DCR only) cannot say."""
    from ..ops.space_to_depth import space_to_depth
    return [space_to_depth(dev, prec, inputs[0], int(attrs["blocksize"]), attrs.get("mode", "DCR"))]


def _family(name: str):
    """A kernel family module, or Unsupported when this checkout lacks it (the
    dry run then falls back to the unfused ONNX nodes)."""
    import importlib
    try:
        return importlib.import_module(f"clss.ops.{name}")
    except ModuleNotFoundError as e:
        if e.name == f"clss.ops.{name}":
            raise Unsupported(f"kernel family {name!r} is missing (clss/ops/{name}.py)") from None
        raise


@internal_op("clss.Conv")
def _conv(dev, prec, attrs, inputs):
    """Conv with its fused epilogue: act(conv(x, w) + b + residual), a DepthToSpace stored
    shuffled (attrs "d2s", passes.fuse_conv_depth_to_space)."""
    conv = _family("conv")
    x, w, b, r = (list(inputs) + [None] * 4)[:4]
    kw = dict(strides=attrs["strides"], pads=attrs["pads"], dilations=attrs["dilations"],
              group=attrs["group"], activation=attrs["activation"], alpha=attrs["alpha"], residual=r)
    if attrs.get("transpose"):
        return [conv.conv_transpose2d(dev, prec, x, w, b, output_padding=attrs["output_padding"], **kw)]
    return [conv.conv2d(dev, prec, x, w, b, packed=attrs.setdefault("_packed", {}),
                        out_blocked=bool(attrs.get("blocked_out")), gated=bool(attrs.get("gated")),
                        depth_to_space=attrs.get("d2s"), **kw)]


@internal_op("clss.ConcatBlocked")
def _concat_blocked(dev, prec, attrs, inputs):
    """A channel concat of NCHW tensors (or channel ranges of them: absorbed Slices; or
    such a tensor times a one-channel map: an absorbed Mul) written in the blocked layout
    for the blocked convs it feeds (clss/model/layout.py). Its inputs: one per range,
    then the scale maps that attrs["scales"] index."""
    conv = _family("conv")
    ranges = attrs["ranges"]
    xs, extra = list(inputs[:len(ranges)]), list(inputs[len(ranges):])
    # absorbed Muls: (index into the inputs after the data ones, channel) per data input
    scales = [None if sc is None else (extra[sc[0]], sc[1]) for sc in attrs.get("scales", [None] * len(xs))]
    return [conv.concat_to_blocked(dev, prec, xs, attrs["block"], ranges, scales)]


@internal_op("clss.LSTMCell")
def _lstm_cell(dev, prec, attrs, inputs):
    """A ConvLSTM cell's pointwise half (passes.fuse_lstm_cell): (h', c') from the gates,
    NCHW or channel-blocked (clss/model/layout.py), and c."""
    lstm = _family("lstm")
    return list(lstm.lstm_cell(dev, prec, inputs[0], inputs[1], tuple(attrs["order"])))


@internal_op("clss.BinaryRelu")
def _binary_relu(dev, prec, attrs, inputs):
    """Relu(a op b) in one kernel (the binary_relu pass)."""
    elementwise = _family("elementwise")
    return [elementwise.binary(dev, prec, attrs["op"], inputs[0], inputs[1], relu=True)]


@internal_op("clss.MaxPool")
def _max_pool(dev, prec, attrs, inputs):
    """MaxPool whose Indices output nobody reads: the values alone."""
    pool = _family("pool")
    x = inputs[0]
    if attrs.get("blocked"):   # a channel-blocked input (clss/model/layout.py)
        return [pool.max_pool(dev, prec, x, **pool._pool_attrs(attrs, 2), blocked=True)]
    return [pool.max_pool(dev, prec, x, **pool._pool_attrs(attrs, x.ndim - 2))]


@internal_op("clss.MLP")
def _mlp(dev, prec, attrs, inputs):
    """A chain of pointwise convolutions in one kernel (clss/ops/mlp.py); the
    layers are packed on the device once, at the first (dry) call."""
    mlp = _family("mlp")
    packed = attrs.setdefault("_packed", {})
    if prec not in packed:
        layers = [(w, b, (act, alpha)) for w, b, act, alpha in attrs["layers"]]
        packed[prec] = mlp.pack(getattr(dev, "base", dev), prec, layers)
    return [mlp.mlp(dev, prec, inputs[0], packed[prec])]


def packed_bytes(attrs: dict) -> int:
    """Device bytes of weights an internal op packed for itself."""
    total = 0
    for w in attrs.get("_packed", {}).values():
        total += w.nbytes if hasattr(w, "nbytes") else sum(c.buffer.nbytes for c in getattr(w, "chunks", ()))
    return total


# --- the device the handlers see ----------------------------------------------------

class PlannedDevice(Device):
    """The model's Device as handlers see it. Shares the real device's context,
    queue and program cache; intercepts allocation, uploads and (dry) launches."""

    def __init__(self, base: Device):  # noqa: super().__init__ would make a new context
        self.__dict__.update(base.__dict__)
        self.base = base
        self.dry = False
        self.node = -1
        self._cursor = 0
        self._upload_cursor = 0
        self.records: list[tuple] = []          # dry: (shape, dtype, array) per empty() call
        self.planned: dict[tuple[int, int], tuple] = {}  # (node, call) -> (shape, dtype, array|None)
        self.uploads: dict[tuple[int, int], tuple] = {}  # (node, call) -> (host, device)
        self.unplanned = 0
        self._kernel_memo: dict = {}
        # A recorded run (Executor.run(record=...)): every launch and copy becomes a
        # command with its arguments bound, kept in `recording`, and its event goes to
        # `events` where that is a list.
        self.recording: list | None = None
        self.events: list | None = None
        self.override: dict = {}    # (node, call) -> the caller's array for that allocation

    def begin(self, node: int) -> None:
        self.node, self._cursor, self._upload_cursor = node, 0, 0
        self.records = []

    def empty(self, shape, precision: str = "fp32", dtype=None):
        dt = np.dtype(dtype) if dtype is not None else storage_dtype(precision)
        shape = tuple(int(s) for s in shape)
        if self.dry:
            a = self.base.empty(shape, precision, dt)
            self.records.append((shape, dt, a))
            return a
        key = (self.node, self._cursor)
        self._cursor += 1
        o = self.override.get(key)
        if o is not None and o.shape == shape and o.dtype == dt:
            return o
        p = self.planned.get(key)
        if p is not None and p[0] == shape and p[1] == dt:
            return p[2] if p[2] is not None else self.base.empty(shape, precision, dt)
        self.unplanned += 1
        if self.unplanned == 1:
            warnings.warn(f"node {self.node} allocated {shape} {dt} outside the load-time plan "
                          "(a handler whose allocations differ between calls); running unplanned")
        return self.base.empty(shape, precision, dt)

    def to_device(self, a, precision: str = "fp32"):
        """Handlers upload constant inputs (they arrive as numpy) on every call;
        the same bytes at the same call site are uploaded once and kept."""
        key = (self.node, self._upload_cursor)
        self._upload_cursor += 1
        a = np.asarray(a)
        hit = self.uploads.get(key)
        if hit is not None:
            host, devarr = hit
            if host is a or (host.shape == a.shape and host.dtype == a.dtype and np.array_equal(host, a)):
                return devarr
        devarr = self.base.to_device(a, precision)
        self.uploads[key] = (a.copy(), devarr)
        return devarr

    def kernel(self, stem: str, name: str, precision: str = "fp32", **defines):
        """Device.kernel re-reads and hashes the source on every call; a loaded
        model's kernels do not change under it, so they are looked up once."""
        key = (stem, name, precision, tuple(sorted(defines.items())))
        k = self._kernel_memo.get(key)
        if k is None:
            k = self.base.kernel(stem, name, precision, **defines)
            self._kernel_memo[key] = k
        return k

    def launch(self, kernel, global_size, args, local_size=None, wait_for=None):
        if self.dry:
            # A completed event, should a handler wait on what it launched.
            e = cl.UserEvent(self.context)
            e.set_status(cl.command_execution_status.COMPLETE)
            return e
        if self.recording is None:
            e = self.base.launch(kernel, global_size, args, local_size, wait_for)
        else:
            # wait_for is not kept: the queue is in order, so a replay keeps the order anyway
            cmd = self.base.prepare(kernel, global_size, args, local_size)
            self.recording.append(cmd)
            e = cmd(wait_for)
        if self.events is not None:
            self.events.append(e)
        return e

    def copy(self, dst, src):
        """dst <- src, as Device.copy; recorded in a recorded run, as a launch is."""
        if not self.dry:
            return self._command(lambda: self.base.copy(dst, src))

    def fill(self, a, value):
        """a <- value, as Device.fill; recorded in a recorded run."""
        if not self.dry:
            self._command(lambda: self.base.fill(a, value))

    def _command(self, cmd):
        if self.recording is not None:
            self.recording.append(cmd)
        e = cmd()
        if self.events is not None and e is not None:
            self.events.append(e)
        return e


# --- prepared nodes -----------------------------------------------------------------


def _last_use(g: Graph) -> dict[str, int]:
    """Index of the last node that reads each tensor."""
    last: dict[str, int] = {}
    for i, node in enumerate(g.nodes):
        for t in node.inputs:
            if t:
                last[t] = i
    return last

@dataclass
class Step:
    """A node ready to call: handler, and where each input comes from."""
    node: Node
    fn: object
    sources: list              # per input: ("none",) | ("host", ndarray) | ("dev", name)
    outputs: list[str]
    expect: dict = field(default_factory=dict)   # output index -> planned buffer ptr (checked)
    release: list = field(default_factory=list)  # tensors dead after this step


def storage_ptr(a) -> int | None:
    b = a.base_data
    return None if b is None else b.int_ptr


def _unsupported_reason(e: Exception) -> str:
    if isinstance(e, Unsupported):
        return str(e)
    return f"{type(e).__name__}: {e}"


class Executor:
    """Validates, plans and runs a Graph on one device and precision."""

    def __init__(self, graph: Graph, dev: Device, prec: str):
        self.g = graph
        self.base = dev
        self.prec = prec
        self.pdev = PlannedDevice(dev)
        # Graph inputs used only as GridSample grids stay float32 in the half precisions:
        # they are coordinates, and half would move samples by up to 1/8 pixel at 1080p.
        uses: dict[str, list] = {}
        for n in graph.nodes:
            for i, t in enumerate(n.inputs):
                uses.setdefault(t, []).append((n.op, i))
        self.fp32_inputs = set() if prec == "fp32" else {
            t for t in graph.inputs if graph.dtypes[t].kind == "f" and uses.get(t)
            and all(op == "GridSample" and i == 1 for op, i in uses[t])}
        self.const_dev: dict[str, cla.Array] = {}   # constants used as device tensors
        self.steps: list[Step] = []
        self.plan = Plan()
        self.output_allocs: dict = {}

    # -- constants ------------------------------------------------------------------
    def const_array(self, name: str) -> cla.Array:
        a = self.const_dev.get(name)
        if a is None:
            a = self.base.to_device(self.g.consts[name], self.prec)
            self.const_dev[name] = a
        return a

    @property
    def weight_bytes(self) -> int:
        """Constants on the device: uploaded by the model, packed by fused ops,
        or uploaded (once) by handlers."""
        return int(sum(a.nbytes for a in self.const_dev.values())
                   + sum(packed_bytes(n.attrs) for n in self.g.nodes)
                   + sum(d.nbytes for _, d in self.pdev.uploads.values()))

    # -- the dry run ----------------------------------------------------------------
    def _step(self, node: Node) -> Step:
        """Raises Unsupported when the node cannot be set up."""
        h = handler_for(node.op)
        if node.domain and not node.op.startswith("clss."):
            raise Unsupported(custom_domain_reason(node.domain))
        if h is None:
            if node.op in LOWERED_OPS:
                raise Unsupported(f"clss runs {node.op} only in the forms its load-time passes rewrite "
                                  "(see the README's clss.Model section); not this one")
            raise Unsupported(NO_KERNEL)
        g = self.g
        for t in list(node.inputs) + list(node.outputs):
            if t and t not in g.consts and g.dtypes.get(t) == np.float64:
                raise Unsupported(f"tensor {t!r} is float64; clss kernels are float32/float16")
        sources = []
        for i, t in enumerate(node.inputs):
            if not t:
                sources.append(("none",))
            elif i in h.const_inputs:
                if t not in g.consts:
                    raise Unsupported(f"input {i} ({t!r}) must be a constant (known at load); "
                                      "here it depends on the graph's inputs")
                sources.append(("host", g.consts[t]))
            elif t in g.consts:
                sources.append(("const", t))
            else:
                sources.append(("dev", t))
        return Step(node, h.fn, sources, list(node.outputs))

    def _inputs(self, step: Step, env: dict) -> list:
        out = []
        for s in step.sources:
            k = s[0]
            if k == "dev":
                out.append(env[s[1]])
            elif k == "host":
                out.append(s[1])
            elif k == "const":
                out.append(self.const_array(s[1]))
            else:
                out.append(None)
        return out

    def _placeholder(self, t: str):
        dt = self.g.dtypes[t]
        if t in self.fp32_inputs:
            return self.base.empty(self.g.shapes[t], "fp32")
        return self.base.empty(self.g.shapes[t], self.prec, None if dt.kind == "f" else dt)

    def live_bytes(self) -> int:
        """Largest sum of tensor bytes live at any one step, from the resolved
        shapes alone (no allocation): what the plan can at best reach."""
        g = self.g
        st = storage_dtype(self.prec).itemsize
        size = {}
        for t, shape in g.shapes.items():
            dt = g.dtypes.get(t, np.dtype(np.float32))
            size[t] = int(np.prod(shape, dtype=np.int64)) * (st if dt.kind == "f" else dt.itemsize)
        last = _last_use(g)
        end = len(g.nodes)
        for t in g.outputs:
            last[t] = end
        live, peak = {t: size.get(t, 0) for t in g.inputs}, 0
        for i, n in enumerate(g.nodes):
            for t in n.outputs:
                if t:
                    live[t] = size.get(t, 0)
            peak = max(peak, sum(live.values()))
            for t in list(live):
                if last.get(t, -1) <= i:
                    del live[t]
        consts = sum(size.get(t, 0) for t in g.consts)
        return peak + consts

    def check_memory(self) -> None:
        need = self.live_bytes()
        have = self.base.info.global_mem
        if need > have:
            raise ModelError(f"the model needs at least {need / 2**20:,.2f} MiB of device memory at these "
                             f"input shapes (weights plus the largest set of tensors alive at once); "
                             f"{self.base.info.name} has {have / 2**20:,.2f} MiB (no allocation was made)")

    def trace(self) -> None:
        """Call every node with launches disabled: collects every unsupported
        node (fused ops that fail fall back to their parts), checks output
        shapes, records allocations, then plans memory. Nothing is computed."""
        self.check_memory()
        g, pdev = self.g, self.pdev
        work = list(g.nodes)
        final: list[Node] = []
        bad: list[tuple] = []
        records: list[list] = []
        outmap: list[list] = []
        env: dict = {t: self._placeholder(t) for t in g.inputs}
        remaining = _use_counts(work, g.outputs)
        pdev.dry = True
        try:
            while work:
                node = work.pop(0)
                idx = len(final)
                pdev.begin(idx)
                try:
                    step = self._step(node)
                    ins = self._inputs(step, env)
                    outs = list(step.fn(pdev, self.prec, node.attrs, ins))
                    outs = self._check_outputs(node, outs)
                except Exception as e:
                    if not isinstance(e, (Unsupported, ValueError, NotImplementedError, TypeError,
                                          KeyError, IndexError)):
                        raise RuntimeError(f"node {node.name!r} ({node.source_ops}): "
                                           f"{type(e).__name__}: {e}") from e
                    if node.unfused:
                        work[:0] = node.unfused
                        remaining = _use_counts(work, g.outputs)
                        continue
                    for name, op in node.sources:
                        bad.append((name, op, node.opset, _unsupported_reason(e)))
                    step = None
                    outs = [self._placeholder(t) if t else None for t in node.outputs]
                final.append(node)
                self.steps.append(step)
                recs = list(pdev.records)
                records.append(recs)
                ins_ptrs = {}
                for t in node.inputs:
                    if t and t in env:
                        p = storage_ptr(env[t])
                        if p is not None:
                            ins_ptrs.setdefault(p, t)
                om = []
                for o in outs:
                    p = None if o is None else storage_ptr(o)
                    hit = next((("alloc", j) for j, r in enumerate(recs)
                                if p is not None and storage_ptr(r[2]) == p), None)
                    if hit is None and p is not None and p in ins_ptrs:
                        hit = ("alias", ins_ptrs[p])
                    if hit is None:
                        hit = ("foreign", 0 if o is None else o.nbytes)
                    om.append(hit)
                outmap.append(om)
                for t, o in zip(node.outputs, outs):
                    if t:
                        env[t] = o
                for t in node.inputs:
                    if t and t in remaining:
                        remaining[t] -= 1
                        if remaining[t] <= 0:
                            env.pop(t, None)
                for t in node.outputs:
                    if t and remaining.get(t, 0) <= 0:
                        env.pop(t, None)
                pdev.records = []
        finally:
            pdev.dry = False
            env.clear()
        g.nodes = final
        if bad:
            raise UnsupportedModelError(bad)
        self._plan(records, outmap)

    def _check_outputs(self, node: Node, outs: list) -> list:
        g = self.g
        if len(outs) < sum(1 for t in node.outputs if t):
            used = [k for k, t in enumerate(node.outputs) if t and k >= len(outs)]
            if used:
                raise Unsupported(f"produces {len(outs)} output(s); the model uses output {used[0]}")
        fixed = []
        for t, o in zip(node.outputs, outs):
            if not t:
                fixed.append(o)
                continue
            want = tuple(g.blocked.get(t, g.shapes[t]))
            if tuple(o.shape) != want:
                if int(np.prod(o.shape)) == int(np.prod(want)):
                    o = o.reshape(want)
                else:
                    raise Unsupported(f"output {t!r} has shape {tuple(o.shape)}; ONNX shape inference "
                                      f"says {want}")
            fixed.append(o)
        return fixed

    # -- planning -------------------------------------------------------------------
    def _plan(self, records, outmap) -> None:
        g = self.g
        n = len(g.nodes)
        last = _last_use(g)
        outputs = set(g.outputs)
        root: dict[str, tuple | None] = {}
        allocs: dict[tuple[int, int], Alloc] = {}
        for i, recs in enumerate(records):
            for j, (shape, dt, arr) in enumerate(recs):
                nb = int(arr.nbytes)
                allocs[(i, j)] = Alloc(i, j, shape, dt, nb, i, i, fresh=nb == 0)
        unplanned = 0
        for i, (node, om) in enumerate(zip(g.nodes, outmap)):
            for t, m in zip(node.outputs, om):
                if not t:
                    continue
                if m[0] == "alloc":
                    root[t] = (i, m[1])
                elif m[0] == "alias":
                    root[t] = root.get(m[1])
                else:
                    root[t] = None
                    unplanned += m[1]
        for t, r in root.items():
            if r is None:
                continue
            a = allocs[r]
            if t in outputs:
                a.fresh = True
            a.end = max(a.end, last.get(t, a.start))
        # Where each graph output is allocated, so that a run can hand the caller's array
        # out for it (run(out=...)): outputs then need no copy. Only outputs with an
        # allocation of their own (not a constant's, not one shared with another output).
        roots = [root.get(t) for t in g.outputs]
        self.output_allocs = {t: allocs[r] for t, r in zip(g.outputs, roots)
                              if r is not None and roots.count(r) == 1}
        if CONCAT_IN_PLACE:
            concat_in_place(g, self.steps, allocs, root, last, self._align())
        self.plan = Plan(allocs, assign_slots(list(allocs.values())), unplanned)
        check_plan(list(allocs.values()))
        self._materialise(outmap, last)

    def _materialise(self, outmap, last) -> None:
        """One buffer per slot; each pooled allocation an Array view into its slot."""
        buffers = [cl.Buffer(self.base.context, cl.mem_flags.READ_WRITE, max(int(s), 1))
                   for s in self.plan.slots]
        planned = {}
        for key, a in self.plan.allocs.items():
            arr = None
            if not a.fresh and a.slot is not None:
                arr = cla.Array(self.base.queue, a.shape, a.dtype, data=buffers[a.slot])
            elif a.parent is not None:      # a concat input in place: a sub-buffer of the concat's
                parent = self.plan.allocs[a.parent]
                arr = cla.Array(self.base.queue, a.shape, a.dtype,
                                data=buffers[parent.slot].get_sub_region(a.offset, max(a.nbytes, 1)))
            planned[key] = (a.shape, a.dtype, arr)
        self.pdev.planned = planned
        self._buffers = buffers
        # Where each pooled output must land: a handler that allocates differently
        # at run time than in the dry run would break the liveness the plan rests on.
        outputs = set(self.g.outputs)
        for i, (step, om) in enumerate(zip(self.steps, outmap)):
            step.expect = {k: storage_ptr(planned[(i, m[1])][2]) for k, m in enumerate(om)
                           if m[0] == "alloc" and planned[(i, m[1])][2] is not None}
            step.release = [t for t in set(step.node.inputs) if t and last.get(t) == i
                            and t not in outputs]
        # Constants the handlers take as device tensors are uploaded now, once.
        for step in self.steps:
            for s in step.sources:
                if s[0] == "const":
                    self.const_array(s[1])

    def _align(self) -> int:
        """The byte alignment of a sub-buffer's origin on this device."""
        try:
            return max(1, int(self.base.cl_device.mem_base_addr_align) // 8)
        except Exception:
            return 4096

    # -- a run ----------------------------------------------------------------------
    def run(self, env: dict, out: dict | None = None, record: list | None = None,
            events: list | None = None) -> dict:
        """env: graph input name -> device array. Returns every graph output, written into
        out[name] where given and its allocation allows (see output_allocs). record: a list
        that gets every launch and copy as a command with bound arguments (a launch plan
        to replay while the same buffers are in use); events: a list for their events."""
        pdev = self.pdev
        pdev.unplanned = 0
        pdev.override = {}
        for t, a in (out or {}).items():
            al = self.output_allocs.get(t)
            if al is not None and al.nbytes == a.nbytes and al.dtype == a.dtype:
                pdev.override[(al.node, al.call)] = a.reshape(al.shape)
        pdev.recording, pdev.events = record, events
        try:
            return self._run(env)
        finally:
            pdev.recording = pdev.events = None
            pdev.override = {}

    def _run(self, env: dict) -> dict:
        g, pdev, prec = self.g, self.pdev, self.prec
        for i, step in enumerate(self.steps):
            pdev.begin(i)
            outs = step.fn(pdev, prec, step.node.attrs, self._inputs(step, env))
            for k, (t, o) in enumerate(zip(step.outputs, outs)):
                if not t:
                    continue
                want = g.blocked.get(t, g.shapes[t])
                env[t] = o if tuple(o.shape) == tuple(want) else o.reshape(want)
                p = step.expect.get(k)
                if p is not None and storage_ptr(o) != p:
                    raise RuntimeError(f"node {step.node.name!r} ({step.node.source_ops}) wrote output "
                                       f"{t!r} outside its planned buffer: its handler allocates "
                                       "differently from the load-time dry run")
            for t in step.release:
                env.pop(t, None)
        res = {}
        for t in g.outputs:
            if t in env:
                res[t] = env[t]
            else:   # a 0-d constant is uploaded as shape (1,): give it its own
                a = self.const_array(t)
                res[t] = a if tuple(a.shape) == tuple(g.shapes[t]) else a.reshape(tuple(g.shapes[t]))
        return res


# A channel concat's inputs written in place by their producers (below); False: every
# concat copies its inputs (the A/B of tests/test_model_concat_in_place.py).
CONCAT_IN_PLACE = True


def concat_in_place(g: Graph, steps: list, allocs: dict, root: dict, last: dict, align: int) -> int:
    """Give the inputs of each Concat whose inputs are contiguous byte ranges of its output
    (every dimension before the axis is 1: a batch-1 channel concat) the concat's own bytes:
    an input's allocation becomes a sub-buffer of the concat's (Alloc.parent, offset), its
    producer writes it there, and the concat copies it no more (attrs "_in_place"). On a GPU
    that is a launch and a pass over the tensor saved per input; on any device the memory.

    An input qualifies when: its producer allocated it (not a view, a constant, a graph
    input or output, or another concat's output placed in turn: OpenCL has no sub-buffer
    of a sub-buffer), the allocation holds this tensor alone and exactly its bytes, the
    concat is its last reader, it appears once, and its offset meets the device's sub-buffer
    alignment (mem_base_addr_align). The concat's allocation then lives from the first such
    producer on. Returns the number of inputs placed."""
    placed_total, parents, children = 0, set(), set()
    for node in g.nodes:
        node.attrs.pop("_in_place", None)
    owners: dict = {}
    for t, r in root.items():
        if r is not None:
            owners[r] = owners.get(r, 0) + 1
    for i, node in enumerate(g.nodes):
        if node.op != "Concat" or steps[i] is None or not node.outputs or not node.outputs[0]:
            continue
        out = node.outputs[0]
        r = root.get(out)
        shape = g.shapes.get(out)
        if r is None or shape is None or allocs[r].fresh or r in children or out in g.blocked:
            continue
        axis = int(node.attrs.get("axis", 0)) % len(shape)
        if int(np.prod(shape[:axis], dtype=np.int64)) != 1:
            continue
        item = allocs[r].dtype.itemsize
        ins = [t for t in node.inputs if t]
        offset, placed = 0, []
        for k, t in enumerate(ins):
            nbytes = int(np.prod(g.shapes[t], dtype=np.int64)) * item if t in g.shapes else -1
            rt = root.get(t)
            if (rt is not None and rt[0] != i and ins.count(t) == 1 and t not in g.outputs
                    and t not in g.blocked and last.get(t) == i and owners.get(rt) == 1
                    and rt not in parents and rt not in children and not allocs[rt].fresh
                    and allocs[rt].nbytes == nbytes and allocs[rt].dtype == allocs[r].dtype
                    and offset % align == 0):
                placed.append((k, rt, offset))
            offset += max(nbytes, 0)
        if not placed or offset != allocs[r].nbytes:
            continue
        for k, rt, off in placed:
            allocs[rt].parent, allocs[rt].offset = r, off
            allocs[r].start = min(allocs[r].start, allocs[rt].start)
            children.add(rt)
        parents.add(r)
        node.attrs["_in_place"] = [k for k, _, _ in placed]
        placed_total += len(placed)
    return placed_total


def _use_counts(nodes: list[Node], outputs) -> dict[str, int]:
    c: dict[str, int] = {}
    for n in nodes:
        for t in n.inputs:
            if t:
                c[t] = c.get(t, 0) + 1
    for t in outputs:
        c[t] = c.get(t, 0) + 10**9   # graph outputs stay
    return c
