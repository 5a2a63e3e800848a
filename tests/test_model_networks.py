"""Whole networks through clss.Model against onnxruntime, fp32 and fp16:

* an NSRR-style network (Xiao et al. 2020, seeds/000 Fig. 4): per-frame feature
  extraction (3 conv layers, 32-32-8, concatenated with the RGB-D input),
  zero-upsampling (Concat with zeros + DepthToSpace), backward warping of the
  previous frames (GridSample), feature reweighting (3 conv layers 32-32-n,
  tanh scaled to (0, 10)) and the 3-scale, 10-layer reconstruction U-Net
  (64-32 | 64-64 | 128-128 | 64-64 | 32-3, max pooling, bilinear upsizing,
  skip concatenations);
* an NSRD-style block (seeds/001): gated convolution on the warped
  lighting + motion mask, PixelUnshuffle of the previous HR output, a ConvLSTM
  cell carrying (h, c), a residual channel-attention block (GlobalAveragePool,
  1x1 squeeze/excite, sigmoid gating) and PixelShuffle back to HR, remodulated;
* the shader MLP of seeds/004 (Spencer 2022): 5x5 neighbourhoods of beauty and
  depth (50 inputs, gathered by a one-hot 5x5 convolution), two hidden layers
  of 50 and an output layer of 25, leaky ReLU throughout;
* the CLSS classifier and composition networks from weights_tools.

Spatial sizes are small; channel widths are the papers' (NSRR) or ours (NSRD,
whose widths are in an unpublished supplement).
"""
from __future__ import annotations

import numpy as np
import pytest
from onnx import helper, numpy_helper

import clss
from clss.tolerance import Tolerance, compare
from clss.verify.twin import make_model, run_ort

# Deep networks: accumulation order differs from onnxruntime's and compounds
# over ~20 layers (fp32); in fp16 every intermediate tensor is stored rounded to
# 11 bits, and the reference (fp32 arithmetic on fp16-rounded inputs and
# weights) does not round them.
NET_TOL = {"fp32": Tolerance(2e-5, 2e-4), "fp16": Tolerance(5e-3, 5e-3)}


