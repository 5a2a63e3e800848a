"""The whole NSRR frame step as one ONNX graph, run by onnxruntime: the oracle that
tests hold the OpenCL step (frame.py, nsrr.cl) to. State is explicit: the graph
takes the history [1,12N,H,W] and returns the next one.

Graph inputs (internal conventions, contract.to_internal):
    color [1,3,h,w] linear / exposure     depth [1,1,h,w] reversed-Z
    motion [1,2,h,w] render pixels        hist [1,12N,H,W] the history
    base_grid [1,H,W,2] (with the residual): where each output pixel centre lies in the
        render frame, jitter-aware (`base_grid`)
    zu_y [H], zu_x [W] int64: the render row / column whose jittered sample lands on
        each output row / column, or h / w (a zero row / column) where none does
        (computed from the jitter by `zu_index`, as nsrr.cl places samples)
    keep [1]: 1 = warp the history, 0 = a reset;  dup [1]: 1 = after a reset every
        valid slot is the current frame's features ("duplicate"), 0 = zeros
    with "base": "rules" (networks.BASES): jitter [2] render pixels and rules_hist
        [1,16,H,W], the clss-rules step's history (its oracle's, clss/methods/clss/oracle.py,
        inlined here as the base: rules_hist_out's PQ colour, channels 0-2)
Outputs: output [1,3,H,W] linear (/ exposure), hist_out [1,12N,H,W], and with the rules'
base rules_hist_out [1,16,H,W].

The networks (networks.py) are inlined: features on the render frame, then the stack
[Z_i, warped history] padded to a multiple of 4 for the reconstruction.
"""
from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto

from ...ops.zero_upsample import placement
from ...pipeline.contract import PQ_NITS, output_size
from ...pipeline.twin import GraphBuilder, TwinRunner, base_grid, make_model, pq_decode, pq_encode, value_info  # noqa: F401 (base_grid: also this module's API)
from .. import RULES_HISTORY_CHANNELS as HISTORY_CHANNELS, rules_graph
from . import networks as nets
from .frame import pad4
from .upscaler import load_weights

OPSET = 18


def zu_index(n: int, scale: float, jit: float, size: int) -> np.ndarray:
    """[size] int64: the render index placed on each output index, n where none is."""
    pos = placement(n, scale, jit, size)
    idx = np.full(size, n, np.int64)
    ok = pos >= 0
    idx[pos[ok]] = np.arange(n)[ok]
    return idx


def depth_taps(n: int, scale: float, jit: float, size: int) -> tuple[np.ndarray, np.ndarray]:
    """([size], [size]) int64: the two render samples either side of each output pixel
    centre along one axis, jitter-aware and edge-clamped, float32 operation for operation
    as nsrr.cl's base (the current depth the rejection compares)."""
    f = np.float32
    u = (np.arange(size).astype(f) + f(0.5)) / f(scale) - f(0.5) - f(jit)
    i0 = np.floor(np.clip(u, f(0), f(n - 1))).astype(np.int64)
    return i0, np.minimum(i0 + 1, n - 1)


