"""NSRD's network (Li et al. 2024, Fig. 2 and section 3.3) as one ONNX graph, from named
weights, and the constants of the frame step around it.

One network per integer scale s, at render resolution (padded to even, for the one
down/up level), in the PQ domain of the lighting:

    cur   [1,10,hp,wp]    the current frame: lighting (PQ, 3), material (3), normal (3),
                          depth (1)
    warp  [1,8,hp,wp]     the lighting of frames i-1 and i-2 warped to frame i (PQ) with
                          their occlusion masks: w1 (3), v1 (1), w2 (3), v2 (1)
    prev  [1,3s^2,hp,wp]  the previous output's lighting (PQ), warped at output resolution
                          and pixel-unshuffled (torch order: channel c*s*s + i*s + j)
    h, c  [1,hid,hp,wp]   the ConvLSTM state
 -> y     [1,3s^2,hp,wp]  the output lighting's correction, sub-pixel (pixel shuffle CRD
                          = DepthToSpace CRD makes it H x W; the finish kernel adds the
                          current lighting to it: bilinear, or guided, BASES)
    h_out, c_out          the next state

Layers (weight names = the torch twin's state_dict keys, weights_tools/methods/nsrd/twin.py):
    ga.f, ga.g   reliable warping: a gated conv over [cur, warp]: LeakyReLU(f) * sigmoid(g)
    pf, cf       features of prev and of cur (LeakyReLU)
    lstm         ConvLSTM gates over [gated, pf, cf, h] -> i, f, o, g (4 x hid)
    dn           3x3 stride-2 conv (the U's down level) -> RCAB r1 at half resolution
    up           3x3 conv to 4 x hid, DepthToSpace CRD 2 (sub-pixel up), + h (skip)
    r0           RCAB at full render resolution
    out          3x3 conv to 3 s^2
    RCAB rK: x + conv(LeakyReLU(conv(x))) * sigmoid(conv1x1(ReLU(conv1x1(GAP(.)))))

With config "out_base": "rules" (OUT_BASES; issue 53 part 2, docs/methods/nsrd.md "The
rules' base") prev has 3s^2 more channels, the clss-rules output of this frame (its
history's PQ colour, pixel-unshuffled like the previous output), which pf reads beside the
previous output, and one more head beside out, mix (hid -> s^2, 3x3, linear, sub-pixel: one
value per output pixel): the step's output is the rules' moved towards NSRD's own by
clamp(mix, 0, 1). Its weights start at zero, so the untrained head gives exactly clss-rules.

Widths are far below the paper's (64 channels, 4+ RCAB groups): the training here runs on
one CPU thread for about half an hour (docs/methods/nsrd.md).
"""
from __future__ import annotations

import numpy as np
import onnx
from onnx import helper, numpy_helper

from ...networks.weights import ConfiguredWeights, preset_widths, zero_head
from ...networks.weights import with_rules_base as _with_rules_base
from ...pipeline.twin import NetworkBuilder, base_grid, value_info  # noqa: F401 (base_grid: also this module's API)

OPSET = 18
CUR = 10                 # lighting 3, material 3, normal 3, depth 1
WARP = 8                 # w1 3, v1 1, w2 3, v2 1
STATE = 8                # the render-res history: L (3), M (1), A (3), depth (1)
ALPHA = 0.1              # LeakyReLU slope

