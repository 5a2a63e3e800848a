"""NSS's network (Arm Neural Super Sampling, 2025; the model gym's NSS v1 layout) as one
ONNX graph from named weights, and the constants of the frame step around it.

One network at render resolution, padded to multiples of 8 (three stride-2 levels):

    x     [1,12,hp,wp]   warped history (Karis tonemapped, 3), jittered colour (Karis, 3),
                         disocclusion (1), the previous frame's 4 temporal parameters
                         warped (the feedback, 4), the time-filtered luma derivative (1)
 -> kpn   [1,K*K,hp/4,wp/4]  per-pixel kernel-prediction weights (sigmoid), K x K taps
                         (K = 4: the "mid"/"low" presets, 6: "high"), shared by the render
                         pixels of each 4 x 4 block
    tp    [1,4,hp,wp]    temporal parameters (sigmoid): theta (history rectification), alpha
                         (accumulation, scaled to ALPHA_RANGE), gamma (neighbourhood clamp
                         width, x GAMMA_SCALE), feedback (read back next frame)

Layers (weight names = the torch twin's state_dict keys, weights_tools/methods/nss/twin.py),
14 3x3 convolutions, ReLU hidden, nearest x2 upsampling with concatenated skips:

    e0 12->32 s2, e1 32->32 (skip a, 1/2), e2 32->32 s2, e3 32->32 (skip b, 1/4),
    e4 32->64 s2, e5 64->64, e6 64->32                               (1/8)
    d0 up, 32->16; [d0, b] 48->32 = d1 (1/4) -> kpn 32->K*K (sigmoid)
    d2 up, 32->16; [d2, a] 48->16 = d3, d4 16->16 (1/2) -> up, tp 16->4 (sigmoid)

With config "base": "rules" (BASES; issue 53, docs/methods/nss.md "The rules' base") the
network also reads the clss-rules output (RULES_IN more channels of x: the rules' result
of this frame averaged over each render pixel's 2 x 2 output pixels, Karis tonemapped) and
has one more head beside tp, mix 16->1 (linear, at render resolution): the step's output
is the rules' output moved towards NSS's own by clamp(mix, 0, 1). Its weights start at
zero, so the untrained head gives exactly clss-rules.
"""
from __future__ import annotations

import numpy as np
import onnx

from ...networks.weights import ConfiguredWeights, zero_head
from ...networks.weights import with_rules_base as _with_rules_base
from ...pipeline.twin import NetworkBuilder, value_info

OPSET = 18
IN = 12                  # the network's input channels
TEMPORAL = 4             # theta, alpha, gamma, feedback
MULTIPLE = 8             # the network's size along each axis: a multiple of this
KPN_LEVEL = 4            # the kernel-prediction head's resolution divisor
# alpha = ALPHA_RANGE[0] + (ALPHA_RANGE[1] - ALPHA_RANGE[0]) * sigmoid; gamma = GAMMA_SCALE * sigmoid
ALPHA_RANGE = (0.05, 0.40)
GAMMA_SCALE = 2.0
THETA_SHARPEN = 2.0      # theta = t^g / (t^g + (1-t)^g), g = 2: the model gym's sharp theta
KPN_EPS = 1e-7           # the smallest kernel weight (a sum of them is never 0)
CLAMP_EPS = 1e-7         # the smallest variance of the neighbourhood clamp
TM_MAX = 1.0 - 2.0 ** -20   # accumulated Karis values are clamped below 1 (invertible)
COLOR_MAX = 65504.0      # linear colour is clamped to [0, half max] (the model gym's MaxHalf)
# Disocclusion (reversed-Z): the reconstructed previous depth dr (the current depth scattered
# to the previous frame, the nearest kept) read bilinearly at p + motion, against the
# pixel's own depth d: rel = max(dr - d, 0) / (DEPTH_TOL * max(d, dr) + DEPTH_FLOOR),
# disocclusion = clip(rel - 1, 0, 1): 0 while something nearer landed within DEPTH_TOL,
# 1 beyond twice it, continuous between; 1 where p + motion leaves the frame, and on a reset.
DEPTH_TOL = 0.05
DEPTH_FLOOR = 1e-6
SCATTER_WMIN = 0.1       # bilinear weight a tap needs to receive a scattered depth
GATHER_RADIUS = 2        # the portable depth path's search radius (render pixels)
# The luma derivative (flicker of thin features): luma l of the tonemapped colour, the
# previous (l, derivative) warped; t = clip((|l - l_prev| - D_MIN) / (D_MAX - D_MIN), 0, 1),
# rate = D_ALPHA (1 - 0.9 min(deriv_prev / D_MAX, 1)), deriv = (deriv_prev + rate (t^1.5 -
# deriv_prev)) (1 - disocclusion).
D_MIN, D_MAX, D_ALPHA = 0.05, 0.3, 0.1
LUMA = (0.2126, 0.7152, 0.0722)