def build_graph(render_size, scale, cfg, weights, history=None, nits=PQ_NITS) -> onnx.ModelProto:
    h, w = render_size
    H, W = output_size(h, w, scale)
    Hp, Wp = pad4(H), pad4(W)
    sy, sx = H / h, W / w
    n = cfg["n_prev"]
    nvalid = n if history is None else int(history)
    C = nets.FEAT
    g = GraphBuilder(OPSET)
    # rgbd and features at render resolution
    pq = pq_encode(g, "color", nits)
    rgbd = g.concat([pq, "depth"])
    g.inline(nets.build_features(cfg, weights, h, w), "fe", {"rgbd": rgbd}, {"feat": "feat"})
    # zero-upsampling: a zero column and row appended, then the placement gathers
    zc = g.const(np.zeros((1, C, h, 1), np.float32), np.float32, "zcol")
    z = g.op("Gather", g.concat(["feat", zc], axis=3), "zu_x", axis=3)
    zr = g.const(np.zeros((1, C, 1, W), np.float32), np.float32, "zrow")
    z = g.op("Gather", g.concat([z, zr], axis=2), "zu_y", axis=2)
    # motion: bilinear (half-pixel, edge-clamped) to output size, in output pixels
    sizes = g.i64([1, 2, H, W])
    m = g.op("Resize", "motion", "", "", sizes, mode="linear",
             coordinate_transformation_mode="half_pixel")
    mx = g.mul(g.chan(m, slice(0, 1)), g.const(np.float32(sx)))
    my = g.mul(g.chan(m, slice(1, 2)), g.const(np.float32(sy)))
    xs = g.const(np.arange(W, dtype=np.float32).reshape(1, 1, 1, W), np.float32, "xs")
    ys = g.const(np.arange(H, dtype=np.float32).reshape(1, 1, H, 1), np.float32, "ys")
    px, py = g.add(xs, mx), g.add(ys, my)
    gx = g.normalised(px, W)
    gy = g.normalised(py, H)
    grid = g.op("Transpose", g.concat([gx, gy], axis=1), perm=[0, 2, 3, 1])
    warped = g.op("GridSample", "hist", grid, mode="bilinear", padding_mode="zeros",
                  align_corners=0)
    tau = nets.reject_tau(cfg)
    if tau >= 0:
        warped = g.mul(warped, _depth_keep(g, h, w, sy, sx, px, py, tau))
    # reset: keep * warped + dup * Z in every slot; slots beyond `history` are zero
    tiled = g.op("Tile", z, g.i64([1, n, 1, 1]))
    prev = g.add(g.mul(warped, "keep"), g.mul(tiled, "dup"))
    mask = np.zeros((1, C * n, 1, 1), np.float32)
    mask[:, :C * nvalid] = 1.0
    prev = g.mul(prev, g.const(mask, np.float32, "slots"))
    stack = g.concat([z, prev])
    g.slice(stack, 1, 0, C * n)
    g.nodes[-1].output[0] = "hist_out"
    g.nodes[-1].name = "hist_out"
    padded = g.op("Pad", stack, g.i64([0, 0, 0, 0, 0, 0, Hp - H, Wp - W]), mode="constant")
    feeds = {"stack": padded}
    rules = nets.rules_base(cfg)
    if rules:
        # the rules' base: clss-rules' whole frame graph (rule mode, its defaults, no
        # reactive mask), reset where this step resets; its next history's PQ colour
        reset = g.sub(g.const(np.float32([1.0]), np.float32, "one"), "keep")
        react = g.const(np.zeros((1, 1, h, w), np.float32), np.float32, "no_reactive")
        g.inline(rules_graph((h, w), scale, nits), "rules",
                 {"color": "color", "depth": "depth", "motion": "motion", "jitter": "jitter",
                  "reset": reset, "reactive": react, "history": "rules_hist"},
                 {"history_out": "rules_hist_out", "output": "rules_output"})
        base = g.slice("rules_hist_out", 1, 0, 3)
        feeds["base"] = g.op("Pad", base, g.i64([0, 0, 0, 0, 0, 0, Hp - H, Wp - W]),
                             mode="constant")
    elif cfg.get("residual", False):
        # the residual base: the PQ colour bilinear at each output pixel centre, jitter-aware
        base = g.op("GridSample", pq, "base_grid", mode="bilinear", padding_mode="border",
                    align_corners=0)
        feeds["base"] = g.op("Pad", base, g.i64([0, 0, 0, 0, 0, 0, Hp - H, Wp - W]),
                             mode="constant")
    g.inline(nets.build_reconstruct(cfg, weights, Hp, Wp), "re", feeds, {"y": "y"})
    y = g.slice(g.slice("y", 2, 0, H), 3, 0, W)
    pq_decode(g, g.clip(y, 0.0, 1.0), nits, name="output")
    vi, i64 = value_info, TensorProto.INT64
    inputs = ([vi("color", [1, 3, h, w]), vi("depth", [1, 1, h, w]), vi("motion", [1, 2, h, w]),
               vi("hist", [1, C * n, H, W]), vi("zu_y", [H], i64), vi("zu_x", [W], i64),
               vi("keep", [1]), vi("dup", [1])]
              + ([vi("base_grid", [1, H, W, 2])] if cfg.get("residual", False) and not rules else [])
              + ([vi("jitter", [2]), vi("rules_hist", [1, HISTORY_CHANNELS, H, W])] if rules else [])
              + ([vi("depth_prev", [1, 1, h, w]), vi("dtap_y0", [H], i64), vi("dtap_y1", [H], i64),
                  vi("dtap_x0", [W], i64), vi("dtap_x1", [W], i64)] if tau >= 0 else []))
    outputs = [vi("output", [1, 3, H, W]), vi("hist_out", [1, C * n, H, W])]
    if rules:
        outputs.append(vi("rules_hist_out", [1, HISTORY_CHANNELS, H, W]))
    return make_model(g.nodes, g.inits, "nsrr_frame", inputs, outputs, __name__, OPSET)


