"""NSRR's three networks (Xiao et al. 2020, Fig. 4) as ONNX graphs, from named weights.

    features        rgbd [1,4,h,w] -> feat [1,12,h,w]: 3 conv 3x3 + ReLU (8 learned
                    channels) concatenated after the RGB-D input; render resolution
    reconstruct     stack [1,12*(1+N),Hp,Wp] -> y [1,3,Hp,Wp]: the feature reweighting
                    (3 conv on the RGB-D of every slot, tanh scaled to (0, 10), one map per
                    previous frame multiplied into its 12 features) then the 3-scale
                    10-layer U-Net (max pooling, nearest upsizing, skip concatenations)

`stack` is the current frame's zero-upsampled features (channels 0-11) followed by the
N previous frames' zero-upsampled, accumulatively warped features (12 each), padded to
a multiple of 4 (two poolings). The output is the frame in the PQ domain.

Residual (config "residual", a deviation from the paper, on by default): the U-Net's
output is added to `base` [1,3,H,W], the current frame's PQ colour resampled bilinearly
at the output pixel centres with its jitter (nsrr.cl). The network then learns a
correction instead of the image; with the ~1000 training steps this machine affords, the
paper's form (residual False, still supported) stayed hazy and grey well below the
spatial baselines (docs/methods/nsrr.md). With config "base": "rules" (BASES) the base is
the clss-rules output instead, and the U-Net also reads it (3 more input channels).

Widths. The paper's (32-32-8 | 32-32-N | 64-32, 64-64, 128-128, 64-64, 32-3) cost 163
kMAC per output pixel with N = 4 (`macs_per_pixel`); at 270p -> 1080p that is 0.68 TFLOP
a frame, about 40 s on 2 busy CPU cores, and its training out of reach in the time given
here (docs/methods/nsrr.md). `WIDTHS["default"]` keeps the architecture with 46 kMAC per
pixel (190 GFLOP a 1080p frame); "fast" halves the U-Net again except its last layer (the
paper's "Ours-Fast", 19 kMAC); "paper" is the paper's. One config, stored with the
weights (safetensors metadata), builds the OpenCL step, the ONNX twin and the torch twin.

The same weight names are the torch twin's state_dict keys (weights_tools/methods/nsrr/twin.py):
fe.{0,1,2}.{weight,bias}, rw.{0,1,2}.*, un.{0..9}.*.
"""
from __future__ import annotations

import numpy as np
import onnx

from ...networks.weights import ConfiguredWeights, preset_widths
from ...pipeline.twin import NetworkBuilder, value_info

FEAT_LEARNED = 8
FEAT = 4 + FEAT_LEARNED            # RGB-D + learned
MAX_PREV = 4
WEIGHT_SCALE = 10.0                # tanh (-1, 1) -> (0, 10)
ACTS = ("relu", "leaky")
# History rejection (config "reject"): "none" (the paper; files without the key) or "depth":
# every warped slot is emptied at an output pixel whose previous depth (the 2x2 render
# samples of the previous frame around where the pixel was) and current depth (the 2x2
# around its centre) are apart by more than REJECT_TAU of the nearer: a disocclusion, where
# the warp brings back what the moved object covered (the ghost beside make demo's sphere).
REJECTS = ("none", "depth")
REJECT_TAU = 0.1
# The residual's base (config "base", issue 53): "bilinear" (files without the key: the
# current frame's PQ colour bilinear at the output pixel centres, jitter-aware) or "rules":
# the clss-rules method's output for this frame (its history clipped into the render
# neighbourhood's colour box and blended by its fixed rule; PQ, from clss/methods/clss's
# rule-mode frame step, its history kept as the rules keep it). With "rules" the base is
# also an input of the U-Net: BASE_CHANNELS more channels of un.0, after the reweighted
# stack, and the network corrects the rules instead of replacing them.
BASES = ("bilinear", "rules")
BASE_CHANNELS = 3
LEAKY_ALPHA = 0.1
OPSET = 18

WIDTHS = {
    # fe: feature extraction hidden widths; rw: reweighting hidden widths;
    # un: the U-Net's 9 hidden widths (enc 1a 1b, enc 2a 2b, bottom a b, dec 2a 2b, dec 1a)
    "paper": {"fe": [32, 32], "rw": [32, 32], "un": [64, 32, 64, 64, 128, 128, 64, 64, 32]},
    "default": {"fe": [16, 16], "rw": [16, 16], "un": [24, 16, 32, 32, 64, 64, 32, 32, 16]},
    "fast": {"fe": [16, 16], "rw": [16, 16], "un": [12, 8, 16, 16, 32, 32, 16, 16, 8]},
}


