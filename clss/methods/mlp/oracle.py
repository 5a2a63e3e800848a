"""The whole-frame ONNX twin of the shader MLP upscaler (onnxruntime): the same frame step
as mlp_upscale.cl, written with ONNX nodes from transform.py's constants.

    color [h, w, 3] -> PQ encode -> edge pad 2 -> Conv (25 one-hot 5x5 filters) = the 5x5
    neighbourhoods [3, 25, h, w] -> minus their mean -> ramp;
    depth_hr [H, W] -> edge pad (1, 1, 4-s, 4-s) -> Conv (one-hot, stride s) -> the 5x5
    output-res neighbourhoods [1, 25, h, w] -> minus their mean -> ramp (zeros in the
    ablation);
    concat [3, 50, h, w] -> Conv 1x1 (its bias plus fcj.weight @ jitter with the jitter
    input) + LeakyRelu, Conv 1x1 + LeakyRelu, Conv 1x1 (the
    first B*B units) -> inverse ramp + mean = blocks [3, B*B, h, w];
    ConvTranspose (one-hot B x B, stride s) of the blocks / of ones = sums / counts ->
    crop the one-pixel ring -> mean -> PQ decode -> [H, W, 3].

`blocks_graph` and `fold_graph` are the two kernels' twins (clss/verify/cases/mlp_upscale.py);
`build_graph` is the whole frame, `OracleMlp` runs it frame by frame with the contract's
`step` (tests/test_method_mlp.py holds the OpenCL upscaler to it)."""
from __future__ import annotations

import numpy as np
import onnx

from ...pipeline.contract import PQ_NITS, validate_frame
from ...pipeline.twin import GraphBuilder, make_model, pq_decode, pq_encode, value_info
from . import transform as tf

OPSET = 19


