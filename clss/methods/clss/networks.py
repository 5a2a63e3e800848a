"""The two CLSS networks (classification, composition) as ONNX graphs, seeded init, and
the torch names of their parameters (`TORCH_NAME_MAP`, `import_torch_state_dict`).

The paper (Guo et al. 2022, Fig. 4) gives the shape of the networks but not the
widths (those are in an unpublished supplement); the widths below are ours, chosen
so that both networks together cost about the paper's 71.4 GFLOP per 2160p frame
(`count_flops`, conv multiply-adds counted as 2 FLOP).

Classifier graph (input "x" [1,27,H,W] at output resolution, H and W divisible by
16; the pipeline pads to a multiple of 16 and crops the logits):

    SpaceToDepth(2)                       92 ch at H/2 (level 0)
    stem    Conv1x1 92->c0, ReLU
    enc0    bottleneck(c0)                level 0, H/2
    down1   Conv3x3/s2 c0->c1, ReLU;  enc1 bottleneck(c1)   H/4
    down2   Conv3x3/s2 c1->c2, ReLU;  enc2 bottleneck(c2)   H/8
    down3   Conv3x3/s2 c2->c3, ReLU;  enc3 bottleneck(c3)   H/16
    dec     Resize(bilinear) enc1..enc3 up to H/2, Concat(enc0..enc3),
            Conv1x1 ->c0, ReLU, Conv3x3 c0->c0, ReLU, Conv1x1 c0->6
    output "logits" [1,6,H/2,W/2]; the bilinear x2 to H is the pipeline's.

    bottleneck(c): Conv1x1 c->c/2, ReLU, Conv3x3 c/2->c/2, ReLU, Conv1x1 c/2->c,
                   Add(input), ReLU

Composition graph: "x" [1,22,H,W] -> Conv1x1 22->hidden, ReLU -> Conv1x1 hidden->1,
Sigmoid -> "w" [1,1,H,W] (the paper's per-pixel two-layer MLP as 1x1 convolutions).

Initializer names are "cls.<layer>.weight|bias" and "comp.<layer>.weight|bias" so one
safetensors file holds both networks (clss.networks reads and writes it).
"""
from __future__ import annotations

import re

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from ...networks.weights import apply_weights, load_weights, model_weights

IR_VERSION = 10
OPSET = 18

# Channel order of the network inputs (clss-frame.md, stages 6 and 8). The pipeline
# must stack its buffers in exactly this order.
CLASSIFIER_INPUTS = (
    ("bicubic_color", 3),    # current colour, jitter-aware bicubic to output res
    ("warped_color", 3),     # history colour warped by the motion
    ("depth", 1),            # upsampled (dilated) depth
    ("motion", 2),           # upsampled dilated motion, output pixels
    ("inv_counter", 1),      # 1 / (1 + warped sample counter)
    ("color_min", 3),        # warped history colour range
    ("color_max", 3),
    ("depth_difference", 1),
    ("warped_logits", 6),    # previous frame's logits, warped
    # The rule detectors' measurements (issue 23, reference.md s4b), at render res then
    # bilinear: what the labels are made of, at a scale the network can learn from.
    ("prev_depth_difference", 1),  # the previous frame's own depth at p + motion
    ("color_change", 1),     # one-frame change of the encoded colour at p + motion
    ("depth_edge", 1),       # relative depth range over the 3x3 render neighbourhood
    ("color_spread", 1),     # encoded-colour range over the 3x3 render neighbourhood
)
COMPOSITION_INPUTS = (
    ("bicubic_color", 3),
    ("warped_color", 3),
    ("depth", 1),
    ("motion", 2),
    ("inv_counter", 1),
    ("color_min", 3),
    ("color_max", 3),
    ("logits", 6),           # this frame's logits (not the warped ones)
)
CLASSIFIER_CHANNELS = sum(n for _, n in CLASSIFIER_INPUTS)    # 27
COMPOSITION_CHANNELS = sum(n for _, n in COMPOSITION_INPUTS)  # 22
LOGITS = ("ghost_visibility", "ghost_shading", "ghost_none",
          "alias_geometry", "alias_texture", "alias_none")

DEFAULT_WIDTHS = (16, 32, 64, 128)
DEFAULT_MLP_HIDDEN = 32

