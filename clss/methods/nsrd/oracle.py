"""The whole NSRD frame step as one ONNX graph, run by onnxruntime: the oracle that tests
hold the OpenCL step (frame.py, nsrd.cl) to. State is explicit: the graph takes
the state of the previous frame and returns the next one.

Graph inputs (internal conventions, contract.to_internal; G-buffers NCHW):
    color [1,3,h,w] linear / exposure   depth [1,1,h,w] reversed-Z   motion [1,2,h,w]
    albedo, normal [1,3,h,w]            albedo_hr [1,3,H,W]
    state [1,8,h,w]   the render-resolution history (nsrd.cl's file comment)
    hist [1,3,H,W]    the previous output's lighting (PQ)
    h, c [1,hid,hp,wp] the ConvLSTM state
    keep [1]: 0 on a reset          base_grid [1,H,W,2]: where each output pixel centre
                                    lies in the render frame (networks.base_grid)
    guide_idx [16HW], guide_w [1,1,16,H,W]: the guided base's taps (networks.guide_taps;
                                    only with the config's base "guided")
    with "out_base": "rules" (networks.OUT_BASES): jitter [2] render pixels and rules_hist
        [1,16,H,W], the clss-rules step's history (its own twin, clss/methods/clss/oracle.py,
        inlined: clss.methods.rules_graph)
Outputs: output [1,3,H,W] linear (/ exposure), state_out, hist_out, h_out, c_out; with the
rules' base rules_hist_out [1,16,H,W] and mix_out (the network's mix head [1,s^2,hp,wp]).
On a reset the runner feeds zero h and c (the OpenCL step zeroes its buffers).
"""
from __future__ import annotations

import numpy as np
import onnx

from ...pipeline.contract import PQ_NITS, validate_gbuffers
from .. import RULES_HISTORY_CHANNELS, rules_graph
from ...pipeline.twin import GraphBuilder, TwinRunner, make_model, pq_decode, pq_encode, value_info
from . import networks as nets
from .upscaler import GBUFFERS, load_weights

OPSET = 18


def _material(g, a, demod):
    if not demod:
        return g.const(np.ones((1, 3, 1, 1), np.float32))
    ok = g.op("GreaterOrEqual", a, g.const(np.float32(nets.DEMOD_EPS)))
    return g.where(ok, a, g.const(np.float32(1.0)))


def _warp_grid(g, motion, h, w, scale=1.0):
    """GridSample grid of p + motion (scaled), align_corners=0."""
    mx = g.chan(motion, slice(0, 1))
    my = g.chan(motion, slice(1, 2))
    if scale != 1.0:
        mx, my = g.mul(mx, g.const(np.float32(scale))), g.mul(my, g.const(np.float32(scale)))
    xs = g.const(np.arange(w, dtype=np.float32).reshape(1, 1, 1, w), np.float32, "xs")
    ys = g.const(np.arange(h, dtype=np.float32).reshape(1, 1, h, 1), np.float32, "ys")
    gx = g.normalised(g.add(xs, mx), w)
    gy = g.normalised(g.add(ys, my), h)
    return g.op("Transpose", g.concat([gx, gy], axis=1), perm=[0, 2, 3, 1])


def _guided_base(g, L, demod, h, w, H, W):
    """networks.BASES "guided": Gathers of the 16 taps, their material distance to the
    output pixel's point material, the weighted mean."""
    K = nets.GUIDE_TAPS ** 2

    def gather(x, c):           # [1,c,h,w] -> [1,c,K,H,W]
        return g.reshape(g.op("Gather", g.reshape(x, [1, c, h * w]), "guide_idx", axis=2),
                         [1, c, K, H, W])
    wt = "guide_w"
    if demod:
        d = g.sub(gather(_material(g, "albedo", True), 3),
                  g.reshape(_material(g, "albedo_hr", True), [1, 3, 1, H, W]))
        d2 = g.op("ReduceSum", g.mul(d, d), g.i64([1]), keepdims=1)
        sim = g.op("Exp", g.mul(d2, g.const(np.float32(-1.0 / nets.GUIDE_SIGMA ** 2))))
        wt = g.mul(wt, g.add(sim, g.const(np.float32(nets.GUIDE_FLOOR))))
    else:                       # every material 1: the tent alone
        wt = g.mul(wt, g.const(np.float32(1.0 + nets.GUIDE_FLOOR)))
    num = g.op("ReduceSum", g.mul(wt, gather(L, 3)), g.i64([2]), keepdims=0)
    return g.div(num, g.op("ReduceSum", wt, g.i64([2]), keepdims=0))