def make_config(widths="default", n_prev=MAX_PREV, residual=True, act="relu",
                reject="none", base="bilinear") -> dict:
    w = preset_widths(widths, WIDTHS)
    n_prev = int(n_prev)
    if not 1 <= n_prev <= MAX_PREV:
        raise ValueError(f"n_prev: expected 1..{MAX_PREV}, got {n_prev}")
    w["n_prev"] = n_prev
    w["residual"] = bool(residual)
    if act not in ACTS:
        raise ValueError(f"act: expected one of {', '.join(ACTS)}, got {act!r}")
    if act != "relu":           # configs without the key (older weights) are ReLU
        w["act"] = act
    if reject not in REJECTS:
        raise ValueError(f"reject: expected one of {', '.join(REJECTS)}, got {reject!r}")
    if reject != "none":        # configs without the key keep every warped sample
        w["reject"] = reject
    if base not in BASES:
        raise ValueError(f"base: expected one of {', '.join(BASES)}, got {base!r}")
    if base != "bilinear":      # configs without the key: the bilinear base
        if not residual:
            raise ValueError(f"base {base!r}: needs the residual (the network corrects its base)")
        w["base"] = base
    return w


def base_of(cfg) -> str:
    """The residual's base (BASES): "rules" or "bilinear" (files without the key)."""
    from .. import config_base
    return config_base(cfg, BASES, "bilinear", "NSRR")


def rules_base(cfg) -> bool:
    """True where the base is the clss-rules output, also fed to the U-Net."""
    return bool(cfg.get("residual", False)) and base_of(cfg) == "rules"


def reject_tau(cfg) -> float:
    """The depth rejection's relative threshold, or -1 (off) without "reject": "depth"."""
    return REJECT_TAU if cfg.get("reject", "none") == "depth" else -1.0


def act_of(cfg) -> tuple[str, float]:
    """(ONNX op, alpha) of every hidden layer's activation (the U-Net's, the feature
    extraction's and the reweighting's first two): "relu" (the paper) or "leaky"
    (LeakyRelu, slope LEAKY_ALPHA below 0: no unit can die)."""
    a = cfg.get("act", "relu")
    return ("LeakyRelu", LEAKY_ALPHA) if a == "leaky" else ("Relu", 0.0)


def layer_shapes(cfg) -> dict:
    """name -> (cout, cin) of every 3x3 conv."""
    n = cfg["n_prev"]
    f1, f2 = cfg["fe"]
    r1, r2 = cfg["rw"]
    u = cfg["un"]
    cin = FEAT * (1 + n) + (BASE_CHANNELS if rules_base(cfg) else 0)
    s = {"fe.0": (f1, 4), "fe.1": (f2, f1), "fe.2": (FEAT_LEARNED, f2),
         "rw.0": (r1, 4 * (1 + n)), "rw.1": (r2, r1), "rw.2": (n, r2),
         "un.0": (u[0], cin), "un.1": (u[1], u[0]),
         "un.2": (u[2], u[1]), "un.3": (u[3], u[2]),
         "un.4": (u[4], u[3]), "un.5": (u[5], u[4]),
         "un.6": (u[6], u[5] + u[3]), "un.7": (u[7], u[6]),
         "un.8": (u[8], u[7] + u[1]), "un.9": (3, u[8])}
    return s


def init_weights(cfg, seed=0) -> dict:
    """Seeded He-normal init (the untrained networks; the torch twin starts from the
    same tensors). The last layer of the U-Net starts small and its bias at mid-grey in
    PQ (0 with the residual), so an untrained network outputs a flat image (the base)."""
    g = np.random.default_rng(seed)
    out = {}
    for name, (co, ci) in layer_shapes(cfg).items():
        std = np.sqrt(2.0 / (ci * 9))
        if name == "un.9":
            std *= 0.1
        out[f"{name}.weight"] = g.normal(0, std, (co, ci, 3, 3)).astype(np.float32)
        out[f"{name}.bias"] = np.zeros(co, np.float32)
    out["un.9.bias"][:] = 0.0 if cfg.get("residual", False) else 0.5
    # Reweighting maps start at 1 (tanh = -0.8), not at 5 (tanh(0)): at 5 the previous
    # frames' features entered the U-Net 5x amplified, and the first shipped training
    # learnt to ignore them (its output without history equalled the one with it)
    out["rw.2.bias"][:] = np.arctanh(2.0 / WEIGHT_SCALE - 1.0)
    return out