# The blend's base (config "base", issue 53; docs/methods/clss.md, "The rules' base"),
# stored as JSON under the weights file's metadata entry CONFIG_KEY:
#   "paper" (files without the key): the paper's form. The classifier's visibility decision
#     (at vis_margin) or the depth test drops the history; the composition MLP's sigmoid
#     is the blend weight.
#   "rules": clss-rules refined. The rules decide what history to drop (the depth test
#     alone), the counter has the rules' cap (4), and the MLP corrects the rules' weight
#     1/(1+n) in the logit domain: w = sigmoid(z - ln n) = 1/(1 + n exp(-z)), n >= 1 off
#     the ghosts. With the MLP's last layer at zero (z = 0) the frame step is clss-rules'.
#     The classifier's logits stay MLP inputs (and in the history).
CONFIG_KEY = "clss_config"
BASES = ("paper", "rules")


def base_of(cfg) -> str:
    """The blend's base (BASES) of a config dict (None or {}: "paper")."""
    from .. import config_base
    return config_base(cfg, BASES, "paper", "CLSS")


def read_config(path) -> dict:
    """The config stored with a weights file (.safetensors; CONFIG_KEY), {} where it has
    none (the files before the key: the paper's form)."""
    import json

    from safetensors import safe_open
    with safe_open(str(path), "np") as f:
        meta = f.metadata() or {}
    if CONFIG_KEY not in meta:
        return {}
    cfg = json.loads(meta[CONFIG_KEY])
    base_of(cfg)
    return cfg


def save_networks(tensors: dict, path, cfg=None) -> None:
    """The networks' tensors with their config (CONFIG_KEY) where it is not the paper's
    (a config of {} or base "paper" writes the file as clss.networks.save_weights does)."""
    from ...networks import save_weights
    from ...networks.weights import save_with_config
    cfg = {k: v for k, v in (cfg or {}).items() if not (k == "base" and v == "paper")}
    if cfg:
        base_of(cfg)
        save_with_config(path, CONFIG_KEY, cfg, tensors)
    else:
        save_weights(tensors, path)


def channel_slices(inputs):
    """{name: slice} into the channel axis for CLASSIFIER_INPUTS / COMPOSITION_INPUTS."""
    out, start = {}, 0
    for name, n in inputs:
        out[name] = slice(start, start + n)
        start += n
    return out


class _Graph:
    """Accumulates nodes and seeded initializers for one network."""

    def __init__(self, prefix, seed):
        self.prefix = prefix
        self.rng = np.random.default_rng(seed)
        self.nodes, self.inits = [], []

    def conv(self, x, name, cin, cout, k, stride=1, relu=True, gain=2.0):
        w_name, b_name = f"{self.prefix}.{name}.weight", f"{self.prefix}.{name}.bias"
        fan_in = cin * k * k
        # He init; small non-zero biases so that engines are tested on their bias path.
        w = self.rng.normal(0.0, np.sqrt(gain / fan_in), (cout, cin, k, k)).astype(np.float32)
        b = self.rng.uniform(-0.05, 0.05, cout).astype(np.float32)
        self.inits += [numpy_helper.from_array(w, w_name), numpy_helper.from_array(b, b_name)]
        y = f"{self.prefix}.{name}"
        p = k // 2
        self.nodes.append(helper.make_node(
            "Conv", [x, w_name, b_name], [y], name=y, kernel_shape=[k, k],
            strides=[stride, stride], pads=[p, p, p, p], dilations=[1, 1], group=1))
        return self.relu(y) if relu else y

    def op(self, op_type, inputs, name, **attrs):
        y = f"{self.prefix}.{name}"
        self.nodes.append(helper.make_node(op_type, inputs, [y], name=y, **attrs))
        return y

    def relu(self, x):
        return self.op("Relu", [x], x.split(".", 1)[1] + ".relu")

    def const(self, name, values):
        n = f"{self.prefix}.{name}"
        self.inits.append(numpy_helper.from_array(np.asarray(values, np.float32), n))
        return n


def _dims(height, width):
    if (height is None) != (width is None):
        raise ValueError("give both height and width, or neither")
    return ("H", "W") if height is None else (int(height), int(width))


def _half(d, f):
    return d // f if isinstance(d, int) else f"{d}/{f}"


def _model(g, inputs, outputs, name, doc):
    graph = helper.make_graph(g.nodes, name, inputs, outputs, initializer=g.inits)
    model = helper.make_model(graph, producer_name="weights_tools",
                              opset_imports=[helper.make_opsetid("", OPSET)], doc_string=doc)
    model.ir_version = IR_VERSION
    return model


