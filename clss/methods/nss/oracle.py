"""The whole NSS frame step as one ONNX graph, run by onnxruntime: the oracle that tests
hold the OpenCL step (frame.py, nss.cl) to. State is explicit: the graph takes the state
of the previous frame and returns the next one.

Graph inputs (internal conventions, contract.to_internal):
    color [1,3,h,w] linear / exposure   depth [1,1,h,w] reversed-Z   motion [1,2,h,w]
    hist [1,3,H,W]    the previous output (linear / exposure)
    deriv [1,2,h,w]   the previous (luma derivative, luma)
    tp [1,4,hp,wp]    the previous temporal parameters
    keep [1]: 0 on a reset
    taps [K*K*H*W] int64, tent [1,1,K*K,H,W], kq [H*W] int64, centre [H*W] int64,
    valid [1,1,H,W]: the jitter-aware tap layout (networks.post_taps, `frame_feeds`)
    with "base": "rules" (networks.BASES): jitter [2] render pixels and rules_hist
        [1,16,H,W], the clss-rules step's history (its own twin, clss/methods/clss/oracle.py,
        inlined through the method registry: its output is the base and 3 channels of x)
Outputs: output [1,3,H,W] linear (/ exposure), hist_out, deriv_out, tp_out, x (the
network's input), recon (the reconstructed previous depth, float); with the rules' base
rules_hist_out [1,16,H,W] and mix_out (the network's mix head).

The depth reprojection is ScatterElements with reduction max over indices computed in
the graph from the motion (a tap that receives nothing goes to a spare last element).
"""
from __future__ import annotations

import numpy as np
import onnx

from ...pipeline.contract import PQ_NITS
from ...pipeline.twin import GraphBuilder, TwinRunner, base_grid, make_model, value_info
from .. import RULES_HISTORY_CHANNELS, rules_graph
from . import networks as nets
from .upscaler import load_weights

OPSET = 18


def _karis(g, x):
    m = g.op("ReduceMax", x, g.i64([1]), keepdims=1)
    return g.div(x, g.add(g.const(np.float32(1.0)), m))


def _grid(g, xs, ys, w, h):
    """GridSample grid [1,h',w',2] of index coordinates xs, ys [1,1,h',w'] in a w x h image."""
    gx, gy = g.normalised(xs, w), g.normalised(ys, h)
    return g.op("Transpose", g.concat([gx, gy], axis=1), perm=[0, 2, 3, 1])


def _sample(g, x, grid, padding="zeros"):
    return g.op("GridSample", x, grid, mode="bilinear", padding_mode=padding, align_corners=0)


def _i64(g, x):
    return g.op("Cast", x, to=onnx.TensorProto.INT64)


def _scatter_depth(g, d, xs, ys, h, w):
    """kernels/scatter.cl's scatter_depth (max, cleared to 0 = far) as ScatterElements."""
    bx, by = g.op("Floor", xs), g.op("Floor", ys)
    fx, fy = g.sub(xs, bx), g.sub(ys, by)
    one = g.const(np.float32(1.0))
    idx, upd = [], []
    dd = g.reshape(d, [h * w])
    for b in (0, 1):
        for a in (0, 1):
            tx = g.add(bx, g.const(np.float32(a))) if a else bx
            ty = g.add(by, g.const(np.float32(b))) if b else by
            wx = fx if a else g.sub(one, fx)
            wy = fy if b else g.sub(one, fy)
            wk = g.mul(wx, wy)
            ok = g.op("Greater", wk, g.const(np.float32(nets.SCATTER_WMIN)))
            for v, n in ((tx, w), (ty, h)):
                ok = g.op("And", ok, g.op("GreaterOrEqual", v, g.const(np.float32(0.0))))
                ok = g.op("And", ok, g.op("Less", v, g.const(np.float32(n))))
            lin = g.add(g.mul(_i64(g, g.op("Clip", ty, g.const(np.float32(0)),
                                             g.const(np.float32(h - 1)))), g.i64(w)),
                        _i64(g, g.op("Clip", tx, g.const(np.float32(0)), g.const(np.float32(w - 1)))))
            idx.append(g.reshape(g.where(ok, lin, g.i64(h * w)), [h * w]))
            upd.append(dd)
    data = g.const(np.zeros(h * w + 1, np.float32))
    r = g.op("ScatterElements", data, g.concat(idx, axis=0), g.concat(upd, axis=0), axis=0,
             reduction="max")
    return g.reshape(g.slice(r, 0, 0, h * w), [1, 1, h, w])