QUALITY = {"low": 4, "mid": 4, "high": 6}
# The step's base (config "base", issue 53 part 2): "paper" (files without the key: NSS as
# the model gym builds it, its own accumulation is the output) or "rules": clss-rules'
# frame step runs beside NSS's (its own history, clipped into the render neighbourhood's
# colour box and blended by its 1/(1+n) rule; clss/methods/clss's rule-mode kernels asked
# of the method registry), its output is RULES_IN more channels of the network's input and
# the base of the output: out = rules + clamp(mix, 0, 1) (nss - rules), per output pixel,
# linear; mix = 0 (the head's weights at zero) is clss-rules exactly. NSS's history is the
# output, so its accumulation refines the rules' result too.
BASES = ("paper", "rules")
RULES_IN = 3


def make_config(scale=2.0, quality="mid", base="paper") -> dict:
    s = float(scale)
    if s != 2.0:
        raise ValueError(f"scale: NSS runs at 2x (its kernel-prediction taps and jitter "
                         f"offsets are per output pixel of a 2x grid), got {scale!r}")
    if quality not in QUALITY:
        raise ValueError(f"quality: expected one of {', '.join(QUALITY)}, got {quality!r}")
    if base not in BASES:
        raise ValueError(f"base: expected one of {', '.join(BASES)}, got {base!r}")
    cfg = {"scale": 2, "quality": quality, "kpn": QUALITY[quality], "name": quality}
    if base != "paper":         # configs without the key: the paper's form
        cfg["base"] = base
    return cfg


def rules_base(cfg) -> bool:
    """True where the step refines clss-rules' output (config "base": "rules")."""
    from .. import config_base
    return config_base(cfg, BASES, "paper", "NSS") == "rules"


def in_channels(cfg) -> int:
    """The network's input channels: IN, and RULES_IN more with the rules' base."""
    return IN + (RULES_IN if rules_base(cfg) else 0)


def layer_shapes(cfg) -> dict:
    """name -> (cout, cin, k) of every conv."""
    K = int(cfg["kpn"])
    out = {"e0": (32, in_channels(cfg), 3), "e1": (32, 32, 3), "e2": (32, 32, 3), "e3": (32, 32, 3),
           "e4": (64, 32, 3), "e5": (64, 64, 3), "e6": (32, 64, 3),
           "d0": (16, 32, 3), "d1": (32, 48, 3), "kpn": (K * K, 32, 3),
           "d2": (16, 32, 3), "d3": (16, 48, 3), "d4": (16, 16, 3), "tp": (TEMPORAL, 16, 3)}
    if rules_base(cfg):
        out["mix"] = (1, 16, 3)
    return out


STRIDE2 = ("e0", "e2", "e4")
# each layer's output resolution divisor (for the MACs)
LEVEL = {"e0": 2, "e1": 2, "e2": 4, "e3": 4, "e4": 8, "e5": 8, "e6": 8, "d0": 4, "d1": 4,
         "kpn": 4, "d2": 2, "d3": 2, "d4": 2, "tp": 1, "mix": 1}


def init_weights(cfg, seed=0) -> dict:
    """Seeded He-normal init, zero biases; the heads start small (sigmoid 0.5 everywhere:
    an even kernel, alpha in the middle of its range); the rules' base's mix head at zero
    (the step is clss-rules')."""
    g = np.random.default_rng(seed)
    out = {}
    for name, (co, ci, k) in layer_shapes(cfg).items():
        if name == "mix":
            continue
        std = np.sqrt(2.0 / (ci * k * k)) * (0.1 if name in ("kpn", "tp") else 1.0)
        out[f"{name}.weight"] = g.normal(0, std, (co, ci, k, k)).astype(np.float32)
        out[f"{name}.bias"] = np.zeros(co, np.float32)
    if rules_base(cfg):
        out.update(zero_mix(cfg))
    return out


def zero_mix(cfg) -> dict:
    """The mix head's tensors at zero: clamp(mix, 0, 1) = 0, the output is the rules'."""
    return zero_head("mix", layer_shapes(cfg))