def _bottleneck(g, x, name, c):
    mid = max(c // 2, 1)
    y = g.conv(x, f"{name}.reduce", c, mid, 1)
    y = g.conv(y, f"{name}.mid", mid, mid, 3)
    # Residual branch ends without ReLU and with a smaller init so the sum stays in range.
    y = g.conv(y, f"{name}.expand", mid, c, 1, relu=False, gain=1.0)
    s = g.op("Add", [x, y], f"{name}.add")
    return g.relu(s)


def build_classifier(widths=DEFAULT_WIDTHS, seed=0, in_channels=CLASSIFIER_CHANNELS,
                     height=None, width=None) -> onnx.ModelProto:
    """Classification network; H, W (output resolution) must be multiples of 16."""
    widths = tuple(int(c) for c in widths)
    if len(widths) != 4 or min(widths) < 2:
        raise ValueError(f"widths must be 4 integers >= 2, got {widths}")
    H, W = _dims(height, width)
    for d in (H, W):
        if isinstance(d, int) and d % 16:
            raise ValueError(f"classifier size {height}x{width} is not a multiple of 16 "
                             "(the pipeline pads to 16 and crops)")
    c0, c1, c2, c3 = widths
    g = _Graph("cls", seed)
    x = g.op("SpaceToDepth", ["x"], "s2d", blocksize=2)
    f0 = _bottleneck(g, g.conv(x, "stem", 4 * in_channels, c0, 1), "enc0", c0)
    f1 = _bottleneck(g, g.conv(f0, "down1", c0, c1, 3, stride=2), "enc1", c1)
    f2 = _bottleneck(g, g.conv(f1, "down2", c1, c2, 3, stride=2), "enc2", c2)
    f3 = _bottleneck(g, g.conv(f2, "down3", c2, c3, 3, stride=2), "enc3", c3)
    ups = [f0]
    for i, f in ((1, f1), (2, f2), (3, f3)):
        s = float(2 ** i)
        scales = g.const(f"dec.up{i}.scales", [1.0, 1.0, s, s])
        ups.append(g.op("Resize", [f, "", scales], f"dec.up{i}", mode="linear",
                        coordinate_transformation_mode="half_pixel"))
    cat = g.op("Concat", ups, "dec.concat", axis=1)
    y = g.conv(cat, "dec.fuse", c0 + c1 + c2 + c3, c0, 1)
    y = g.conv(y, "dec.conv", c0, c0, 3)
    y = g.conv(y, "dec.out", c0, len(LOGITS), 1, relu=False, gain=1.0)
    # Rename the last tensor to the graph output name.
    g.nodes[-1].output[0] = "logits"
    inp = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, in_channels, H, W])
    out = helper.make_tensor_value_info("logits", TensorProto.FLOAT,
                                        [1, len(LOGITS), _half(H, 2), _half(W, 2)])
    doc = ("CLSS classifier; input channels: "
           + ", ".join(f"{n}({c})" for n, c in CLASSIFIER_INPUTS)
           + "; output logits at half resolution: " + ", ".join(LOGITS))
    return _model(g, [inp], [out], "clss_classifier", doc)


def build_composition(hidden=DEFAULT_MLP_HIDDEN, seed=0, in_channels=COMPOSITION_CHANNELS,
                      height=None, width=None) -> onnx.ModelProto:
    """Composition MLP as two 1x1 convolutions -> blend weight w in (0,1)."""
    H, W = _dims(height, width)
    # A different stream from the classifier even for the same seed.
    g = _Graph("comp", [seed, 1])
    y = g.conv("x", "fc1", in_channels, int(hidden), 1)
    y = g.conv(y, "fc2", int(hidden), 1, 1, relu=False, gain=1.0)
    g.op("Sigmoid", [y], "sigmoid")
    g.nodes[-1].output[0] = "w"
    inp = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, in_channels, H, W])
    out = helper.make_tensor_value_info("w", TensorProto.FLOAT, [1, 1, H, W])
    doc = ("CLSS composition MLP; input channels: "
           + ", ".join(f"{n}({c})" for n, c in COMPOSITION_INPUTS))
    return _model(g, [inp], [out], "clss_composition", doc)


def count_flops(model, height, width):
    """Conv FLOPs (multiply-add = 2) of `model` for an output frame of height x width.

    Spatial sizes are propagated through the ops this module emits; `height`, `width`
    are the graph input's H, W (the output resolution for both networks).
    """
    inits = {t.name: t for t in model.graph.initializer}
    hw = {model.graph.input[0].name: (height, width)}
    total = 0
    for n in model.graph.node:
        h, w = hw[n.input[0]]
        attrs = {a.name: helper.get_attribute_value(a) for a in n.attribute}
        if n.op_type == "SpaceToDepth":
            b = attrs["blocksize"]
            h, w = h // b, w // b
        elif n.op_type == "DepthToSpace":
            b = attrs["blocksize"]
            h, w = h * b, w * b
        elif n.op_type == "Resize":
            s = numpy_helper.to_array(inits[n.input[2]])
            h, w = int(h * s[2]), int(w * s[3])
        elif n.op_type == "Conv":
            cout, cin_g, kh, kw = inits[n.input[1]].dims
            st = attrs.get("strides", [1, 1])
            p = attrs.get("pads", [0, 0, 0, 0])
            h = (h + p[0] + p[2] - kh) // st[0] + 1
            w = (w + p[1] + p[3] - kw) // st[1] + 1
            total += 2 * cout * cin_g * kh * kw * h * w
        for o in n.output:
            hw[o] = (h, w)
    return total