def _onehot(n, side):
    """[n, 1, side, side]: filter k picks pixel (k // side, k % side)."""
    w = np.zeros((n, 1, side, side), np.float32)
    for k in range(n):
        w[k, 0, k // side, k % side] = 1.0
    return w


def _ramp(g, r):
    mag = g.sub(g.op("Pow", g.add(g.op("Abs", r), g.const(tf.EPS)), g.const(1.0 / tf.GAMMA)),
                g.const(tf.EPS_ROOT))
    return g.mul(g.op("Sign", r), mag)


def _ramp_inv(g, y):
    mag = g.sub(g.op("Pow", g.add(g.op("Abs", y), g.const(tf.EPS_ROOT)), g.const(tf.GAMMA)),
                g.const(tf.EPS))
    return g.mul(g.op("Sign", y), mag)


def _dc_ramp(g, taps):
    m = g.op("ReduceMean", taps, g.i64([1]), keepdims=1)
    return m, _ramp(g, g.sub(taps, m))


def add_blocks(g, color, feat, tensors, render_size, scale, feature=True, nits=PQ_NITS,
               jitter=None):
    """Nodes from color [h, w, 3] linear (and feat [H, W]) to blocks [3, B*B, h, w];
    `jitter` ([2]) feeds the jitter input of a network that has one."""
    h, w = render_size
    s, b = tf.check_scale(scale), tf.block(scale)
    t = tf.check_weights(tensors)
    x = g.reshape(g.op("Transpose", color, perm=[2, 0, 1]), [3, 1, h, w])
    x = pq_encode(g, x, nits)
    x = g.op("Pad", x, g.i64([0, 0, tf.HALF, tf.HALF, 0, 0, tf.HALF, tf.HALF]), mode="edge")
    taps = g.op("Conv", x, g.const(_onehot(tf.TAPS ** 2, tf.TAPS)))
    m, xb = _dc_ramp(g, taps)
    if feature:
        f = g.reshape(feat, [1, 1, s * h, s * w])
        f = g.op("Pad", f, g.i64([0, 0, 1, 1, 0, 0, 4 - s, 4 - s]), mode="edge")
        ftaps = g.op("Conv", f, g.const(_onehot(tf.TAPS ** 2, tf.TAPS)), strides=[s, s])
        _, xf = _dc_ramp(g, ftaps)
        xf = g.op("Expand", xf, g.i64([3, tf.TAPS ** 2, h, w]))
    else:
        xf = g.const(np.zeros((3, tf.TAPS ** 2, h, w), np.float32))
    y = g.concat([xb, xf], axis=1)
    for k, name in enumerate(tf.LAYER_NAMES):
        wt, bias = t[f"{name}.weight"], t[f"{name}.bias"]
        if k == len(tf.LAYER_NAMES) - 1:
            wt, bias = wt[:b * b], bias[:b * b]        # the units the block uses
        if k == 0 and tf.has_jitter(t):
            # fc1 also sees the frame's jitter: its bias plus JITTER_KEY @ jitter
            bias = g.add(g.const(bias), g.op("MatMul", g.const(t[tf.JITTER_KEY]), jitter))
            y = g.add(g.op("Conv", y, g.const(wt[:, :, None, None])),
                      g.reshape(bias, [1, tf.WIDTHS[1], 1, 1]))
        else:
            y = g.op("Conv", y, g.const(wt[:, :, None, None]), g.const(bias))
        if tf.ACTS[k] == "leaky_relu":
            y = g.op("LeakyRelu", y, alpha=tf.LEAKY_ALPHA)
    return g.add(m, _ramp_inv(g, y))


def add_fold(g, blk, render_size, scale, nits=PQ_NITS, name="output"):
    """Nodes from blocks [3, B*B, h, w] to the frame [H, W, 3] linear."""
    h, w = render_size
    s, b = tf.check_scale(scale), tf.block(scale)
    H, W = s * h, s * w
    k = g.const(_onehot(b * b, b))

    def spread(x):
        y = g.op("ConvTranspose", x, k, strides=[s, s])       # [., 1, H+2, W+2]
        y = g.op("Slice", y, g.i64([1, 1]), g.i64([H + 1, W + 1]), g.i64([2, 3]))
        return y

    sums = spread(blk)
    counts = spread(g.const(np.ones((1, b * b, h, w), np.float32)))
    v = g.clip(g.div(sums, counts), 0.0, 1.0)
    lin = pq_decode(g, v, nits, name=g._name("decoded"))
    return g.op("Transpose", g.reshape(lin, [3, H, W]), perm=[1, 2, 0], name=name)


def _model(g, inputs, outputs, name):
    return make_model(g.nodes, g.inits, name, inputs, outputs, __name__, OPSET)


_vi = value_info


def build_graph(render_size, scale, tensors, feature=True, nits=PQ_NITS) -> onnx.ModelProto:
    """color [h, w, 3] (+ depth_hr [H, W] with the feature pass, + jitter [2] with the
    jitter input) -> output [H, W, 3]."""
    h, w = render_size
    s = tf.check_scale(scale)
    g = GraphBuilder(OPSET)
    jit = tf.has_jitter(tensors)
    blk = add_blocks(g, "color", "depth_hr", tensors, render_size, s, feature, nits,
                     jitter="jitter" if jit else None)
    add_fold(g, blk, render_size, s, nits)
    inputs = [_vi("color", (h, w, 3))] + ([_vi("depth_hr", (s * h, s * w))] if feature else []) \
        + ([_vi("jitter", (2,))] if jit else [])
    return _model(g, inputs, [_vi("output", (s * h, s * w, 3))], "mlp_frame")


def blocks_graph(render_size, scale, tensors, feature=True) -> onnx.ModelProto:
    """The twin of kernel mlp_upscale_blocks: color, feat -> blocks."""
    h, w = render_size
    s, b = tf.check_scale(scale), tf.block(scale)
    g = GraphBuilder(OPSET)
    blk = add_blocks(g, "color", "feat", tensors, render_size, s, feature)
    g.op("Identity", blk, name="blocks")
    inputs = [_vi("color", (h, w, 3)), _vi("feat", (s * h, s * w))]
    if not feature:      # the input stays (the kernel takes it) but feeds nothing
        g.op("Identity", "feat", name="feat_unused")
    outs = [_vi("blocks", (3, b * b, h, w))] + ([_vi("feat_unused", (s * h, s * w))]
                                               if not feature else [])
    return _model(g, inputs, outs, "mlp_upscale_blocks")


def fold_graph(render_size, scale) -> onnx.ModelProto:
    """The twin of kernel mlp_upscale_fold: blocks -> [H, W, 3]."""
    h, w = render_size
    s, b = tf.check_scale(scale), tf.block(scale)
    g = GraphBuilder(OPSET)
    add_fold(g, "blocks", render_size, s)
    return _model(g, [_vi("blocks", (3, b * b, h, w))], [_vi("output", (s * h, s * w, 3))],
                  "mlp_upscale_fold")


def frame_pq_graph(render_size, scale, tensors, feature=True, nits=PQ_NITS) -> onnx.ModelProto:
    """The twin of the whole frame step (mlp_upscale.frame: the fused kernel or the pair)
    with the output PQ-encoded again, so that a conformance case compares code values as
    the method's tests do: color [h, w, 3], feat [H, W] -> output_pq [H, W, 3]."""
    h, w = render_size
    s = tf.check_scale(scale)
    g = GraphBuilder(OPSET)
    blk = add_blocks(g, "color", "feat", tensors, render_size, s, feature, nits)
    lin = add_fold(g, blk, render_size, s, nits, name="linear")
    g.op("Identity", pq_encode(g, lin, nits), name="output_pq")
    inputs = [_vi("color", (h, w, 3)), _vi("feat", (s * h, s * w))]
    outs = [_vi("output_pq", (s * h, s * w, 3))]
    if not feature:
        g.op("Identity", "feat", name="feat_unused")
        outs.append(_vi("feat_unused", (s * h, s * w)))
    return _model(g, inputs, outs, "mlp_upscale_frame")


class OracleMlp:
    """Frame-by-frame runner of the twin with the contract's `step`. precision="fp16"
    feeds it the fp16-rounded weights the device's fp16 path uses."""

    def __init__(self, render_size, scale=2.0, weights=None, feature=True, precision="fp32",
                 exposure=1.0, **unused):
        import onnxruntime as ort
        self.render_size, self.scale = tuple(render_size), tf.check_scale(scale)
        self.feature, self.exposure = bool(feature), float(exposure)
        tensors, _ = tf.load_weights(weights, feature=self.feature, scale=self.scale)
        if precision != "fp32":
            tensors = {k: v.astype(np.float16).astype(np.float32) for k, v in tensors.items()}
        self.jitter = tf.has_jitter(tensors)
        self.model = build_graph(self.render_size, self.scale, tensors, self.feature)
        self.session = ort.InferenceSession(self.model.SerializeToString(),
                                            providers=["CPUExecutionProvider"])

    def step(self, color, depth=None, motion=None, jitter=(0.0, 0.0), reset=False,
             depth_hr=None, **unused):
        h, w = self.render_size
        f = validate_frame(color, np.zeros((h, w), np.float32), np.zeros((h, w, 2), np.float32),
                           jitter, render_size=self.render_size)
        feeds = {"color": f["color"] * np.float32(1.0 / self.exposure)}
        if self.jitter:
            feeds["jitter"] = np.asarray(f["jitter"], np.float32).reshape(2)
        if self.feature:
            feeds["depth_hr"] = np.ascontiguousarray(np.asarray(depth_hr, np.float32).reshape(
                self.scale * h, self.scale * w))
        (y,) = self.session.run(["output"], feeds)
        return y * np.float32(self.exposure)


def twin(method, render_size, scale=2.0, weights=tf.UNTRAINED, **kwargs):
    """clss.methods.twin's entry: the twin of "mlp" or "mlp-nofeature", at the seeded init
    unless `weights` says otherwise (as CLSS's twin: tests compare the upscaler built with
    weights="untrained" against it)."""
    return OracleMlp(render_size, scale, weights=weights, feature=(method == "mlp"), **kwargs)