# The weights file: tensors, and the config under "nsrr_config" (clss.networks).
FILE = ConfiguredWeights("nsrr", "nsrr_config",
                         lambda cfg: {n: (co, ci, 3) for n, (co, ci) in layer_shapes(cfg).items()})
check_weights, save, load = FILE.check, FILE.save, FILE.load


def _builder(cfg, weights) -> NetworkBuilder:
    return NetworkBuilder(weights, OPSET, hidden=act_of(cfg))


_vi = value_info


def build_features(cfg, weights, h="h", w="w") -> onnx.ModelProto:
    g = _builder(cfg, weights)
    y = g.conv(g.conv(g.conv("rgbd", "fe.0", "hidden"), "fe.1", "hidden"), "fe.2", "hidden")
    g.op("Concat", "rgbd", y, axis=1, name="feat")
    return g.model("nsrr_features", [_vi("rgbd", [1, 4, h, w])], [_vi("feat", [1, FEAT, h, w])],
                   __name__)


def build_reconstruct(cfg, weights, H="H", W="W") -> onnx.ModelProto:
    n = cfg["n_prev"]
    residual = bool(cfg.get("residual", False))
    g = _builder(cfg, weights)

    def conv2(x, a, b):           # two 3x3 convs with the hidden activation
        return g.conv(g.conv(x, a, "hidden"), b, "hidden")

    x = "stack"
    # Feature reweighting on the RGB-D of the current and every previous slot.
    rgbd = g.op("Concat", *[g.slice(x, 1, FEAT * k, FEAT * k + 4) for k in range(n + 1)], axis=1)
    r = g.conv(conv2(rgbd, "rw.0", "rw.1"), "rw.2", act="Tanh")
    half = g.const(np.float32(WEIGHT_SCALE / 2), hint="half_scale")
    r = g.op("Mul", g.op("Add", r, g.const(np.float32(1.0), hint="one")), half)
    parts = [g.op("Mul", g.slice(x, 1, FEAT * k, FEAT * (k + 1)), g.slice(r, 1, k - 1, k))
             for k in range(1, n + 1)]
    # (with the rules' base: the base too, the network's input as well as what it corrects)
    x = g.op("Concat", g.slice("stack", 1, 0, FEAT), *parts,
             *(["base"] if rules_base(cfg) else []), axis=1)
    # The reconstruction U-Net.
    pool = dict(kernel_shape=[2, 2], strides=[2, 2])
    up = g.const(np.array([1, 1, 2, 2], np.float32), hint="scales")
    e1 = conv2(x, "un.0", "un.1")
    e2 = conv2(g.op("MaxPool", e1, **pool), "un.2", "un.3")
    b = conv2(g.op("MaxPool", e2, **pool), "un.4", "un.5")
    rs = dict(mode="nearest", coordinate_transformation_mode="asymmetric", nearest_mode="floor")
    d2 = g.op("Concat", g.op("Resize", b, "", up, **rs), e2, axis=1)
    d2 = conv2(d2, "un.6", "un.7")
    d1 = g.op("Concat", g.op("Resize", d2, "", up, **rs), e1, axis=1)
    y = g.conv(g.conv(d1, "un.8", "hidden"), "un.9", name=None if residual else "y")
    inputs = [_vi("stack", [1, FEAT * (n + 1), H, W])]
    if residual:
        g.op("Add", y, "base", name="y")
        inputs.append(_vi("base", [1, 3, H, W]))
    return g.model("nsrr_reconstruct", inputs, [_vi("y", [1, 3, H, W])], __name__)


def macs_per_pixel(cfg, scale) -> dict:
    """Multiply-adds per output pixel of each network (for the docs and bench)."""
    s = layer_shapes(cfg)
    m = {k: co * ci * 9 for k, (co, ci) in s.items()}
    fe = sum(m[k] for k in ("fe.0", "fe.1", "fe.2")) / float(scale) ** 2
    rw = sum(m[k] for k in ("rw.0", "rw.1", "rw.2"))
    un = (m["un.0"] + m["un.1"] + m["un.8"] + m["un.9"]
          + (m["un.2"] + m["un.3"] + m["un.6"] + m["un.7"]) / 4 + (m["un.4"] + m["un.5"]) / 16)
    return {"features": fe, "reweighting": rw, "reconstruction": un, "total": fe + rw + un}