def count_params(model):
    return int(sum(np.prod(t.dims) for t in model.graph.initializer
                   if not t.name.endswith(".scales")))


def pad16(n: int) -> int:
    """n rounded up to a multiple of 16: the classifier's input sides must be (SpaceToDepth(2)
    then three stride-2 levels), so the pipeline pads its input to this and crops the logits."""
    return -(-int(n) // 16) * 16


def frame_flops(classifier, composition, height, width):
    """(classifier, composition) conv FLOPs for one output frame, the classifier run
    on the frame padded up to multiples of 16 as the pipeline does."""
    return (count_flops(classifier, pad16(height), pad16(width)),
            count_flops(composition, height, width))


# How a PyTorch re-implementation of the networks names its parameters, mapped to our
# initializer names. The torch modules this assumes (documented so that a trainer can
# match them):
#   classifier: stem = Conv2d(92, c0, 1); enc = ModuleList(4 x Bottleneck(conv1 1x1
#     reduce, conv2 3x3, conv3 1x1 expand)); down = ModuleList(3 x Conv2d(k3, s2)),
#     down[i] feeds enc[i+1]; dec = Sequential(Conv2d 1x1, ReLU, Conv2d 3x3, ReLU,
#     Conv2d 1x1 -> 6). Optional "classifier." / "cls." / "module." prefixes.
#   composition: mlp = Sequential(Linear(22, hidden), ReLU, Linear(hidden, 1));
#     Linear [out, in] weights become 1x1 conv [out, in, 1, 1].
TORCH_NAME_MAP = (
    (r"stem\.(weight|bias)", "cls.stem.{0}"),
    (r"enc\.(\d)\.conv1\.(weight|bias)", "cls.enc{0}.reduce.{1}"),
    (r"enc\.(\d)\.conv2\.(weight|bias)", "cls.enc{0}.mid.{1}"),
    (r"enc\.(\d)\.conv3\.(weight|bias)", "cls.enc{0}.expand.{1}"),
    (r"down\.(\d)\.(weight|bias)", "cls.down{0+1}.{1}"),
    (r"dec\.0\.(weight|bias)", "cls.dec.fuse.{0}"),
    (r"dec\.2\.(weight|bias)", "cls.dec.conv.{0}"),
    (r"dec\.4\.(weight|bias)", "cls.dec.out.{0}"),
    (r"mlp\.0\.(weight|bias)", "comp.fc1.{0}"),
    (r"mlp\.2\.(weight|bias)", "comp.fc2.{0}"),
)
_TORCH_PREFIXES = ("module.", "classifier.", "cls.", "composition.", "comp.")


def torch_to_onnx_name(name):
    """Our initializer name for a torch parameter name, or None if not a network weight."""
    for p in _TORCH_PREFIXES:
        if name.startswith(p):
            name = name[len(p):]
    for pattern, template in TORCH_NAME_MAP:
        m = re.fullmatch(pattern, name)
        if m:
            groups = list(m.groups())
            # "{0+1}": torch down[i] is our down{i+1}.
            return re.sub(r"\{(\d)(\+1)?\}",
                          lambda r: str(int(groups[int(r.group(1))]) + 1) if r.group(2)
                          else groups[int(r.group(1))], template)
    return None


def import_torch_state_dict(path, model, strict=True):
    """Load a torch state dict saved as safetensors into `model` (in place) using
    TORCH_NAME_MAP. Linear weights [out, in] become 1x1 conv weights. Tensors that do
    not belong to this model (the other network, optimizer buffers such as BatchNorm
    running stats) are ignored; with strict, every learned initializer of the model
    must be covered. Returns the list of (torch name, onnx name) applied."""
    src = load_weights(path)
    shapes = {k: v.shape for k, v in model_weights(model).items()}
    mapped, pairs = {}, []
    for tname, arr in src.items():
        oname = torch_to_onnx_name(tname)
        if oname is None or oname not in shapes:
            continue
        if arr.ndim == 2 and len(shapes[oname]) == 4:
            arr = arr.reshape(arr.shape + (1, 1))
        mapped[oname] = arr
        pairs.append((tname, oname))
    apply_weights(model, mapped, strict=strict)
    return pairs