# Demodulation: material m = albedo where albedo >= DEMOD_EPS (per channel), else 1.
# Lighting = colour / m; the output = lighting_hr * m_hr with the same rule at output
# resolution. Where the material is black (sky: albedo 0, or a black texture) dividing
# would blow noise up by 1/albedo; with m = 1 there the lighting is the radiance itself
# and the network super-resolves it directly, as a method without demodulation does.
# 0.01 is below any lit texture value that matters (8-bit sRGB 26/255 is 0.01 linear).
DEMOD_EPS = 0.01
# The output-resolution material is the contract's albedo_hr (one point sample at each
# output pixel centre) filtered with this separable 3x3 binomial, edge-clamped, before the
# eps rule: the reference (and any anti-aliased display) integrates each pixel's
# footprint, and re-modulating by point samples put the texture's aliasing back into the
# output (held-out 4x, the bilinear lighting alone: 21.5 dB with point samples, 22.6 dB
# filtered; docs/methods/nsrd.md).
MATERIAL_FILTER = (0.25, 0.5, 0.25)
# Re-modulation ("remod" in the config): "blur", the filtered material above; "learned",
# a per-output-pixel blend alpha * point + (1 - alpha) * filtered, alpha = sigmoid of s^2
# more output channels of the network (sub-pixel, like the lighting). Neither fixed
# material explains the reference everywhere: with the true lighting (the reference box-
# downsampled to render resolution, upsampled), point samples win on low-frequency
# textures and lose 2-5 dB on textures finer than the output pixels, the filter the other
# way round (docs/methods/nsrd.md); the network sees the render-resolution albedo and
# judges which one a pixel needs.
REMODS = ("blur", "learned")
# The base the network's lighting correction is added to ("base" in the config; files
# without the key are "bilinear"): "bilinear", the current lighting read bilinearly at the
# output pixel centre; "guided", a material-guided (joint bilateral) upsampling: the 4 x 4
# render samples around the centre, each weighted by a tent of radius 2 render pixels
# times how close its material is to the output pixel's point material,
#   w = tent_x * tent_y * (exp(-|m_q - m_p|^2 / GUIDE_SIGMA^2) + GUIDE_FLOOR)
# (|.|^2 over the three channels, the eps rule's materials). Bilinear lighting mixes the
# two sides of every material edge, and re-modulation turns that into a halo: a sky
# sample (material 1, lighting = radiance) next to a lit particle (lighting = irradiance)
# brightens the sky around it and darkens the particle. Measured on the Blender
# validation split, the base alone (no network): 24.6 dB bilinear with the filtered
# material, 26.8 guided with the point material (docs/methods/nsrd.md). GUIDE_SIGMA was
# picked there (0.1 / 0.2 / 0.3 / 0.5: 26.5 / 26.7 / 26.8 / 26.8 dB); the floor keeps the
# weights' sum positive where no sample matches (it then falls back to the tent).
BASES = ("bilinear", "guided")
GUIDE_SIGMA = 0.3
GUIDE_FLOOR = 1e-4
GUIDE_TAPS = 4           # per axis: floor(u) - 1 .. floor(u) + 2
# The step's output base (config "out_base", issue 53 part 2; "base" above already names the
# lighting's upsampling base): "paper" (files without the key: NSRD as the paper builds it,
# its re-modulated output is the output) or "rules": clss-rules' frame step runs beside
# NSRD's (its own history, clipped into the render neighbourhood's colour box and blended by
# its 1/(1+n) rule; clss/methods/clss's rule-mode kernels asked of the method registry), its
# PQ colour is 3s^2 more channels of prev (pixel-unshuffled as the previous output is: both
# are output-resolution images, and pf reads them together) and its output the base of the
# step's: out = rules + clamp(mix, 0, 1) (nsrd - rules), per output pixel, linear; mix = 0
# (the head's weights at zero) is clss-rules exactly. NSRD's own recurrence (its state, the
# previous output's lighting, the ConvLSTM) is the paper's, untouched by the mix.
OUT_BASES = ("paper", "rules")
# The occlusion-aware mask (the contract has one kind of motion vector, not the paper's
# two): the previous frame's depth (reversed-Z, render res, kept on the device), warped
# bilinearly by the current motion, against the current depth:
#   rel = |d_warped - d| / (DEPTH_TOL * max(d, d_warped) + 1e-6),  mask = clip(2 - rel, 0, 1)
# 1 while the relative depth change is under DEPTH_TOL, 0 beyond twice it, continuous
# in between (so fp16 / fp32 / onnxruntime cannot flip a pixel at a threshold). Outside
# the previous frame the warp reads 0 (far): the mask is 0 unless the pixel is sky too.
DEPTH_TOL = 0.1
DEPTH_FLOOR = 1e-6

WIDTHS = {
    # feat: the gated / prev / cur feature widths; hid: the ConvLSTM state and the U's
    # full-resolution level; down: the half-resolution level
    "default": {"feat": 16, "hid": 16, "down": 32},
    "fast": {"feat": 8, "hid": 8, "down": 16},
}


def make_config(scale, widths="default", demod=True, mask=True, remod="blur",
                warp_state=False, base="bilinear", out_base="paper") -> dict:
    s = float(scale)
    if not s.is_integer() or not 2 <= s <= 4:
        raise ValueError(f"scale: NSRD runs at the integer scales 2, 3 and 4 (sub-pixel "
                         f"upsampling), got {scale!r}")
    w = preset_widths(widths, WIDTHS)
    if remod not in REMODS:
        raise ValueError(f"remod: expected one of {', '.join(REMODS)}, got {remod!r}")
    if base not in BASES:
        raise ValueError(f"base: expected one of {', '.join(BASES)}, got {base!r}")
    # warp_state: the ConvLSTM's h and c warped by the motion before the cell (the paper
    # carries them unwarped; with this camera motion they ghost: docs/methods/nsrd.md)
    w.update(scale=int(s), demod=bool(demod), mask=bool(mask), remod=remod,
             warp_state=bool(warp_state))
    if base != "bilinear":      # files from before the key stay byte-identical
        w["base"] = base
    if out_base not in OUT_BASES:
        raise ValueError(f"out_base: expected one of {', '.join(OUT_BASES)}, got {out_base!r}")
    if out_base != "paper":     # configs without the key: the paper's form
        w["out_base"] = out_base
    return w