def with_rules_base(cfg, weights) -> tuple[dict, dict]:
    """(cfg, weights) of paper-form NSS weights given the rules' base: e0 reads RULES_IN
    more channels (their weights zero), the mix head at zero. The step is then exactly
    clss-rules, and the network as trained (a fine-tune's start)."""
    if rules_base(cfg):
        return dict(cfg), dict(weights)
    return _with_rules_base(cfg, weights, key="base", layer="e0", layer_shapes=layer_shapes,
                            check=check_weights)


FILE = ConfiguredWeights("nss", "nss_config", layer_shapes,
                         describe=lambda cfg: f"({cfg.get('quality')}, x{cfg['scale']})")
check_weights, save, load = FILE.check, FILE.save, FILE.load


def parameter_count(cfg) -> int:
    return sum(co * ci * k * k + co for co, ci, k in layer_shapes(cfg).values())


def macs_per_pixel(cfg) -> float:
    """Multiply-adds per render pixel."""
    return sum(co * ci * k * k / LEVEL[n] ** 2 for n, (co, ci, k) in layer_shapes(cfg).items())


def _up(g, x):
    return g.op("Resize", x, "", g.const(np.array([1, 1, 2, 2], np.float32), hint="scales"),
                mode="nearest", coordinate_transformation_mode="asymmetric",
                nearest_mode="floor")


def build_network(cfg, weights, hp="h", wp="w") -> onnx.ModelProto:
    K = int(cfg["kpn"])
    g = NetworkBuilder(weights, OPSET, hidden=("Relu", None))
    c = g.conv
    a = c(c("x", "e0", "hidden", stride=2), "e1", "hidden")
    b = c(c(a, "e2", "hidden", stride=2), "e3", "hidden")
    x = c(c(c(b, "e4", "hidden", stride=2), "e5", "hidden"), "e6", "hidden")
    x = c(g.op("Concat", c(_up(g, x), "d0", "hidden"), b, axis=1), "d1", "hidden")
    c(x, "kpn", "Sigmoid", name="kpn")
    x = c(g.op("Concat", c(_up(g, x), "d2", "hidden"), a, axis=1), "d3", "hidden")
    x = _up(g, c(x, "d4", "hidden"))
    c(x, "tp", "Sigmoid", name="tp")
    rules = rules_base(cfg)
    if rules:
        c(x, "mix", name="mix")         # linear: the step clamps it to [0, 1]
    q = (lambda v: v // KPN_LEVEL) if isinstance(hp, int) else (lambda v: f"{v}/4")
    return g.model("nss_network", [value_info("x", [1, in_channels(cfg), hp, wp])],
                   [value_info("kpn", [1, K * K, q(hp), q(wp)]),
                    value_info("tp", [1, TEMPORAL, hp, wp])]
                   + ([value_info("mix", [1, 1, hp, wp])] if rules else []), __name__)


def pad8(n: int) -> int:
    """The network's size along an axis: a multiple of 8, for its three stride-2 levels."""
    return -(-int(n) // MULTIPLE) * MULTIPLE


def post_taps(render_size, jitter, K):
    """The jitter-aware tap layout of the kernel-prediction filter at 2x, float32 as the
    kernel computes it. For output pixel (X, Y): its centre in the jittered sample grid
    u = (X + 0.5) / 2 - 0.5 - jx (v likewise), the K x K render samples from floor(u) -
    (K/2 - 1), edge-clamped; each tap's weight is the network's times the separable tent
    (K/2 - |sample - u|); the centre sample is the nearest one, n = floor(u + 0.5), valid
    where it landed in this output pixel: floor((n + 0.5 + jx) * 2) == X.

    Returns per axis (for x and y): (first tap index [N] int, tent weights [K, N] float32,
    centre index [N] int (clamped), centre valid [N] bool), N the output size."""
    h, w = (int(v) for v in render_size)
    out = []
    for n, j in ((w, jitter[0]), (h, jitter[1])):
        N = 2 * n
        X = np.arange(N, dtype=np.float32)
        j = np.float32(j)
        u = (X + np.float32(0.5)) / np.float32(2.0) - np.float32(0.5) - j
        f = np.floor(u)
        first = f.astype(np.int64) - (K // 2 - 1)
        tent = np.stack([np.maximum(np.float32(K // 2) - np.abs((f + np.float32(t - (K // 2 - 1))) - u),
                                    np.float32(0.0)) for t in range(K)]).astype(np.float32)
        c = np.floor(u + np.float32(0.5))
        land = np.floor((c + np.float32(0.5) + j) * np.float32(2.0))
        ci = c.astype(np.int64)
        valid = (land == X) & (ci >= 0) & (ci < n)
        out.append((first, tent, np.clip(ci, 0, n - 1), valid))
    return out
