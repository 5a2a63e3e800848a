"""What the ONNX graphs of every method share: a small graph builder (named nodes,
deduplicated constants, a few ops, inlining of a network), its form for a network built
from named weights (`NetworkBuilder`, the rooms' networks.py), and the PQ transfer as
nodes, written once so that each method's whole-frame twin (clss/methods/*/oracle.py)
encodes and decodes exactly as contract.pq_encode / pq_decode do."""
from __future__ import annotations

import numpy as np
import onnx
from onnx import helper, numpy_helper

from .contract import PQ_C1, PQ_C2, PQ_C3, PQ_M1, PQ_M2, PQ_PEAK_NITS

# onnxruntime 1.2x reads IR 10 at most; onnx >= 1.23 writes a newer one by default.
IR_VERSION = 10


class GraphBuilder:
    """Node list with generated names and deduplicated constants."""

    def __init__(self, opset):
        self.opset = opset
        self.nodes, self.inits = [], []
        self._n = 0
        self._consts = {}

    def _name(self, hint):
        self._n += 1
        return f"{hint}_{self._n}"

    def op(self, op_type, *inputs, name=None, **attrs):
        out = name or self._name(op_type.lower())
        self.nodes.append(helper.make_node(op_type, list(inputs), [out], name=out, **attrs))
        return out

    def const(self, value, dtype=np.float32, hint="c"):
        arr = np.asarray(value, dtype)
        key = (arr.dtype.str, arr.shape, arr.tobytes())
        if key not in self._consts:
            name = self._name(hint)
            self.inits.append(numpy_helper.from_array(arr, name))
            self._consts[key] = name
        return self._consts[key]

    def i64(self, values):
        return self.const(values, np.int64, "i")

    # small vocabulary
    def add(self, a, b): return self.op("Add", a, b)
    def sub(self, a, b): return self.op("Sub", a, b)
    def mul(self, a, b): return self.op("Mul", a, b)
    def div(self, a, b): return self.op("Div", a, b)

    def clip(self, x, lo, hi):
        return self.op("Clip", x, self.const(lo), self.const(hi))

    def slice(self, x, axis, start, end):
        return self.op("Slice", x, self.i64([start]), self.i64([end]), self.i64([axis]))

    def chan(self, x, s: slice):
        return self.slice(x, 1, s.start, s.stop)

    def concat(self, xs, axis=1, name=None):
        return self.op("Concat", *xs, axis=axis, name=name)

    def reshape(self, x, shape):
        return self.op("Reshape", x, self.i64(shape))

    def where(self, cond, a, b, name=None):
        return self.op("Where", cond, a, b, name=name)

    def normalised(self, u, n):
        """GridSample align_corners=0 coordinate of pixel-index coordinate u: (2u+1)/n - 1."""
        return self.sub(self.div(self.add(self.mul(u, self.const(2.0)), self.const(1.0)),
                                 self.const(float(n))), self.const(1.0))

    def grid_sample(self, x, grid, cubic):
        if self.opset >= 20:
            mode = "cubic" if cubic else "linear"
        else:
            mode = "bicubic" if cubic else "bilinear"
        return self.op("GridSample", x, grid, mode=mode, padding_mode="border", align_corners=0)

    def inline(self, model: onnx.ModelProto, prefix, inputs: dict, outputs: dict):
        """Copy `model`'s nodes and initializers in, tensors renamed `prefix/...`;
        `inputs`/`outputs` map the model's graph input/output names to ours."""
        g = model.graph
        init_names = {t.name for t in g.initializer}
        rename = dict(inputs)
        rename.update(outputs)

        def r(n):
            if n == "":
                return n
            return rename.get(n, f"{prefix}/{n}")

        for t in g.initializer:
            t2 = onnx.TensorProto()
            t2.CopyFrom(t)
            t2.name = r(t.name)
            self.inits.append(t2)
        for nd in g.node:
            if nd.domain not in ("", "ai.onnx"):
                raise ValueError(f"{prefix}: node {nd.name} uses domain {nd.domain!r}; only "
                                 "the default ONNX domain can be inlined")
            if any(a.type in (onnx.AttributeProto.GRAPH, onnx.AttributeProto.GRAPHS)
                   for a in nd.attribute):
                raise ValueError(f"{prefix}: node {nd.name} ({nd.op_type}) has a subgraph")
            n2 = onnx.NodeProto()
            n2.CopyFrom(nd)
            n2.name = f"{prefix}/{nd.name or nd.op_type}"
            del n2.input[:]
            del n2.output[:]
            n2.input.extend(r(i) for i in nd.input)
            n2.output.extend(r(o) for o in nd.output)
            self.nodes.append(n2)
        missing = [n for n in list(inputs) if n not in
                   {i.name for i in g.input if i.name not in init_names}]
        if missing:
            raise ValueError(f"{prefix}: model has no graph input named {missing}")

    def model(self, name, inputs, outputs, producer, doc_string=None) -> onnx.ModelProto:
        """The graph built so far as a ModelProto (make_model)."""
        return make_model(self.nodes, self.inits, name, inputs, outputs, producer, self.opset,
                          doc_string)