class Net:
    """Accumulates nodes and seeded initializers."""

    def __init__(self, seed):
        self.rng = np.random.default_rng(seed)
        self.nodes, self.inits, self.k = [], {}, 0

    def name(self, stem):
        self.k += 1
        return f"{stem}{self.k}"

    def op(self, op, inputs, **attrs):
        y = self.name(op.lower())
        self.nodes.append(helper.make_node(op, list(inputs), [y], name=y, **attrs))
        return y

    def const(self, value, stem="c"):
        n = self.name(stem)
        self.inits[n] = np.asarray(value)
        return n

    def conv(self, x, cin, cout, k=3, act="Relu", w=None, b=None, stride=1):
        if w is None:
            w = self.const(self.rng.normal(0, np.sqrt(2.0 / (cin * k * k)), (cout, cin, k, k)).astype(np.float32), "w")
            b = self.const(self.rng.uniform(-0.05, 0.05, cout).astype(np.float32), "b")
        y = self.op("Conv", [x, w, b], pads=[k // 2] * 4, strides=[stride, stride])
        return self.op(act, [y]) if act else y

    def model(self, inputs, outputs):
        return make_model(self.nodes, inputs, outputs, initializers=self.inits)


def feature_extraction(net, x, weights=None):
    """3 conv layers 32-32-8 on RGB-D, concatenated with the input: 12 channels."""
    ws = weights or [None] * 3
    y = net.conv(x, 4, 32, w=ws[0] and ws[0][0], b=ws[0] and ws[0][1])
    y = net.conv(y, 32, 32, w=ws[1] and ws[1][0], b=ws[1] and ws[1][1])
    y = net.conv(y, 32, 8, w=ws[2] and ws[2][0], b=ws[2] and ws[2][1])
    return net.op("Concat", [x, y], axis=1)


def zero_upsample(net, x, c, h, w, s):
    """Each low-res pixel to the top-left of its s x s block, zeros elsewhere
    (DepthToSpace DCR takes block position 0 from the first c channels)."""
    z = net.const(np.zeros((1, c * (s * s - 1), h, w), np.float32), "zeros")
    return net.op("DepthToSpace", [net.op("Concat", [x, z], axis=1)], blocksize=s, mode="DCR")


def build_nsrr(h=8, w=12, scale=2, n_prev=2, seed=0):
    H, W = h * scale, w * scale
    net = Net(seed)
    shared = [(net.const(net.rng.normal(0, np.sqrt(2 / (ci * 9)), (co, ci, 3, 3)).astype(np.float32), "fw"),
               net.const(net.rng.uniform(-0.05, 0.05, co).astype(np.float32), "fb"))
              for ci, co in ((4, 32), (32, 32), (32, 8))]
    feats_cur = zero_upsample(net, feature_extraction(net, "cur"), 12, h, w, scale)
    rgbd = [zero_upsample(net, "cur", 4, h, w, scale)]
    prev_feats = []
    for i in range(n_prev):
        f = zero_upsample(net, feature_extraction(net, f"prev{i}", shared), 12, h, w, scale)
        f = net.op("GridSample", [f, f"grid{i}"], mode="bilinear", padding_mode="zeros", align_corners=0)
        prev_feats.append(f)
        rgbd.append(net.op("Slice", [f, net.const(np.array([0], np.int64)), net.const(np.array([4], np.int64)),
                                     net.const(np.array([1], np.int64))]))
    # Feature reweighting: weights in (0, 10) per previous frame.
    r = net.op("Concat", rgbd, axis=1)
    r = net.conv(r, 4 * (n_prev + 1), 32)
    r = net.conv(r, 32, 32)
    r = net.conv(r, 32, n_prev, act="Tanh")
    r = net.op("Mul", [net.op("Add", [r, net.const(np.float32(1.0))]), net.const(np.float32(5.0))])
    parts = [net.name("wmap") for _ in range(n_prev)]
    net.nodes.append(helper.make_node("Split", [r, net.const(np.ones(n_prev, np.int64))], parts, axis=1))
    rew = [net.op("Mul", [f, p]) for f, p in zip(prev_feats, parts)]
    x = net.op("Concat", [feats_cur] + rew, axis=1)
    cin = 12 * (n_prev + 1)
    # Reconstruction U-Net: 3 scales, 10 conv layers.
    e1 = net.conv(net.conv(x, cin, 64), 64, 32)
    e2 = net.conv(net.conv(net.op("MaxPool", [e1], kernel_shape=[2, 2], strides=[2, 2]), 32, 64), 64, 64)
    b = net.conv(net.conv(net.op("MaxPool", [e2], kernel_shape=[2, 2], strides=[2, 2]), 64, 128), 128, 128)
    up = net.const(np.array([1, 1, 2, 2], np.float32), "scales")
    d2 = net.op("Resize", [b, "", up], mode="linear")
    d2 = net.conv(net.conv(net.op("Concat", [d2, e2], axis=1), 128 + 64, 64), 64, 64)
    d1 = net.op("Resize", [d2, "", up], mode="linear")
    d1 = net.conv(net.conv(net.op("Concat", [d1, e1], axis=1), 64 + 32, 32), 32, 3, act=None)
    net.nodes[-1].output[0] = "out"
    g = np.random.default_rng(seed + 1)
    inputs = {"cur": g.random((1, 4, h, w), np.float32)}
    for i in range(n_prev):
        inputs[f"prev{i}"] = g.random((1, 4, h, w), np.float32)
    ys, xs = np.meshgrid((np.arange(H) + 0.5) / H * 2 - 1, (np.arange(W) + 0.5) / W * 2 - 1, indexing="ij")
    for i in range(n_prev):
        motion = g.normal(0, 1.5, (2, H, W)) * np.array([2 / W, 2 / H])[:, None, None]
        inputs[f"grid{i}"] = np.stack([xs + motion[0], ys + motion[1]], -1)[None].astype(np.float32)
    return net.model(inputs, ["out"]), inputs


def pixel_shuffle(net, x, n, c, h, w, r, inverse=False):
    """torch.nn.PixelShuffle / PixelUnshuffle as exported: Reshape-Transpose-Reshape (CRD)."""
    if inverse:
        mid, perm, out = (n, c, h // r, r, w // r, r), (0, 1, 3, 5, 2, 4), (n, c * r * r, h // r, w // r)
    else:
        mid, perm, out = (n, c // (r * r), r, r, h, w), (0, 1, 4, 2, 5, 3), (n, c // (r * r), h * r, w * r)
    t = net.op("Reshape", [x, net.const(np.array(mid, np.int64), "shape")])
    t = net.op("Transpose", [t], perm=list(perm))
    return net.op("Reshape", [t, net.const(np.array(out, np.int64), "shape")])


def build_nsrd(h=8, w=12, scale=2, hid=16, feat=24, seed=0):
    H, W = h * scale, w * scale
    net = Net(seed)
    # Gated convolution over warped LR lighting (3), G-buffers (6) and the motion mask (1).
    x = net.op("Concat", ["warped", "gbuf", "mask"], axis=1)
    f = net.conv(x, 10, feat, act="LeakyRelu")
    gate = net.conv(x, 10, feat, act="Sigmoid")
    temporal = net.op("Mul", [f, gate])
    # Previous HR reconstruction to LR space, then features.
    prev = net.conv(pixel_shuffle(net, "prev_hr", 1, 3, H, W, scale, inverse=True), 3 * scale * scale, feat)
    spatial = net.conv("lighting", 3, feat)
    xt = net.op("Concat", [temporal, prev, spatial], axis=1)
    # ConvLSTM cell.
    gates = net.conv(net.op("Concat", [xt, "h"], axis=1), 3 * feat + hid, 4 * hid, act=None)
    i, fg, o, gg = (net.name(s) for s in "ifog")
    net.nodes.append(helper.make_node("Split", [gates, net.const(np.full(4, hid, np.int64))],
                                      [i, fg, o, gg], axis=1))
    i, fg, o = (net.op("Sigmoid", [t]) for t in (i, fg, o))
    gg = net.op("Tanh", [gg])
    c_new = net.op("Add", [net.op("Mul", [fg, "c"]), net.op("Mul", [i, gg])])
    h_new = net.op("Mul", [o, net.op("Tanh", [c_new])])
    # Residual channel attention block.
    r = net.conv(net.conv(h_new, hid, hid), hid, hid, act=None)
    s = net.op("GlobalAveragePool", [r])
    s = net.conv(s, hid, hid // 4, k=1)
    s = net.conv(s, hid // 4, hid, k=1, act="Sigmoid")
    rcab = net.op("Add", [h_new, net.op("Mul", [r, s])])
    # Back to HR and remodulation with the HR material.
    up = pixel_shuffle(net, net.conv(rcab, hid, 3 * scale * scale, act=None), 1, 3 * scale * scale, h, w, scale)
    net.op("Mul", [up, "material"])
    net.nodes[-1].output[0] = "out"
    for n in net.nodes:
        for k, t in enumerate(n.output):
            if t == c_new:
                n.output[k] = "c_out"
            if t == h_new:
                n.output[k] = "h_out"
    for n in net.nodes:
        for k, t in enumerate(n.input):
            if t == c_new:
                n.input[k] = "c_out"
            if t == h_new:
                n.input[k] = "h_out"
    g = np.random.default_rng(seed + 1)
    inputs = {"warped": g.random((1, 3, h, w), np.float32), "gbuf": g.random((1, 6, h, w), np.float32),
              "mask": (g.random((1, 1, h, w)) > 0.3).astype(np.float32),
              "prev_hr": g.random((1, 3, H, W), np.float32), "lighting": g.random((1, 3, h, w), np.float32),
              "h": g.normal(0, 0.5, (1, hid, h, w)).astype(np.float32),
              "c": g.normal(0, 0.5, (1, hid, h, w)).astype(np.float32),
              "material": g.random((1, 3, H, W), np.float32)}
    return net.model(inputs, ["out", "h_out", "c_out"]), inputs


def build_shader_mlp(h=9, w=14, seed=0):
    net = Net(seed)
    onehot = np.eye(25, dtype=np.float32).reshape(25, 1, 5, 5)
    taps = [net.op("Conv", [t, net.const(onehot, "unfold")], pads=[2] * 4) for t in ("beauty", "depth")]
    y = net.op("Concat", taps, axis=1)
    for cin, cout in ((50, 50), (50, 50), (50, 25)):
        y = net.conv(y, cin, cout, k=1, act="LeakyRelu")
    net.nodes[-1].output[0] = "kernel"
    g = np.random.default_rng(seed + 1)
    inputs = {"beauty": g.random((1, 1, h, w), np.float32), "depth": g.random((1, 1, h, w), np.float32)}
    return net.model(inputs, ["kernel"]), inputs


def _half_model(model):
    """The model with its float initializers rounded to fp16: the fp16 reference."""
    import onnx
    m = onnx.ModelProto()
    m.CopyFrom(model)
    for t in m.graph.initializer:
        a = numpy_helper.to_array(t)
        if a.dtype == np.float32:
            t.CopyFrom(numpy_helper.from_array(a.astype(np.float16).astype(np.float32), t.name))
    return m


def check_network(model, feeds, prec, input_shapes=None):
    cm = clss.Model(model, precision=prec, input_shapes=input_shapes)
    outs = cm.run(feeds)
    if prec == "fp32":
        refs = run_ort(model, feeds)
    else:
        refs = run_ort(_half_model(model), {k: v.astype(np.float16).astype(np.float32) for k, v in feeds.items()})
    for name, r in zip(cm.output_names, refs):
        c = compare(outs[name], r, NET_TOL[prec])
        assert c.passed, f"{name} {prec}: max abs {c.max_abs:.3g} (scale {np.abs(r).max():.3g}), " \
                         f"err/tol {c.ratio:.3g} {c.detail}"
    return cm


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_nsrr(prec):
    model, feeds = build_nsrr()
    # The U-Net's outputs declare no shape, as exporters may leave them (the other
    # networks declare theirs); clss infers them as onnxruntime does.
    declared = {o.name: tuple(d.dim_value for d in o.type.tensor_type.shape.dim) for o in model.graph.output}
    for o in model.graph.output:
        o.type.tensor_type.ClearField("shape")
    cm = check_network(model, feeds, prec)
    assert cm.output_shapes == declared
    ops = cm.execution_ops()
    assert ops["Conv+relu"] >= 14 and ops["GridSample"] == 2, ops


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_nsrd(prec):
    model, feeds = build_nsrd()
    cm = check_network(model, feeds, prec)
    ops = cm.execution_ops()
    assert ops["SpaceToDepth"] == 1 and ops["DepthToSpace"] == 1 and "Transpose" not in ops, ops
    # the temporal gate: a LeakyRelu conv times a Sigmoid conv, one gated conv where the
    # device's vector width divides its channels (passes.fuse_gated_conv: 8-wide CPUs here)
    gated = ops["Conv+leaky_relu*sigmoid"]
    assert ops["Conv+leaky_relu"] + gated == 1 and (ops["Conv+sigmoid"] >= 1 or gated == 1), ops


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_shader_mlp(prec):
    model, feeds = build_shader_mlp()
    cm = check_network(model, feeds, prec)
    assert cm.execution_ops()["MLP(3 layers)"] == 1, cm.execution_ops()


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_clss_networks(prec):
    nets = pytest.importorskip("clss.methods.clss.networks")
    g = np.random.default_rng(5)
    h, w = 32, 48
    cls = nets.build_classifier()
    x = g.random((1, nets.CLASSIFIER_CHANNELS, h, w), np.float32)
    cm = check_network(cls, {"x": x}, prec, input_shapes={"x": x.shape})
    # 4 bottleneck residuals, plus the decoder fuse carrying its resized parts
    # as a residual (the conv_resize pass).
    assert cm.execution_ops()["Conv+Add+relu"] == 5
    comp = nets.build_composition()
    x = g.random((1, nets.COMPOSITION_CHANNELS, h, w), np.float32)
    cm = check_network(comp, {"x": x}, prec, input_shapes={"x": x.shape})
    assert sum(cm.execution_ops().values()) == 1     # one fused MLP kernel


def test_recurrent_state_device_resident(dev):
    """NSRD's (h, c) carried on the device from one call to the next."""
    model, feeds = build_nsrd()
    cm = clss.Model(model)
    state = {"h": dev.to_device(feeds["h"]), "c": dev.to_device(feeds["c"])}
    ins = {k: dev.to_device(v) for k, v in feeds.items() if k not in state}
    host = dict(feeds)
    for _ in range(2):
        out = cm.run_device({**ins, **state})
        state = {"h": out["h_out"], "c": out["c_out"]}
        ref = cm.run(host)
        host.update(h=ref["h_out"], c=ref["c_out"])
        np.testing.assert_array_equal(dev.to_host(out["out"]), ref["out"])


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_cli_compare_ort(prec, tmp_path, capsys):
    """`clss run --compare-ort` on an NSRR-shaped network and a CLSS network."""
    import onnx
    from clss.cli import main
    nets = pytest.importorskip("clss.methods.clss.networks")
    model, feeds = build_nsrr()
    cls = nets.build_classifier()
    for name, m, fs in (("nsrr", model, feeds),
                        ("classifier", cls, {"x": np.random.default_rng(1).random((1, nets.CLASSIFIER_CHANNELS, 32, 32), np.float32)})):
        path = tmp_path / f"{name}.onnx"
        onnx.save(m, str(path))
        args = ["run", str(path), "--compare-ort", "--repeat", "1", "--precision", prec]
        for k, v in fs.items():
            np.save(tmp_path / f"{k}.npy", v)
            args += ["--input", f"{k}={tmp_path / (k + '.npy')}"]
        rc = main(args)
        out = capsys.readouterr().out
        assert rc == 0 and out.rstrip().endswith("PASS"), out