def build_graph(render_size, cfg, weights, nits=PQ_NITS) -> onnx.ModelProto:
    h, w = (int(v) for v in render_size)
    s = int(cfg["scale"])
    H, W, hp, wp = h * s, w * s, nets.pad2(h), nets.pad2(w)
    hid = cfg["hid"]
    g = GraphBuilder(OPSET)
    keep = "keep"
    # demodulation and the render-resolution warp of the state
    L = pq_encode(g, g.div("color", _material(g, "albedo", cfg["demod"])), nits)
    smp = g.op("GridSample", "state", _warp_grid(g, "motion", h, w), mode="bilinear",
               padding_mode="zeros", align_corners=0)
    dw = g.chan(smp, slice(7, 8))
    if cfg["mask"]:
        den = g.add(g.mul(g.const(np.float32(nets.DEPTH_TOL)), g.op("Max", "depth", dw)),
                    g.const(np.float32(nets.DEPTH_FLOOR)))
        rel = g.div(g.op("Abs", g.sub(dw, "depth")), den)
        m = g.clip(g.sub(g.const(np.float32(2.0)), rel), 0.0, 1.0)
        m = g.mul(m, keep)
    else:
        m = g.mul(g.const(np.ones((1, 1, h, w), np.float32)), keep)
    w1 = g.mul(g.chan(smp, slice(0, 3)), keep)
    w2 = g.mul(g.chan(smp, slice(4, 7)), keep)
    v2 = g.mul(m, g.chan(smp, slice(3, 4)))
    cur = g.concat([L, "albedo", "normal", "depth"])
    warp = g.concat([w1, m, w2, v2])
    g.concat([L, m, w1, "depth"], name="state_out")
    # the previous output, warped at output resolution, pixel-unshuffled (torch order)
    mhr = g.op("Resize", "motion", "", "", g.i64([1, 2, H, W]), mode="linear",
               coordinate_transformation_mode="half_pixel")
    prev = g.op("GridSample", "hist", _warp_grid(g, mhr, H, W, float(s)), mode="bilinear",
                padding_mode="zeros", align_corners=0)
    prev = g.mul(prev, keep)
    def unshuffle(x):
        return g.reshape(g.op("Transpose", g.reshape(x, [1, 3, h, s, w, s]),
                              perm=[0, 1, 3, 5, 2, 4]), [1, 3 * s * s, h, w])
    prev = unshuffle(prev)
    rules = nets.rules_base(cfg)
    if rules:
        # the rules' base: clss-rules' whole frame graph (rule mode, its defaults, no
        # reactive mask), reset where this step resets; its PQ colour after prev
        g.inline(rules_graph((h, w), float(s), nits), "rules",
                 {"color": "color", "depth": "depth", "motion": "motion", "jitter": "jitter",
                  "reset": g.sub(g.const(np.float32([1.0])), keep),
                  "reactive": g.const(np.zeros((1, 1, h, w), np.float32)),
                  "history": "rules_hist"},
                 {"history_out": "rules_hist_out", "output": "rules_output"})
        prev = g.concat([prev, unshuffle(g.chan("rules_hist_out", slice(0, 3)))])
    pads = g.i64([0, 0, 0, 0, 0, 0, hp - h, wp - w])
    feeds = {k: g.op("Pad", v, pads, mode="constant")
             for k, v in (("cur", cur), ("warp", warp), ("prev", prev))}
    if cfg.get("warp_state", False):
        grid = _warp_grid(g, "motion", h, w)
        for k in ("h", "c"):
            v = g.op("GridSample", g.slice(g.slice(k, 2, 0, h), 3, 0, w), grid, mode="bilinear",
                     padding_mode="zeros", align_corners=0)
            feeds[k] = g.op("Pad", g.mul(v, keep), g.i64([0, 0, 0, 0, 0, 0, hp - h, wp - w]),
                            mode="constant")
    else:
        feeds.update(h="h", c="c")
    g.inline(nets.build_network(cfg, weights, hp, wp), "net", feeds,
             {"y": "y", "h_out": "h_out", "c_out": "c_out", **({"mix": "mix_out"} if rules else {})})
    yc = g.slice(g.slice("y", 2, 0, h), 3, 0, w)
    y = g.op("DepthToSpace", g.slice(yc, 1, 0, 3 * s * s), blocksize=s, mode="CRD")
    if nets.guided(cfg):
        base = _guided_base(g, L, cfg["demod"], h, w, H, W)
    else:
        base = g.op("GridSample", L, "base_grid", mode="bilinear", padding_mode="border",
                    align_corners=0)
    lhr = g.op("Clip", g.add(y, base), g.const(np.float32(0.0)), g.const(np.float32(1.0)),
               name="hist_out")
    lin = pq_decode(g, lhr, nits, name="lin")
    k = np.asarray(nets.MATERIAL_FILTER, np.float32)
    k2 = np.tile((k[:, None] * k[None, :])[None, None], (3, 1, 1, 1))
    ahr = g.op("Conv", g.op("Pad", "albedo_hr", g.i64([0, 0, 1, 1, 0, 0, 1, 1]), mode="edge"),
               g.const(k2), group=3, kernel_shape=[3, 3])
    mat = _material(g, ahr, cfg["demod"])
    if nets.learned_remod(cfg):
        alpha = g.op("Sigmoid", g.op("DepthToSpace", g.slice(yc, 1, 3 * s * s, 4 * s * s),
                                     blocksize=s, mode="CRD"))
        mat = g.add(g.mul(alpha, _material(g, "albedo_hr", True)),
                    g.mul(g.sub(g.const(np.float32(1.0)), alpha), mat))
    out = g.mul(lin, mat)
    if rules:
        # rules + clamp(mix, 0, 1) (nsrd - rules), the mix sub-pixel
        m = g.clip(g.op("DepthToSpace", g.slice(g.slice("mix_out", 2, 0, h), 3, 0, w),
                        blocksize=s, mode="CRD"), 0.0, 1.0)
        out = g.add("rules_output", g.mul(m, g.sub(out, "rules_output")))
    g.op("Identity", out, name="output")
    vi = value_info
    inputs = [vi("color", [1, 3, h, w]), vi("depth", [1, 1, h, w]), vi("motion", [1, 2, h, w]),
              vi("albedo", [1, 3, h, w]), vi("normal", [1, 3, h, w]),
              vi("albedo_hr", [1, 3, H, W]), vi("state", [1, nets.STATE, h, w]),
              vi("hist", [1, 3, H, W]), vi("h", [1, hid, hp, wp]), vi("c", [1, hid, hp, wp]),
              vi("keep", [1])]
    K = nets.GUIDE_TAPS ** 2
    inputs += ([vi("guide_idx", [K * H * W], onnx.TensorProto.INT64), vi("guide_w", [1, 1, K, H, W])]
               if nets.guided(cfg) else [vi("base_grid", [1, H, W, 2])])
    outputs = [vi("output", [1, 3, H, W]), vi("state_out", [1, nets.STATE, h, w]),
               vi("hist_out", [1, 3, H, W]), vi("h_out", [1, hid, hp, wp]),
               vi("c_out", [1, hid, hp, wp])]
    if rules:
        inputs += [vi("jitter", [2]), vi("rules_hist", [1, RULES_HISTORY_CHANNELS, H, W])]
        outputs += [vi("rules_hist_out", [1, RULES_HISTORY_CHANNELS, H, W]),
                    vi("mix_out", [1, s * s, hp, wp])]
    return make_model(g.nodes, g.inits, "nsrd_frame", inputs, outputs, __name__, OPSET)