def _depth_keep(g, h, w, sy, sx, px, py, tau):
    """[1,1,H,W] 1 / 0: nsrr.cl's depth_keep. The current range from the Gathers of the
    2x2 render samples around each pixel centre (dtap_*: depth_taps), the previous one from
    the 2x2 of depth_prev around (px + 0.5) / sx - 0.5, computed in the graph (px, py: where
    each pixel was, output pixels)."""
    f = np.float32

    def rng(taps):
        lo = g.op("Min", *taps)
        return lo, g.op("Max", *taps)

    cur = [g.op("Gather", g.op("Gather", "depth", r, axis=2), c, axis=3)
           for r in ("dtap_y0", "dtap_y1") for c in ("dtap_x0", "dtap_x1")]
    cmin, cmax = rng(cur)

    def taps(p, s, n):
        u = g.sub(g.div(g.add(p, g.const(f(0.5))), g.const(f(s))), g.const(f(0.5)))
        i0 = g.op("Floor", g.clip(u, 0.0, float(n - 1)))
        return i0, g.op("Min", g.add(i0, g.const(f(1.0))), g.const(f(n - 1)))

    (u0, u1), (v0, v1) = taps(px, sx, w), taps(py, sy, h)
    flat = g.reshape("depth_prev", [h * w])
    prev = [g.op("Gather", flat, g.op("Cast", g.add(g.mul(r, g.const(f(w))), c), to=TensorProto.INT64))
            for r in (v0, v1) for c in (u0, u1)]
    pmin, pmax = rng(prev)
    gap = g.sub(g.op("Max", cmin, pmin), g.op("Min", cmax, pmax))
    ok = g.op("LessOrEqual", gap, g.mul(g.op("Max", cmax, pmax), g.const(f(tau))))
    return g.op("Cast", ok, to=TensorProto.FLOAT)


class OracleNsrr(TwinRunner):
    """Frame-by-frame runner of the twin with the contract's `step` (onnxruntime).
    weights: as the upscaler's, except that the default is the seeded init ("untrained"),
    as every method's twin builds it (tests/test_methods.py); None = the shipped file."""

    def __init__(self, render_size, scale=4.0, weights="untrained", *, history=None,
                 reset_fill="zero", depth_inverted=True, motion_scale=(1, 1), exposure=1.0,
                 widths="default", threads=2, **unused):
        self.cfg, self.weights, _ = load_weights(weights, float(scale), widths)
        model = build_graph(tuple(int(v) for v in render_size), float(scale), self.cfg, self.weights, history)
        self._start(model, render_size, scale, depth_inverted, motion_scale, exposure, threads)
        self.reset_fill = reset_fill
        h, w = self.render_size
        self.H, self.W = output_size(h, w, self.scale)
        self.hist = np.zeros((1, nets.FEAT * self.cfg["n_prev"], self.H, self.W), np.float32)
        self.depth_prev = np.zeros((1, 1, h, w), np.float32)
        # the rules' history ("base": "rules"; zeros: only read after a reset)
        self.rules_hist = (np.zeros((1, HISTORY_CHANNELS, self.H, self.W), np.float32)
                           if nets.rules_base(self.cfg) else None)

    def step(self, color, depth, motion, jitter, reset=False, **unused):
        x, reset = self._frame(color, depth, motion, jitter, reset)
        feeds = frame_feeds(self.cfg, x, self.hist, reset, self.reset_fill, self.depth_prev,
                            self.rules_hist)
        if self.rules_hist is None:
            y, self.hist = self.session.run(["output", "hist_out"], feeds)
        else:
            y, self.hist, self.rules_hist = self.session.run(
                ["output", "hist_out", "rules_hist_out"], feeds)
        self.depth_prev = x["depth"]
        return self._image(y)


def frame_feeds(cfg, x, hist, reset, reset_fill="zero", depth_prev=None, rules_hist=None) -> dict:
    """The graph's feeds for one frame: `x` the contract's internal arrays (to_internal:
    color, depth, motion NCHW, jitter), `hist` the previous hist_out (zeros on a reset),
    `depth_prev` the previous frame's x["depth"] (the depth rejection's), `rules_hist` the
    previous rules_hist_out (the rules' base; zeros on a reset)."""
    h, w = x["depth"].shape[2:]
    H, W = hist.shape[2:]
    jx, jy = (float(v) for v in x["jitter"])
    feeds = {"color": x["color"], "depth": x["depth"], "motion": x["motion"], "hist": hist,
             "zu_y": zu_index(h, H / h, jy, H), "zu_x": zu_index(w, W / w, jx, W),
             "keep": np.array([0.0 if reset else 1.0], np.float32),
             "dup": np.array([1.0 if reset and reset_fill == "duplicate" else 0.0], np.float32)}
    if nets.rules_base(cfg):
        feeds["jitter"] = np.float32([jx, jy])
        feeds["rules_hist"] = (np.zeros((1, HISTORY_CHANNELS, H, W), np.float32) if rules_hist is None
                               else np.asarray(rules_hist, np.float32))
    elif cfg.get("residual", False):
        feeds["base_grid"] = base_grid((h, w), (H, W), (jx, jy))
    if nets.reject_tau(cfg) >= 0:
        feeds["depth_prev"] = (np.zeros_like(x["depth"]) if depth_prev is None
                               else np.asarray(depth_prev, np.float32))
        feeds["dtap_y0"], feeds["dtap_y1"] = depth_taps(h, H / h, jy, H)
        feeds["dtap_x0"], feeds["dtap_x1"] = depth_taps(w, W / w, jx, W)
    return feeds


def twin(method, render_size, scale=4.0, **kwargs):
    return OracleNsrr(render_size, scale, **kwargs)