class NetworkBuilder(GraphBuilder):
    """A network's graph from named weights: each weight becomes an initializer once, under
    its own name (the torch twin's state_dict key), and `conv` takes its kernel size from
    the weight. `hidden` is what act="hidden" means: the network's hidden activation (an
    ONNX op, and LeakyRelu's alpha)."""

    def __init__(self, weights: dict, opset: int, hidden: tuple = ("Relu", None)):
        super().__init__(opset)
        self.w, self.hidden = weights, hidden
        self._params = set()

    def param(self, key):
        if key not in self._params:
            self._params.add(key)
            self.inits.append(numpy_helper.from_array(np.asarray(self.w[key], np.float32), key))
        return key

    def act(self, x, op, name=None):
        """x through the activation `op` ("hidden": the network's)."""
        op, alpha = self.hidden if op == "hidden" else (op, None)
        attrs = {"alpha": alpha} if op == "LeakyRelu" and alpha is not None else {}
        return self.op(op, x, name=name, **attrs)

    def conv(self, x, layer, act=None, stride=1, name=None):
        """The square 'same' convolution of `layer`.weight / .bias, then the activation `act`
        (None: linear); `name` names the last node's output."""
        k = int(self.w[f"{layer}.weight"].shape[2])
        p = k // 2
        strides = {"strides": [stride, stride]} if stride != 1 else {}
        y = self.op("Conv", x, self.param(f"{layer}.weight"), self.param(f"{layer}.bias"),
                    name=None if act else name, pads=[p] * 4, kernel_shape=[k, k], **strides)
        return self.act(y, act, name) if act else y


def pq_encode(g, x, nits):
    """The PQ encode of contract.pq_encode as ONNX nodes (linear 1.0 = `nits`)."""
    y = g.clip(g.mul(x, g.const(nits / PQ_PEAK_NITS)), 0.0, 1.0)
    ym = g.op("Pow", y, g.const(PQ_M1))
    num = g.add(g.const(PQ_C1), g.mul(g.const(PQ_C2), ym))
    den = g.add(g.const(1.0), g.mul(g.const(PQ_C3), ym))
    return g.op("Pow", g.div(num, den), g.const(PQ_M2))


def pq_decode(g, e, nits, name):
    """The PQ decode of contract.pq_decode as ONNX nodes; the last one is named `name`."""
    ep = g.op("Pow", g.clip(e, 0.0, 1.0), g.const(1.0 / PQ_M2))
    num = g.op("Max", g.sub(ep, g.const(PQ_C1)), g.const(0.0))
    den = g.sub(g.const(PQ_C2), g.mul(g.const(PQ_C3), ep))
    y = g.op("Pow", g.div(num, den), g.const(1.0 / PQ_M1))
    return g.op("Mul", y, g.const(PQ_PEAK_NITS / nits), name=name)


def value_info(name, shape, elem=onnx.TensorProto.FLOAT):
    """A graph input or output of `shape` (None: unknown)."""
    return helper.make_tensor_value_info(name, elem, None if shape is None else list(shape))


def make_model(nodes, inits, name, inputs, outputs, producer, opset,
               doc_string=None) -> onnx.ModelProto:
    """A twin's ModelProto: the graph, its opset, and the IR version onnxruntime reads
    (onnx >= 1.23 would write a newer one)."""
    graph = helper.make_graph(nodes, name, inputs, outputs, initializer=inits)
    model = helper.make_model(graph, producer_name=producer,
                              opset_imports=[helper.make_opsetid("", opset)])
    if doc_string:
        model.doc_string = doc_string
    model.ir_version = IR_VERSION
    return model


def base_grid(render_size, out_size, jitter) -> np.ndarray:
    """[1,H,W,2] GridSample coordinates (align_corners=0) of each output pixel centre in
    the render frame whose sample j was taken at j + 0.5 + jitter: where a twin reads the
    current render-res image bilinearly as the base its network corrects (a residual
    network's base). Constants in float64, rounded once."""
    (h, w), (H, W) = render_size, out_size
    jx, jy = (float(v) for v in jitter)
    u = (np.arange(W, dtype=np.float64) + 0.5) * (w / W) - 0.5 - jx
    v = (np.arange(H, dtype=np.float64) + 0.5) * (h / H) - 0.5 - jy
    gx = np.broadcast_to(((2 * u + 1) / w - 1)[None, :], (H, W))
    gy = np.broadcast_to(((2 * v + 1) / h - 1)[:, None], (H, W))
    return np.stack([gx, gy], -1)[None].astype(np.float32)


class TwinRunner:
    """What the temporal rooms' ONNX twins (oracle.py) share: an onnxruntime session on the
    whole-frame graph, the contract's settings, and each frame checked and converted to the
    internal conventions with the first frame a reset. A room's runner sets `model` and its
    state, then calls `_start`; its step calls `_frame`."""

    def _start(self, model, render_size, scale, depth_inverted, motion_scale, exposure, threads):
        import onnxruntime as ort
        self.model = model
        self.render_size, self.scale = tuple(int(v) for v in render_size), float(scale)
        so = ort.SessionOptions()
        so.intra_op_num_threads = threads
        self.session = ort.InferenceSession(model.SerializeToString(), sess_options=so,
                                            providers=["CPUExecutionProvider"])
        self.depth_inverted, self.motion_scale, self.exposure = depth_inverted, motion_scale, exposure
        self.first = True

    def _frame(self, color, depth, motion, jitter, reset):
        """(the frame's internal arrays, whether it is a reset: asked, or the first)."""
        from .contract import to_internal, validate_frame
        f = validate_frame(color, depth, motion, jitter, render_size=self.render_size,
                           depth_inverted=self.depth_inverted)
        x = to_internal(f, depth_inverted=self.depth_inverted, motion_scale=self.motion_scale,
                        exposure=self.exposure)
        reset = bool(reset) or self.first
        self.first = False
        return x, reset

    def _image(self, out):
        """A [1, 3, H, W] graph output as the contract's H x W x 3 image, exposure undone."""
        return np.ascontiguousarray(out[0].transpose(1, 2, 0)) * np.float32(self.exposure)