def _nchw(a):
    return np.ascontiguousarray(np.asarray(a, np.float32).transpose(2, 0, 1)[None])


def frame_feeds(cfg, x, gb, st, reset) -> dict:
    """The graph's feeds for one frame: `x` the contract's internal arrays (to_internal),
    `gb` the G-buffers (image layout), `st` the previous outputs {state, hist, h, c}."""
    h, w = x["depth"].shape[2:]
    s = int(cfg["scale"])
    feeds = {"color": x["color"], "depth": x["depth"], "motion": x["motion"],
             "albedo": _nchw(gb["albedo"]), "normal": _nchw(gb["normal"]),
             "albedo_hr": _nchw(gb["albedo_hr"]),
             "keep": np.array([0.0 if reset else 1.0], np.float32)}
    if nets.guided(cfg):
        idx, wgt = nets.guide_taps((h, w), (h * s, w * s), x["jitter"])
        feeds.update(guide_idx=idx.reshape(-1), guide_w=wgt[None, None])
    else:
        feeds["base_grid"] = nets.base_grid((h, w), (h * s, w * s), x["jitter"])
    if nets.rules_base(cfg):
        feeds["jitter"] = np.asarray(x["jitter"], np.float32).reshape(2)
    feeds.update(st)
    if reset:
        feeds["h"] = np.zeros_like(st["h"])
        feeds["c"] = np.zeros_like(st["c"])
    return feeds