def _catmull(g, f):
    """Catmull-Rom weights of the taps at -1, 0, 1, 2 around fraction f (nss.cl's)."""
    c = lambda v: g.const(np.float32(v))  # noqa: E731
    f2 = g.mul(f, f)
    f3 = g.mul(f2, f)
    return [g.sub(g.add(g.mul(c(-0.5), f3), f2), g.mul(c(0.5), f)),
            g.add(g.sub(g.mul(c(1.5), f3), g.mul(c(2.5), f2)), c(1.0)),
            g.add(g.add(g.mul(c(-1.5), f3), g.mul(c(2.0), f2)), g.mul(c(0.5), f)),
            g.sub(g.mul(c(0.5), f3), g.mul(c(0.5), f2))]


def _coords(g, motion, h, w):
    """The motion's channels and the previous-frame positions p + motion [1,1,h,w]."""
    mx, my = g.chan(motion, slice(0, 1)), g.chan(motion, slice(1, 2))
    xg = g.const(np.arange(w, dtype=np.float32).reshape(1, 1, 1, w))
    yg = g.const(np.arange(h, dtype=np.float32).reshape(1, 1, h, 1))
    return mx, my, g.add(xg, mx), g.add(yg, my)


def _depth(g, depth, motion, h, w, name="recon"):
    """The reconstructed previous depth (scatter_depth / nss_depth_gather) as `name`."""
    _, _, xs, ys = _coords(g, motion, h, w)
    _scatter_depth(g, depth, xs, ys, h, w)
    g.nodes[-1].output[0] = name
    return name


def _pre(g, col, depth, motion, recon, hist, tp, deriv, keep, h, w, *, x="x",
         deriv_out="deriv_out", rules=None):
    """nss_pre: the network's input `x` [1,12,hp,wp] and the next derivative state; with
    `rules` (the rules' output [1,3,H,W], linear / exposure) nss_rules_in's 3 channels
    more (the 2 x 2 mean, Karis tonemapped)."""
    H, W, hp, wp = 2 * h, 2 * w, nets.pad8(h), nets.pad8(w)
    c = lambda v: g.const(np.float32(v))  # noqa: E731
    one, zero = c(1.0), c(0.0)
    mx, my, xs, ys = _coords(g, motion, h, w)
    # disocclusion from the reconstructed previous depth
    grid = _grid(g, xs, ys, w, h)
    dr = _sample(g, recon, grid)
    den = g.add(g.mul(c(nets.DEPTH_TOL), g.op("Max", depth, dr)), c(nets.DEPTH_FLOOR))
    rel = g.div(g.op("Max", g.sub(dr, depth), zero), den)
    ins = one
    for v, n in ((xs, w), (ys, h)):
        ok = g.op("And", g.op("GreaterOrEqual", v, c(-0.5)), g.op("LessOrEqual", v, c(n - 0.5)))
        ins = g.mul(ins, g.op("Cast", ok, to=onnx.TensorProto.FLOAT))
    dis = g.sub(one, g.mul(g.mul(g.sub(one, g.clip(g.sub(rel, one), 0.0, 1.0)), ins), keep))
    # the previous output warped at the render pixel centres, the colour, tonemapped
    hx = g.add(g.const((2 * np.arange(w, dtype=np.float32) + 0.5).reshape(1, 1, 1, w)),
               g.mul(c(2.0), mx))
    hy = g.add(g.const((2 * np.arange(h, dtype=np.float32) + 0.5).reshape(1, 1, h, 1)),
               g.mul(c(2.0), my))
    hc = _karis(g, g.mul(_sample(g, hist, _grid(g, hx, hy, W, H)), keep))
    cc = _karis(g, col)
    tpr = g.slice(g.slice(tp, 2, 0, h), 3, 0, w)
    fb = g.mul(g.mul(_sample(g, tpr, grid), keep), g.sub(one, dis))
    s = g.mul(_sample(g, deriv, grid), keep)
    dp, lp = g.chan(s, slice(0, 1)), g.chan(s, slice(1, 2))
    lum = g.const(np.asarray(nets.LUMA, np.float32).reshape(1, 3, 1, 1))
    lum_ = g.op("ReduceSum", g.mul(cc, lum), g.i64([1]), keepdims=1)
    tt = g.clip(g.div(g.sub(g.op("Abs", g.sub(lum_, lp)), c(nets.D_MIN)),
                      c(nets.D_MAX - nets.D_MIN)), 0.0, 1.0)
    rate = g.mul(c(nets.D_ALPHA), g.sub(one, g.mul(c(0.9), g.op("Min", g.div(dp, c(nets.D_MAX)), one))))
    der = g.mul(g.add(dp, g.mul(rate, g.sub(g.mul(tt, g.op("Sqrt", tt)), dp))), g.sub(one, dis))
    g.concat([der, lum_], name=deriv_out)
    parts = [hc, cc, dis, fb, der]
    if rules is not None:
        parts.append(_karis(g, g.op("AveragePool", rules, kernel_shape=[2, 2], strides=[2, 2])))
    xc = g.concat(parts)
    g.op("Pad", xc, g.i64([0, 0, 0, 0, 0, 0, hp - h, wp - w]), mode="edge", name=x)
    return x, deriv_out