def rules_base(cfg) -> bool:
    """True where the step refines clss-rules' output (config "out_base": "rules")."""
    from .. import config_base
    return config_base(cfg, OUT_BASES, "paper", "NSRD", key="out_base") == "rules"


def prev_channels(cfg) -> int:
    """The network's prev input: the previous output's lighting (3 s^2), and with the
    rules' base the rules' PQ colour (3 s^2 more), both pixel-unshuffled."""
    s2 = 3 * int(cfg["scale"]) ** 2
    return s2 * (2 if rules_base(cfg) else 1)


def guided(cfg) -> bool:
    return cfg.get("base", "bilinear") == "guided"


def guide_taps(render_size, out_size, jitter) -> tuple[np.ndarray, np.ndarray]:
    """The guided base's taps, for the twins: (index [16,H,W] int64 into the flattened
    render frame, tent weight [16,H,W] float32), tap k = (dy + 1) * 4 + (dx + 1) for
    dy, dx in -1..2 around floor(u), floor(v) of the output pixel centre (u, v) in the
    render frame (jitter-aware, clamped to it as the bilinear base is); indices clamped
    to the frame. float32 arithmetic in the kernel's order."""
    (h, w), (H, W) = render_size, out_size
    f32 = np.float32
    s = f32(W / w)
    jx, jy = (f32(v) for v in jitter)
    u = np.clip((np.arange(W, dtype=f32) + f32(0.5)) / s - f32(0.5) - jx, f32(0), f32(w - 1))
    v = np.clip((np.arange(H, dtype=f32) + f32(0.5)) / s - f32(0.5) - jy, f32(0), f32(h - 1))
    b0, c0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    idx, wgt = [], []
    for dy in range(-1, GUIDE_TAPS - 1):
        ty = c0 + dy
        wy = np.maximum(f32(0), f32(1) - np.abs(v - ty.astype(f32)) * f32(0.5))
        yi = np.clip(ty, 0, h - 1)
        for dx in range(-1, GUIDE_TAPS - 1):
            tx = b0 + dx
            wx = np.maximum(f32(0), f32(1) - np.abs(u - tx.astype(f32)) * f32(0.5))
            xi = np.clip(tx, 0, w - 1)
            idx.append(yi[:, None] * w + xi[None, :])
            wgt.append(wy[:, None] * wx[None, :])
    return np.stack(idx).astype(np.int64), np.stack(wgt).astype(f32)


def out_channels(cfg) -> int:
    """The network's output: the lighting (3 s^2, sub-pixel), and with the learned
    re-modulation s^2 blend logits."""
    s2 = int(cfg["scale"]) ** 2
    return 3 * s2 + (s2 if learned_remod(cfg) else 0)


def learned_remod(cfg) -> bool:
    return bool(cfg.get("demod", True)) and cfg.get("remod", "blur") == "learned"