def zero_state(cfg, render_size) -> dict:
    h, w = render_size
    s, hid = int(cfg["scale"]), cfg["hid"]
    hp, wp = nets.pad2(h), nets.pad2(w)
    st = {"state": np.zeros((1, nets.STATE, h, w), np.float32),
          "hist": np.zeros((1, 3, h * s, w * s), np.float32),
          "h": np.zeros((1, hid, hp, wp), np.float32), "c": np.zeros((1, hid, hp, wp), np.float32)}
    if nets.rules_base(cfg):
        st["rules_hist"] = np.zeros((1, RULES_HISTORY_CHANNELS, h * s, w * s), np.float32)
    return st


class OracleNsrd(TwinRunner):
    """Frame-by-frame runner of the twin with the contract's `step` (onnxruntime).
    weights: as the upscaler's, except that the default is the seeded init ("untrained");
    None = the shipped file."""

    def __init__(self, render_size, scale=4.0, weights="untrained", *, depth_inverted=True,
                 motion_scale=(1, 1), exposure=1.0, widths="default", threads=2, **unused):
        self.cfg, self.weights, _ = load_weights(weights, float(scale), widths)
        self._start(build_graph(tuple(int(v) for v in render_size), self.cfg, self.weights), render_size,
                    scale, depth_inverted, motion_scale, exposure, threads)
        s = int(self.cfg["scale"])
        h, w = self.render_size
        self.H, self.W = h * s, w * s
        self.st = zero_state(self.cfg, self.render_size)

    def step(self, color, depth, motion, jitter, reset=False, **gbuffers):
        x, reset = self._frame(color, depth, motion, jitter, reset)
        gb = validate_gbuffers("nsrd", GBUFFERS, (), gbuffers, self.render_size, (self.H, self.W))
        names = ["output", "state_out", "hist_out", "h_out", "c_out"]
        if nets.rules_base(self.cfg):
            names += ["rules_hist_out", "mix_out"]
        outs = dict(zip(names, self.session.run(names, frame_feeds(self.cfg, x, gb, self.st, reset))))
        self.st = {k: outs[f"{k}_out"] for k in ("state", "hist", "h", "c")}
        if "rules_hist_out" in outs:
            self.st["rules_hist"] = outs["rules_hist_out"]
        self.last = outs
        return self._image(outs["output"])


def twin(method, render_size, scale=4.0, **kwargs):
    return OracleNsrd(render_size, scale, **kwargs)