def _post(g, col, motion, kpn, tp, hist, keep, K, h, w, *, out="output"):
    """nss_post: the kernel-prediction filter (the tap layout: the feeds taps, tent, kq,
    centre, valid), the Catmull-Rom history, clamp, rectify, accumulate -> `out`."""
    H, W, hp, wp = 2 * h, 2 * w, nets.pad8(h), nets.pad8(w)
    c = lambda v: g.const(np.float32(v))  # noqa: E731
    one = c(1.0)
    # the kernel-prediction filter (jitter-aware taps: the feeds)
    cflat = g.reshape(col, [1, 3, h * w])
    taps = g.reshape(g.op("Gather", cflat, "taps", axis=2), [1, 3, K * K, H, W])
    kw = g.op("Gather", g.reshape(kpn, [1, K * K, (hp // 4) * (wp // 4)]), "kq", axis=2)
    kw = g.mul(g.op("Max", g.reshape(kw, [1, 1, K * K, H, W]), c(nets.KPN_EPS)), "tent")
    ax2 = g.i64([2])
    ws = g.op("ReduceSum", kw, ax2, keepdims=0)
    m1 = g.div(g.op("ReduceSum", g.mul(kw, taps), ax2, keepdims=0), ws)
    m2 = g.div(g.op("ReduceSum", g.mul(kw, g.mul(taps, taps)), ax2, keepdims=0), ws)
    # the temporal parameters at the output pixels
    tpo = g.slice(g.slice(tp, 2, 0, h), 3, 0, w)
    pr = _sample(g, tpo, g.const(base_grid((h, w), (H, W), (0.0, 0.0))), "border")
    p0, p1, p2 = (g.chan(pr, slice(i, i + 1)) for i in range(3))
    ta, tb = g.mul(p0, p0), g.mul(g.sub(one, p0), g.sub(one, p0))
    theta = g.div(ta, g.op("Max", g.add(ta, tb), c(1e-6)))
    alpha = g.add(c(nets.ALPHA_RANGE[0]), g.mul(c(nets.ALPHA_RANGE[1] - nets.ALPHA_RANGE[0]), p1))
    gamma = g.mul(c(nets.GAMMA_SCALE), p2)
    # the previous output, Catmull-Rom at the pixel moved by its render pixel's motion
    mu = g.op("Resize", motion, "", g.const(np.array([1, 1, 2, 2], np.float32)),
              mode="nearest", coordinate_transformation_mode="asymmetric", nearest_mode="floor")
    Hx = g.add(g.const(np.arange(W, dtype=np.float32).reshape(1, 1, 1, W)),
               g.mul(c(2.0), g.chan(mu, slice(0, 1))))
    Hy = g.add(g.const(np.arange(H, dtype=np.float32).reshape(1, 1, H, 1)),
               g.mul(c(2.0), g.chan(mu, slice(1, 2))))
    ons = one
    for v, n in ((Hx, W), (Hy, H)):
        ok = g.op("And", g.op("GreaterOrEqual", v, c(-0.5)), g.op("LessOrEqual", v, c(n - 0.5)))
        ons = g.mul(ons, g.op("Cast", ok, to=onnx.TensorProto.FLOAT))
    fhx, fhy = g.op("Floor", Hx), g.op("Floor", Hy)
    wxs, wys = _catmull(g, g.sub(Hx, fhx)), _catmull(g, g.sub(Hy, fhy))
    x0 = _i64(g, g.op("Clip", fhx, c(-4.0), c(W + 4.0)))
    y0 = _i64(g, g.op("Clip", fhy, c(-4.0), c(H + 4.0)))
    cols = [g.op("Clip", g.add(x0, g.i64(i - 1)), g.i64(0), g.i64(W - 1)) for i in range(4)]
    rows = [g.mul(g.op("Clip", g.add(y0, g.i64(j - 1)), g.i64(0), g.i64(H - 1)), g.i64(W))
            for j in range(4)]
    hflat = g.reshape(hist, [1, 3, H * W])
    hv = None
    for j in range(4):
        r = None
        for i in range(4):
            t = g.op("Gather", hflat, g.reshape(g.add(rows[j], cols[i]), [H * W]), axis=2)
            t = g.mul(wxs[i], g.reshape(t, [1, 3, H, W]))
            r = t if r is None else g.add(r, t)
        t = g.mul(wys[j], r)
        hv = t if hv is None else g.add(hv, t)
    wh = g.clip(hv, 0.0, nets.COLOR_MAX)
    sg = g.mul(g.op("Sqrt", g.op("Max", g.op("Abs", g.sub(m2, g.mul(m1, m1))), c(nets.CLAMP_EPS))),
               gamma)
    hcl = g.add(m1, g.mul(g.sub(g.op("Min", g.op("Max", wh, g.sub(m1, sg)), g.add(m1, sg)), m1), keep))
    rect = g.add(hcl, g.mul(g.sub(wh, hcl), g.mul(g.mul(theta, ons), keep)))
    cen = g.reshape(g.op("Gather", cflat, "centre", axis=2), [1, 3, H, W])
    rt, ct = _karis(g, rect), _karis(g, cen)
    ak = g.mul(g.mul(alpha, "valid"), keep)
    acc = g.clip(g.add(rt, g.mul(g.sub(ct, rt), ak)), 0.0, nets.TM_MAX)
    inv = g.div(one, g.sub(one, g.op("ReduceMax", acc, g.i64([1]), keepdims=1)))
    g.op("Mul", acc, inv, name=out)
    return out


def _mix(g, nss, rules, mix, h, w, *, out="output"):
    """nss_rules_mix: rules + clamp(mix, 0, 1) (nss - rules), the mix [1,1,hp,wp] at the
    output pixels as the temporal parameters are read."""
    H, W = 2 * h, 2 * w
    m = _sample(g, g.slice(g.slice(mix, 2, 0, h), 3, 0, w),
                g.const(base_grid((h, w), (H, W), (0.0, 0.0))), "border")
    g.op("Add", rules, g.mul(g.clip(m, 0.0, 1.0), g.sub(nss, rules)), name=out)
    return out


def _tap_inputs(K, h, w):
    vi = value_info
    H, W = 2 * h, 2 * w
    f, i64 = onnx.TensorProto.FLOAT, onnx.TensorProto.INT64
    return [vi("taps", [K * K * H * W], i64), vi("tent", [1, 1, K * K, H, W], f),
            vi("kq", [H * W], i64), vi("centre", [H * W], i64), vi("valid", [1, 1, H, W])]


def build_graph(render_size, cfg, weights) -> onnx.ModelProto:
    h, w = (int(v) for v in render_size)
    H, W, hp, wp = 2 * h, 2 * w, nets.pad8(h), nets.pad8(w)
    K = int(cfg["kpn"])
    g = GraphBuilder(OPSET)
    col = g.clip("color", 0.0, nets.COLOR_MAX)
    recon = _depth(g, "depth", "motion", h, w)
    rules = nets.rules_base(cfg)
    if rules:
        # the rules' base: clss-rules' whole frame graph (rule mode, its defaults, no
        # reactive mask), reset where this step resets, at the units NSS runs in
        reset = g.sub(g.const(np.float32([1.0])), "keep")
        react = g.const(np.zeros((1, 1, h, w), np.float32))
        g.inline(rules_graph((h, w), 2.0, PQ_NITS), "rules",
                 {"color": "color", "depth": "depth", "motion": "motion", "jitter": "jitter",
                  "reset": reset, "reactive": react, "history": "rules_hist"},
                 {"history_out": "rules_hist_out", "output": "rules_output"})
    x, _ = _pre(g, col, "depth", "motion", recon, "hist", "tp", "deriv", "keep", h, w,
                rules="rules_output" if rules else None)
    g.inline(nets.build_network(cfg, weights, hp, wp), "net", {"x": x},
             {"kpn": "kpn", "tp": "tp_out", **({"mix": "mix_out"} if rules else {})})
    if rules:
        _post(g, col, "motion", "kpn", "tp_out", "hist", "keep", K, h, w, out="nss_output")
        _mix(g, "nss_output", "rules_output", "mix_out", h, w)
    else:
        _post(g, col, "motion", "kpn", "tp_out", "hist", "keep", K, h, w)
    g.op("Identity", "output", name="hist_out")
    vi = value_info
    inputs = [vi("color", [1, 3, h, w]), vi("depth", [1, 1, h, w]), vi("motion", [1, 2, h, w]),
              vi("hist", [1, 3, H, W]), vi("deriv", [1, 2, h, w]),
              vi("tp", [1, nets.TEMPORAL, hp, wp]), vi("keep", [1]), *_tap_inputs(K, h, w)]
    outputs = [vi("output", [1, 3, H, W]), vi("hist_out", [1, 3, H, W]),
               vi("deriv_out", [1, 2, h, w]), vi("tp_out", [1, nets.TEMPORAL, hp, wp]),
               vi("x", [1, nets.in_channels(cfg), hp, wp]), vi("recon", [1, 1, h, w])]
    if rules:
        inputs += [vi("jitter", [2]), vi("rules_hist", [1, RULES_HISTORY_CHANNELS, H, W])]
        outputs += [vi("rules_hist_out", [1, RULES_HISTORY_CHANNELS, H, W]),
                    vi("mix_out", [1, 1, hp, wp])]
    return make_model(g.nodes, g.inits, "nss_frame", inputs, outputs, __name__, OPSET)


# ---- one graph per kernel of nss.cl: the twins of clss verify's nss cases (the same
# nodes as the whole-frame graph above; clss/verify/cases/nss.py) ---------------------------

def inputs_graph(render_size, depth_inverted=True, motion_scale=(1.0, 1.0),
                 exposure=1.0) -> onnx.ModelProto:
    """nss_inputs: color [h,w,3], depth [h,w], motion [h,w,2] (the caller's image layout;
    non-finite values replaced as the kernel does) -> col [3,h,w], dz [h,w], mv [2,h,w]."""
    h, w = (int(v) for v in render_size)
    g = GraphBuilder(OPSET)
    c = lambda v: g.const(np.float32(v))  # noqa: E731

    def fin(x, fill):
        bad = g.op("Or", g.op("IsNaN", x), g.op("IsInf", x))
        return g.where(bad, c(fill), x)

    col = g.clip(g.mul(fin("color", 0.0), c(np.float32(1.0) / np.float32(exposure))),
                 0.0, nets.COLOR_MAX)
    g.op("Transpose", col, perm=[2, 0, 1], name="col")
    d = fin("depth", 0.0 if depth_inverted else 1.0)
    g.op("Identity" if depth_inverted else "Sub", *((d,) if depth_inverted else (c(1.0), d)),
         name="dz")
    m = g.mul(fin("motion", 0.0), g.const(np.asarray(motion_scale, np.float32)))
    g.op("Transpose", m, perm=[2, 0, 1], name="mv")
    vi = value_info
    return make_model(g.nodes, g.inits, "nss_inputs",
                      [vi("color", [h, w, 3]), vi("depth", [h, w]), vi("motion", [h, w, 2])],
                      [vi("col", [3, h, w]), vi("dz", [h, w]), vi("mv", [2, h, w])],
                      __name__, OPSET)


def depth_graph(render_size) -> onnx.ModelProto:
    """scatter_depth / nss_depth_gather: depth [1,1,h,w], motion [1,2,h,w] -> recon
    [1,1,h,w] (0 where nothing lands)."""
    h, w = (int(v) for v in render_size)
    g = GraphBuilder(OPSET)
    _depth(g, "depth", "motion", h, w)
    vi = value_info
    return make_model(g.nodes, g.inits, "nss_depth",
                      [vi("depth", [1, 1, h, w]), vi("motion", [1, 2, h, w])],
                      [vi("recon", [1, 1, h, w])], __name__, OPSET)


def pre_graph(render_size) -> onnx.ModelProto:
    """nss_pre: col, depth, motion, recon, hist, tp (the previous), deriv, keep -> x,
    deriv_out."""
    h, w = (int(v) for v in render_size)
    hp, wp = nets.pad8(h), nets.pad8(w)
    g = GraphBuilder(OPSET)
    _pre(g, "color", "depth", "motion", "recon", "hist", "tp", "deriv", "keep", h, w)
    vi = value_info
    return make_model(g.nodes, g.inits, "nss_pre",
                      [vi("color", [1, 3, h, w]), vi("depth", [1, 1, h, w]),
                       vi("motion", [1, 2, h, w]), vi("recon", [1, 1, h, w]),
                       vi("hist", [1, 3, 2 * h, 2 * w]), vi("tp", [1, nets.TEMPORAL, hp, wp]),
                       vi("deriv", [1, 2, h, w]), vi("keep", [1])],
                      [vi("x", [1, nets.IN, hp, wp]), vi("deriv_out", [1, 2, h, w])],
                      __name__, OPSET)


def post_graph(render_size, K) -> onnx.ModelProto:
    """nss_post: col, motion, kpn, tp (this frame's), hist, keep and the tap layout
    (tap_feeds) -> output [1,3,H,W] (linear / exposure: the next history)."""
    h, w = (int(v) for v in render_size)
    hp, wp = nets.pad8(h), nets.pad8(w)
    g = GraphBuilder(OPSET)
    _post(g, "color", "motion", "kpn", "tp", "hist", "keep", int(K), h, w)
    vi = value_info
    return make_model(g.nodes, g.inits, "nss_post",
                      [vi("color", [1, 3, h, w]), vi("motion", [1, 2, h, w]),
                       vi("kpn", [1, K * K, hp // 4, wp // 4]),
                       vi("tp", [1, nets.TEMPORAL, hp, wp]), vi("hist", [1, 3, 2 * h, 2 * w]),
                       vi("keep", [1]), *_tap_inputs(int(K), h, w)],
                      [vi("output", [1, 3, 2 * h, 2 * w])], __name__, OPSET)


def tap_feeds(cfg, render_size, jitter) -> dict:
    """The jitter-aware tap layout as the graph's feeds (networks.post_taps)."""
    h, w = (int(v) for v in render_size)
    K = int(cfg["kpn"])
    (fx, tx, cx, vx), (fy, ty, cy, vy) = nets.post_taps((h, w), jitter, K)
    sx = np.clip(fx[None, :] + np.arange(K)[:, None], 0, w - 1)      # [K, W]
    sy = np.clip(fy[None, :] + np.arange(K)[:, None], 0, h - 1)      # [K, H]
    taps = sy[:, None, :, None] * w + sx[None, :, None, :]            # [K(j), K(i), H, W]
    tent = ty[:, None, :, None] * tx[None, :, None, :]
    kq = (cy[:, None] // 4) * (nets.pad8(w) // 4) + cx[None, :] // 4
    return {"taps": taps.reshape(-1).astype(np.int64),
            "tent": tent.reshape(1, 1, K * K, 2 * h, 2 * w).astype(np.float32),
            "kq": kq.reshape(-1).astype(np.int64),
            "centre": (cy[:, None] * w + cx[None, :]).reshape(-1).astype(np.int64),
            "valid": (vy[:, None] & vx[None, :]).astype(np.float32)[None, None]}


def zero_state(cfg, render_size) -> dict:
    h, w = render_size
    st = {"hist": np.zeros((1, 3, 2 * h, 2 * w), np.float32),
          "deriv": np.zeros((1, 2, h, w), np.float32),
          "tp": np.zeros((1, nets.TEMPORAL, nets.pad8(h), nets.pad8(w)), np.float32)}
    if nets.rules_base(cfg):
        st["rules_hist"] = np.zeros((1, RULES_HISTORY_CHANNELS, 2 * h, 2 * w), np.float32)
    return st


def frame_feeds(cfg, x, st, reset) -> dict:
    """The graph's feeds for one frame: `x` the contract's internal arrays (to_internal),
    `st` the previous outputs {hist, deriv, tp} (and rules_hist with the rules' base)."""
    h, w = x["depth"].shape[2:]
    feeds = {"color": x["color"], "depth": x["depth"], "motion": x["motion"],
             "keep": np.array([0.0 if reset else 1.0], np.float32)}
    feeds.update(tap_feeds(cfg, (h, w), x["jitter"]))
    if nets.rules_base(cfg):
        feeds["jitter"] = np.asarray(x["jitter"], np.float32).reshape(2)
    feeds.update(st)
    return feeds


class OracleNss(TwinRunner):
    """Frame-by-frame runner of the twin with the contract's `step` (onnxruntime).
    weights: as the upscaler's, except that the default is the seeded init."""

    OUTPUTS = ("output", "hist_out", "deriv_out", "tp_out", "x", "recon")

    def __init__(self, render_size, scale=2.0, weights="untrained", *, depth_inverted=True,
                 motion_scale=(1, 1), exposure=1.0, quality="mid", threads=2, **unused):
        self.cfg, self.weights, _ = load_weights(weights, float(scale), quality)
        self._start(build_graph(tuple(int(v) for v in render_size), self.cfg, self.weights), render_size,
                    scale, depth_inverted, motion_scale, exposure, threads)
        self.st = zero_state(self.cfg, self.render_size)
        self.last: dict = {}

    def step(self, color, depth, motion, jitter, reset=False, **unused):
        x, reset = self._frame(color, depth, motion, jitter, reset)
        names = self.OUTPUTS + (("rules_hist_out", "mix_out") if nets.rules_base(self.cfg) else ())
        outs = dict(zip(names, self.session.run(list(names),
                                                frame_feeds(self.cfg, x, self.st, reset))))
        self.st = {"hist": outs["hist_out"], "deriv": outs["deriv_out"], "tp": outs["tp_out"]}
        if "rules_hist_out" in outs:
            self.st["rules_hist"] = outs["rules_hist_out"]
        self.last = outs
        return self._image(outs["output"])


def twin(method, render_size, scale=2.0, **kwargs):
    return OracleNss(render_size, scale, **kwargs)