def layer_shapes(cfg) -> dict:
    """name -> (cout, cin, k) of every conv."""
    F, hid, D = cfg["feat"], cfg["hid"], cfg["down"]
    sh = {"ga.f": (F, CUR + WARP, 3), "ga.g": (F, CUR + WARP, 3), "pf": (F, prev_channels(cfg), 3),
          "cf": (F, CUR, 3), "lstm": (4 * hid, 3 * F + hid, 3), "dn": (D, hid, 3)}
    for name, c in (("r1", D), ("r0", hid)):
        sh.update({f"{name}.0": (c, c, 3), f"{name}.1": (c, c, 3),
                   f"{name}.a0": (max(c // 4, 2), c, 1), f"{name}.a1": (c, max(c // 4, 2), 1)})
    sh.update({"up": (4 * hid, D, 3), "out": (out_channels(cfg), hid, 3)})
    if rules_base(cfg):
        sh["mix"] = (int(cfg["scale"]) ** 2, hid, 3)
    return sh


def init_weights(cfg, seed=0) -> dict:
    """Seeded He-normal init. The last conv starts small (the output is the bilinear
    lighting at first); the ConvLSTM's forget gate bias starts at 1 (it keeps its state);
    the rules' base's mix head at zero (the step is clss-rules')."""
    g = np.random.default_rng(seed)
    out = {}
    for name, (co, ci, k) in layer_shapes(cfg).items():
        if name == "mix":
            continue
        std = np.sqrt(2.0 / (ci * k * k))
        if name == "out":
            std *= 0.1
        out[f"{name}.weight"] = g.normal(0, std, (co, ci, k, k)).astype(np.float32)
        out[f"{name}.bias"] = np.zeros(co, np.float32)
    hid = cfg["hid"]
    out["lstm.bias"][hid:2 * hid] = 1.0
    if rules_base(cfg):
        out.update(zero_mix(cfg))
    return out


def zero_mix(cfg) -> dict:
    """The mix head's tensors at zero: clamp(mix, 0, 1) = 0, the output is the rules'."""
    return zero_head("mix", layer_shapes(cfg))


def with_rules_base(cfg, weights) -> tuple[dict, dict]:
    """(cfg, weights) of paper-form NSRD weights given the rules' base: pf reads 3 s^2 more
    channels (their weights zero), the mix head at zero. The step is then exactly
    clss-rules, and the network as trained (a fine-tune's start)."""
    if rules_base(cfg):
        return dict(cfg), dict(weights)
    return _with_rules_base(cfg, weights, key="out_base", layer="pf", layer_shapes=layer_shapes,
                            check=check_weights)


# The weights file: tensors, and the config under "nsrd_config" (clss.networks).
FILE = ConfiguredWeights("nsrd", "nsrd_config", layer_shapes,
                         describe=lambda cfg: f"({cfg.get('name')}, x{cfg['scale']})")
check_weights, save, load = FILE.check, FILE.save, FILE.load


def _rcab(g, x, name):
    r = g.conv(g.conv(x, f"{name}.0", "hidden"), f"{name}.1")
    a = g.op("GlobalAveragePool", r)
    a = g.conv(g.conv(a, f"{name}.a0", "Relu"), f"{name}.a1", "Sigmoid")
    return g.op("Add", x, g.op("Mul", r, a))


def build_network(cfg, weights, hp="h", wp="w") -> onnx.ModelProto:
    hid, s2, so = cfg["hid"], prev_channels(cfg), out_channels(cfg)
    g = NetworkBuilder(weights, OPSET, hidden=("LeakyRelu", ALPHA))
    x = g.op("Concat", "cur", "warp", axis=1)
    gated = g.op("Mul", g.conv(x, "ga.f", "hidden"), g.conv(x, "ga.g", "Sigmoid"))
    xt = g.op("Concat", gated, g.conv("prev", "pf", "hidden"), g.conv("cur", "cf", "hidden"), "h",
              axis=1)
    gates = g.conv(xt, "lstm")
    names = [f"gate_{q}" for q in "ifog"]
    sizes = g.op("Constant", value=numpy_helper.from_array(np.full(4, hid, np.int64)))
    g.nodes.append(helper.make_node("Split", [gates, sizes], names, name="split_gates", axis=1))
    i, f, o = (g.op("Sigmoid", n) for n in names[:3])
    gg = g.op("Tanh", names[3])
    c = g.op("Add", g.op("Mul", f, "c"), g.op("Mul", i, gg), name="c_out")
    h = g.op("Mul", o, g.op("Tanh", c), name="h_out")
    d = _rcab(g, g.conv(h, "dn", "hidden", stride=2), "r1")
    u = g.op("DepthToSpace", g.conv(d, "up"), blocksize=2, mode="CRD")
    u = _rcab(g, g.op("Add", u, h), "r0")
    g.conv(u, "out", name="y")
    rules = rules_base(cfg)
    if rules:
        g.conv(u, "mix", name="mix")    # linear: the step clamps it to [0, 1]
    vi = value_info
    mix = [vi("mix", [1, int(cfg["scale"]) ** 2, hp, wp])] if rules else []
    return g.model("nsrd_network",
                   [vi("cur", [1, CUR, hp, wp]), vi("warp", [1, WARP, hp, wp]),
                    vi("prev", [1, s2, hp, wp]), vi("h", [1, hid, hp, wp]),
                    vi("c", [1, hid, hp, wp])],
                   [vi("y", [1, so, hp, wp]), vi("h_out", [1, hid, hp, wp]),
                    vi("c_out", [1, hid, hp, wp])] + mix, __name__)


def macs_per_pixel(cfg) -> float:
    """Multiply-adds per render pixel (the down level's layers count a quarter)."""
    half = {"r1.0", "r1.1", "up"}
    total = 0.0
    for name, (co, ci, k) in layer_shapes(cfg).items():
        if name.endswith((".a0", ".a1")):
            continue
        m = co * ci * k * k
        total += m / 4 if name in half or name == "dn" else m
    return total


def pad2(n: int) -> int:
    """The network's size along an axis: even, for its one down/up level."""
    return -(-int(n) // 2) * 2
