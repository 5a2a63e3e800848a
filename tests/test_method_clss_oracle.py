"""The frame contract and the ONNX frame-step oracle (clss/methods/clss/reference.md).

A numpy transcription of reference.md is checked against the graph's debug outputs, so
the written spec, the oracle and (later) the OpenCL frame path stay one thing."""
from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest

from clss.methods.clss import contract as RC   # the CLSS frame step's own constants
from clss.pipeline import contract as C
from clss.methods.clss import oracle as O

h, w = 24, 32          # render size of the synthetic sequences
OFFS = O.DILATE_OFFSETS


def _opts():
    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    return so


def upscaler(mode="rule", render=(h, w), scale=2.0, **kw):
    return O.OracleUpscaler(render, scale, mode, session_options=_opts(), debug=True, **kw)


# ---------------------------------------------------------------- synthetic scenes
def texture(x, y):
    """Linear colour with detail near the render Nyquist limit; x, y in render pixels."""
    r = 0.45 + 0.35 * np.sin(2 * np.pi * x / 2.3) * np.sin(2 * np.pi * y / 3.1)
    g = 0.45 + 0.35 * np.sign(np.sin(2 * np.pi * (x + 0.6 * y) / 5.3))
    b = 0.30 + 0.25 * np.cos(2 * np.pi * np.hypot(x - 11.0, y - 9.0) / 2.9)
    return np.stack([r, g, b], -1).astype(np.float32)


def render(jitter, shift=0.0, hh=h, ww=w):
    jx, jy = jitter
    x = np.arange(ww, dtype=np.float64)[None, :] + 0.5 + jx - shift
    y = np.arange(hh, dtype=np.float64)[:, None] + 0.5 + jy + 0 * x
    return texture(x + 0 * y, y)


def reference_image(H, W, hh=h, ww=w, n=8):
    """Box-filtered output-resolution target, n x n samples per output pixel."""
    acc = 0
    for sy in range(n):
        for sx in range(n):
            x = (np.arange(W)[None, :] + (sx + 0.5) / n) * ww / W
            y = (np.arange(H)[:, None] + (sy + 0.5) / n) * hh / H + 0 * x
            acc = acc + texture(x + 0 * y, y)
    return acc / (n * n)


def psnr(a, b):
    return 10 * np.log10(1.0 / np.mean((a - b) ** 2))


def plane_depth(hh=h, ww=w, shift=0.0):
    x = np.arange(ww)[None, :] - shift
    return (0.3 + 0.2 * (np.arange(hh)[:, None] / hh) + 0.001 * np.sin(x) + 0 * x).astype(np.float32)


JIT = C.jitter_sequence(2.0)


# ---------------------------------------------------------------- contract
def test_output_size_and_jitter():
    assert C.output_size(540, 960, 2) == (1080, 1920)
    assert C.output_size(25, 13, 1.5) == (38, 20)        # 37.5 rounds up, 19.5 rounds up
    assert C.output_size(7, 9, 1.7) == (12, 15)
    with pytest.raises(C.FrameInputError, match="scale"):
        C.output_size(10, 10, 0.5)
    assert C.halton(1, 2) == 0.5 and C.halton(2, 2) == 0.25 and C.halton(3, 2) == 0.75
    assert abs(C.halton(1, 3) - 1 / 3) < 1e-12 and abs(C.halton(4, 3) - 4 / 9) < 1e-12
    for s, n in ((1.5, 18), (2, 32), (3, 72), (4, 128), (1.7, 24)):
        seq = C.jitter_sequence(s)
        assert seq.shape == (n, 2) and np.all(np.abs(seq) < 0.5)
    assert np.allclose(JIT[0], (0.0, 1 / 3 - 0.5)) and np.allclose(JIT[1], (-0.25, 2 / 3 - 0.5))
    assert np.allclose(C.jitter_for_frame(33, 2), JIT[1])


def test_pq_round_trip_and_anchors():
    # 100 nits (linear 1.0) -> 0.5081, 10000 nits (linear 100) -> 1, 0 -> 7.3e-7 (c1^m2).
    enc = C.pq_encode(np.array([0.0, 1.0, 100.0, 1e6, -3.0], np.float32))
    assert abs(enc[1] - 0.50808) < 1e-4 and abs(enc[2] - 1.0) < 1e-6 and enc[3] == enc[2]
    assert enc[0] < 1e-6 and enc[4] == enc[0]
    lin = np.geomspace(1e-3, 100, 200).astype(np.float32)
    assert np.allclose(C.pq_decode(C.pq_encode(lin)), lin, rtol=2e-4, atol=1e-6)


def _frame(hh=h, ww=w, dtype=np.float32):
    return (np.full((hh, ww, 3), 0.5, dtype), np.full((hh, ww), 0.5, dtype),
            np.zeros((hh, ww, 2), dtype), (0.1, -0.2))


def test_validate_accepts_and_converts():
    c, d, m, j = _frame(dtype=np.float16)
    f = C.validate_frame(c, d, m, j, np.zeros((h, w, 1), np.float16))
    assert f["color"].dtype == np.float32 and f["reactive"].shape == (h, w)
    assert f["jitter"].dtype == np.float32 and f["sanitized"] == {}
    t = C.to_internal(f, depth_inverted=False, motion_scale=(2, -1), exposure=2.0)
    assert t["color"].shape == (1, 3, h, w) and np.allclose(t["color"], 0.25)
    assert np.allclose(t["depth"], 0.5) and t["motion"].shape == (1, 2, h, w)


@pytest.mark.parametrize("bad, pattern", [
    (dict(color=np.zeros((h, w), np.float32)), r"color: expected a h x w x 3 array"),
    (dict(depth=np.zeros((h, w + 1), np.float32)), r"depth: expected shape \(24, 32\)"),
    (dict(motion=np.zeros((h, w, 3), np.float32)), r"motion: expected shape \(24, 32, 2\)"),
    (dict(color=np.zeros((h, w, 3), np.float64)), r"color: expected dtype float16 or float32"),
    (dict(depth=np.zeros((h, w), np.uint16)), r"depth: expected dtype"),
    (dict(jitter=(0.2, 0.7)), r"jitter: expected 2 finite floats in \[-0.5, 0.5\]"),
    (dict(jitter=(0.2, float("nan"))), r"jitter"),
    (dict(jitter=(0.1,)), r"jitter: expected 2 floats"),
    (dict(depth=np.full((h, w), 1.5, np.float32)), r"depth: expected values in \[0.0, 1.0\], got 768"),
    (dict(reactive=np.full((h, w), -0.1, np.float32)), r"reactive: expected values in"),
])
def test_validate_refuses(bad, pattern):
    c, d, m, j = _frame()
    args = dict(color=c, depth=d, motion=m, jitter=j, reactive=None)
    args.update(bad)
    with pytest.raises(C.FrameInputError, match=pattern):
        C.validate_frame(**args)


def test_nan_policy():
    c, d, m, j = _frame()
    c[3, 7, 1] = np.nan
    c[5, 2, 0] = np.inf
    with pytest.raises(C.FrameInputError,
                       match=r"color: expected finite values, got 2 non-finite.*row=3, col=7, channel=1"):
        C.validate_frame(c, d, m, j)
    d[0, 4] = np.nan
    m[1, 1] = np.nan
    f = C.validate_frame(c, d, m, j, sanitize=True)
    assert f["sanitized"] == {"color": 2, "depth": 1, "motion": 2}
    assert f["color"][3, 7, 1] == 0 and f["depth"][0, 4] == 0.0 and f["motion"][1, 1, 0] == 0
    assert C.validate_frame(c, d, m, j, sanitize=True, depth_inverted=False)["depth"][0, 4] == 1.0
    with pytest.raises(C.FrameInputError, match=r"depth: expected finite values, got 1 .*row=0, col=4"):
        C.validate_frame(np.zeros_like(c), d, m, j)
    with pytest.raises(C.FrameInputError, match="render_size|expected shape"):
        C.validate_frame(*_frame(), render_size=(h + 1, w))


# ---------------------------------------------------------------- numpy transcription of reference.md
def np_dilate(d, m):
    hh, ww = d.shape
    pd = np.pad(d, 1, constant_values=-1.0)
    pm = np.pad(m, ((0, 0), (1, 1), (1, 1)))
    best, bm = d.copy(), m.copy()
    for dx, dy in OFFS[1:]:
        c = pd[1 + dy:1 + dy + hh, 1 + dx:1 + dx + ww]
        take = c > best
        best = np.where(take, c, best)
        bm = np.where(take, pm[:, 1 + dy:1 + dy + hh, 1 + dx:1 + dx + ww], bm)
    return best, bm


def np_taps(m):
    hh, ww = m.shape[1:]
    ux = np.arange(ww, dtype=np.float32)[None, :] + m[0]
    uy = np.arange(hh, dtype=np.float32)[:, None] + m[1]
    x0, y0 = np.floor(ux), np.floor(uy)
    fx, fy = ux - x0, uy - y0
    for a, b in ((0, 0), (1, 0), (0, 1), (1, 1)):
        wk = (fx if a else np.float32(1) - fx) * (fy if b else np.float32(1) - fy)
        X, Y = x0 + a, y0 + b
        on = (X >= 0) & (X <= ww - 1) & (Y >= 0) & (Y <= hh - 1)
        yield wk, on, np.clip(Y, 0, hh - 1).astype(int), np.clip(X, 0, ww - 1).astype(int)


def np_recon_and_dd(dd_, m):
    hh, ww = dd_.shape
    R = np.zeros((hh, ww), np.float32)
    for wk, on, Y, X in np_taps(m):
        s = on & (wk > 0.01)
        np.maximum.at(R, (Y[s], X[s]), dd_[s])
    rs = np.zeros_like(R)
    for wk, on, Y, X in np_taps(m):
        rs = rs + R[Y, X] * on * wk
    return R, np.clip((rs - dd_) / np.maximum(rs, 1e-6), -1, 1)


def keys(t):
    a = -0.75
    t = np.abs(t)
    return np.where(t <= 1, ((a + 2) * t - (a + 3)) * t * t + 1,
                    np.where(t < 2, ((a * t - 5 * a) * t + 8 * a) * t - 4 * a, 0.0))


def np_sample(img, u, v, cubic):
    """img [C,h,w] at pixel-index coordinates u (x), v (y) [H,W]: clamp-to-edge taps."""
    _, hh, ww = img.shape
    x0, y0 = np.floor(u), np.floor(v)
    if cubic:
        ks = (-1, 0, 1, 2)
        wxs = [keys(u - (x0 + k)) for k in ks]
        wys = [keys(v - (y0 + k)) for k in ks]
    else:
        ks = (0, 1)
        wxs = [1 - (u - x0), u - x0]
        wys = [1 - (v - y0), v - y0]
    out = 0
    for ky, wy in zip(ks, wys):
        yi = np.clip(y0 + ky, 0, hh - 1).astype(int)
        row = 0
        for kx, wx in zip(ks, wxs):
            xi = np.clip(x0 + kx, 0, ww - 1).astype(int)
            row = row + wx * img[:, yi, xi]
        out = out + wy * row
    return out


def np_rule_step(color, depth, motion, jitter, reactive, history, reset, scale=2.0, cap=4,
                 thr=O.DEPTH_THRESHOLD, slope=RC.DEPTH_SLOPE):
    """reference.md, rule mode, on NCHW-less arrays ([C,h,w]); returns dict of buffers."""
    hh, ww = depth.shape
    H, W = C.output_size(hh, ww, scale)
    X = C.pq_encode(color)                                            # [3,h,w]
    d_dil, m_dil = np_dilate(depth, motion)
    R, dd = np_recon_and_dd(d_dil, m_dil)
    u = np.clip((np.arange(W) + 0.5) * ww / W - 0.5 - jitter[0], 0, ww - 1)[None, :] + np.zeros((H, 1))
    v = np.clip((np.arange(H) + 0.5) * hh / H - 0.5 - jitter[1], 0, hh - 1)[:, None] + np.zeros((1, W))
    up = np.clip(np_sample(X, u, v, True), 0, 1)
    pad = np.pad(X, ((0, 0), (1, 1), (1, 1)), constant_values=np.nan)
    win = np.stack([pad[:, 1 + dy:1 + dy + hh, 1 + dx:1 + dx + ww] for dx, dy in OFFS])
    # the clamp box: min/max narrowed to mean +- CLIP_GAMMA std (float64 here)
    mu, sd = np.nanmean(win, 0), RC.CLIP_GAMMA * np.nanstd(win, 0)
    nmin, nmax = np.maximum(np.nanmin(win, 0), mu - sd), np.minimum(np.nanmax(win, 0), mu + sd)
    # auto-reactive: the largest |dmx| + |dmy| of the dilated motion over the in-bounds 3x3
    mp = np.pad(m_dil, ((0, 0), (1, 1), (1, 1)), constant_values=np.nan)
    mwin = np.stack([mp[:, 1 + dy:1 + dy + hh, 1 + dx:1 + dx + ww] for dx, dy in OFFS])
    div = np.nanmax(np.abs(mwin - m_dil[None]).sum(1), 0)
    auto = np.clip((div - RC.AUTO_REACTIVE_LO) * RC.AUTO_REACTIVE_SLOPE, 0, RC.AUTO_REACTIVE_MAX)
    react = np.maximum(reactive, auto)
    # the depth test's difference: dd less DEPTH_SLOPE x the smaller one-sided step (x + y)
    dp = np.pad(d_dil, 1, mode="edge")
    step = (np.minimum(np.abs(np.diff(dp, axis=1)[1:-1, 1:]), np.abs(np.diff(dp, axis=1)[1:-1, :-1]))
            + np.minimum(np.abs(np.diff(dp, axis=0)[1:, 1:-1]), np.abs(np.diff(dp, axis=0)[:-1, 1:-1])))
    ddt = dd - slope * step / np.maximum(d_dil, 1e-6)
    aux = np_sample(np.concatenate([d_dil[None], m_dil, dd[None], react[None], nmin, nmax,
                                    ddt[None]]), u, v, False)
    mhr = aux[1:3] * np.array([W / ww, H / hh])[:, None, None]
    su = np.arange(W)[None, :] + mhr[0]
    sv = np.arange(H)[:, None] + mhr[1]
    valid = (su >= -0.5) & (su <= W - 0.5) & (sv >= -0.5) & (sv <= H - 0.5) & (not reset)
    uc, vc = np.clip(su, 0, W - 1), np.clip(sv, 0, H - 1)
    hc = np.clip(np_sample(history[:3], uc, vc, True), 0, 1)
    ho = np_sample(history[3:], uc, vc, False)
    wcol = np.where(valid, hc, up)
    wcnt = np.where(valid, ho[0], 0)
    wmin, wmax = np.where(valid, ho[1:4], up), np.where(valid, ho[4:7], up)
    ghost = (aux[11] > thr) | ~valid
    cnt = np.where(ghost, 0, np.minimum(wcnt + 1, cap))
    wgt = np.maximum(1 / (1 + cnt), aux[4])
    # history clip: up + t (wcol - up), one t in [0, 1] for the three channels
    d = wcol - up
    eps = RC.RULE_CLIP_EPS     # the box widened by eps on every side
    lim = np.where(d > 0, aux[8:11] + eps - up, aux[5:8] - eps - up)
    tc = np.where(d != 0, lim / np.where(d != 0, d, 1), 1)
    t = np.minimum(np.maximum(tc, 0).min(0), 1)
    hist = up + t * d
    inside = np.all((up >= aux[5:8]) & (up <= aux[8:11]), 0)   # up may overshoot the box
    assert np.all(((hist >= aux[5:8] - eps - 1e-6) & (hist <= aux[8:11] + eps + 1e-6)) | ~inside)
    out = wgt * up + (1 - wgt) * hist
    return dict(dbg_dilated_depth=d_dil, dbg_dilated_motion=m_dil, dbg_recon_depth=R,
                dbg_depth_diff=dd, dbg_upsampled=up, dbg_motion_hr=mhr, dbg_valid=valid,
                dbg_ghost=ghost, dbg_counter=cnt, dbg_w=wgt, output=C.pq_decode(out),
                history_out=np.concatenate([out, cnt[None], np.where(ghost, up, np.minimum(wmin, up)),
                                            np.where(ghost, up, np.maximum(wmax, up)),
                                            np.zeros((6, H, W))]))


def np_measurements(X, d, m, prev, reset):
    """reference.md s4b: [tdd, cc, edge, spread] [4,h,w] (compressed) of the encoded colour
    X [3,h,w], the pixel's own (entry-converted, not dilated) depth d and motion m [2,h,w]
    against prev [4,h,w] (None: none)."""
    hh, ww = d.shape
    if prev is None or reset:
        tdd = cc = np.zeros_like(d)
    else:
        qx = np.floor((np.arange(ww, dtype=np.float32)[None, :] + m[0]) + np.float32(0.5))
        qy = np.floor((np.arange(hh, dtype=np.float32)[:, None] + m[1]) + np.float32(0.5))
        on = (qx >= 0) & (qx <= ww - 1) & (qy >= 0) & (qy <= hh - 1)
        pv = prev[:, np.clip(qy, 0, hh - 1).astype(int), np.clip(qx, 0, ww - 1).astype(int)]
        pd = pv[3]
        tdd = np.where(on, np.clip((pd - d) / np.maximum(pd, np.float32(1e-6)), -1, 1), 1)
        cc = np.where(on, np.abs(X - pv[:3]).max(0), 1)
    pd_ = np.pad(d, 1, constant_values=np.nan)
    dwin = np.stack([pd_[1 + dy:1 + dy + hh, 1 + dx:1 + dx + ww] for dx, dy in OFFS])
    dmax, dmin = np.nanmax(dwin, 0), np.nanmin(dwin, 0)
    edge = (dmax - dmin) / np.maximum(dmax, np.float32(1e-6))
    px = np.pad(X, ((0, 0), (1, 1), (1, 1)), constant_values=np.nan)
    xwin = np.stack([px[:, 1 + dy:1 + dy + hh, 1 + dx:1 + dx + ww] for dx, dy in OFFS])
    spread = (np.nanmax(xwin, 0) - np.nanmin(xwin, 0)).max(0)
    return np.stack([v / (np.abs(v) + np.float32(k))
                     for v, k in zip((tdd, cc, edge, spread), RC.MEASURE_KNEES)]).astype(np.float32)


def np_measurements_hr(meas, H, W):
    """reference.md s4b: output pixel (I, J) takes the measurements of render pixel
    (((2I + 1) h) // (2H), ((2J + 1) w) // (2W)), the one holding its centre."""
    _, hh, ww = meas.shape
    ri = (2 * np.arange(H) + 1) * hh // (2 * H)
    rj = (2 * np.arange(W) + 1) * ww // (2 * W)
    return meas[:, ri][:, :, rj]


def test_measurements_match_numpy_reference():
    """Net mode's measurements (reference.md s4b) in the graph against np_measurements, at
    an odd size over 4 frames with a reset at frame 2: random depth edges, sub-pixel and
    off-screen motion, motion that puts p + motion on a pixel edge (the tap rounds up);
    they read the pixel's own depth and motion (the data makes the dilated ones differ by
    far more than the tolerances), reach output res at the render pixel holding each
    output pixel's centre, exactly (bilinear would differ); prev_out is this frame's
    (X, depth), and the oracle carries it."""
    rng = np.random.default_rng(5)
    hh, ww, scale = 13, 17, 1.5
    H, W = C.output_size(hh, ww, scale)
    up = O.OracleUpscaler((hh, ww), scale, "net", debug=True, session_options=_opts(),
                          **_networks(handmade=True))
    tols = (1e-6, 2e-3, 1e-6, 2e-3)
    prev = None
    for f in range(4):
        color = rng.uniform(0, 2, (hh, ww, 3)).astype(np.float32)
        depth = np.where(rng.random((hh, ww)) < 0.3, 0.8, 0.2).astype(np.float32)
        depth += rng.uniform(0, 0.01, (hh, ww)).astype(np.float32)
        motion = rng.uniform(-2.5, 2.5, (hh, ww, 2)).astype(np.float32)
        motion[::3, ::2] = np.round(motion[::3, ::2]) + 0.5
        jitter = tuple(C.jitter_for_frame(f, scale))
        up.step(color, depth, motion, jitter, reset=f == 2)
        dbg = up.debug
        X = C.pq_encode(color.transpose(2, 0, 1))
        d, m = depth, motion.transpose(2, 0, 1)
        want = np_measurements(X, d, m, prev, f == 2)
        got = dbg["dbg_measurements"][0]
        # tdd and edge: exact arithmetic on exact inputs; cc and spread: X (numpy's encoder
        # against onnxruntime's) times the knee's slope, up to 1 / 0.02
        for k, tol in enumerate(tols):
            err = np.abs(got[k] - want[k]).max()
            assert err <= tol, (f, k, err)
        # the dilated depth and motion would fail that: the depth edge always, the
        # previous-depth difference whenever there is a previous frame
        d_dil, m_dil = dbg["dbg_dilated_depth"][0, 0], dbg["dbg_dilated_motion"][0]
        alt = np_measurements(X, d_dil, m_dil, prev, f == 2)
        assert np.abs(alt[2] - want[2]).max() > 0.1, f
        if f not in (0, 2):
            assert np.abs(alt[0] - want[0]).max() > 0.1, f
        if f in (0, 2):
            assert not got[:2].any()
        else:
            assert (got[0] == np.float32(1) / np.float32(1 + RC.MEASURE_KNEES[0])).any()   # off screen
        # output res: the graph's own measurements moved exactly (Gather), which the
        # jitter-aware bilinear sampling of section 5 would not give
        got_hr = dbg["dbg_measurements_hr"][0]
        assert got_hr.shape == (4, H, W)
        assert np.array_equal(got_hr, np_measurements_hr(got, H, W))
        u = np.clip((np.arange(W) + 0.5) * ww / W - 0.5 - jitter[0], 0, ww - 1)[None, :] + np.zeros((H, 1))
        v = np.clip((np.arange(H) + 0.5) * hh / H - 0.5 - jitter[1], 0, hh - 1)[:, None] + np.zeros((1, W))
        assert np.abs(np_sample(got, u, v, False) - got_hr).max() > 0.1, f
        st = up.state["prev"]
        assert st.shape == (1, 4, hh, ww) and np.array_equal(st[0, 3], d)
        assert np.abs(st[0, :3] - X).max() < 2e-5
        prev = st[0]


def test_rule_history_clip_hand_cases():
    """reference.md s9: the history is pulled towards `up` by one fraction for all three
    channels until it is inside the box (a per-channel clamp would change its hue)."""
    from onnx import TensorProto, helper
    g = O._Graph(O.OPSET)
    out = O._clip_towards(g, "hist", "up", "lo", "hi")
    g.op("Identity", out, name="clipped")
    vi = [helper.make_tensor_value_info(n, TensorProto.FLOAT, [1, 3, 1, 4])
          for n in ("hist", "up", "lo", "hi")]
    m = helper.make_model(helper.make_graph(g.nodes, "clip", vi, [helper.make_tensor_value_info(
        "clipped", TensorProto.FLOAT, [1, 3, 1, 4])], initializer=g.inits),
        opset_imports=[helper.make_opsetid("", O.OPSET)])
    m.ir_version = O.IR_VERSION
    sess = ort.InferenceSession(m.SerializeToString(), _opts(), providers=["CPUExecutionProvider"])
    # pixels: inside the box | green 0.1 above the box (d_g = 0.2: t = 0.5) | up above the
    # box, history further out (t = 0) | history equal to up
    up = np.array([[.5, .5, .5], [.5, .5, .5], [.9, .5, .5], [.5, .5, .5]], np.float32)
    hist = np.array([[.6, .45, .5], [.6, .7, .4], [.95, .5, .5], [.5, .5, .5]], np.float32)
    # the clip widens the box by eps on every side: fed narrowed by eps, it is [.4, .6]
    lo = np.full((4, 3), .4 + RC.RULE_CLIP_EPS, np.float32)
    hi = np.full((4, 3), .6 - RC.RULE_CLIP_EPS, np.float32)
    want = np.array([[.6, .45, .5], [.55, .6, .45], [.9, .5, .5], [.5, .5, .5]], np.float32)
    feed = {k: np.ascontiguousarray(v.T.reshape(1, 3, 1, 4))
            for k, v in (("hist", hist), ("up", up), ("lo", lo), ("hi", hi))}
    (got,) = sess.run(["clipped"], feed)
    np.testing.assert_allclose(got.reshape(3, 4).T, want, atol=1e-6)


def test_graph_matches_numpy_reference():
    """Random depth edges, random sub-pixel motion (some off-screen), jitter, reactive,
    odd render size and scale 1.5: every stage of reference.md against the graph."""
    rng = np.random.default_rng(3)
    hh, ww, scale = 13, 17, 1.5
    H, W = C.output_size(hh, ww, scale)
    up = O.OracleUpscaler((hh, ww), scale, "rule", debug=True, session_options=_opts())
    hist = None
    for f in range(3):
        color = rng.uniform(0, 2, (hh, ww, 3)).astype(np.float32)
        depth = np.where(rng.random((hh, ww)) < 0.3, 0.8, 0.2).astype(np.float32)
        depth += rng.uniform(0, 0.01, (hh, ww)).astype(np.float32)
        depth[2:5, 3:6] = 0.5          # ties: the centre keeps its own motion
        motion = rng.uniform(-2.5, 2.5, (hh, ww, 2)).astype(np.float32)
        motion[::3, ::2] = np.round(motion[::3, ::2])      # integer motion: one-tap scatters
        jitter = tuple(C.jitter_for_frame(f + 5, scale))
        reactive = np.where(rng.random((hh, ww)) < 0.2, 0.7, 0.0).astype(np.float32)
        out = up.step(color, depth, motion, jitter, reactive=reactive)
        got = dict(up.debug, output=out.transpose(2, 0, 1)[None], history_out=up.state["history"])
        ref = np_rule_step(color.transpose(2, 0, 1), depth, motion.transpose(2, 0, 1),
                           np.array(jitter, np.float32), reactive,
                           hist if hist is not None else np.zeros((16, H, W), np.float32), f == 0, scale)
        for k in ("dbg_dilated_depth", "dbg_dilated_motion", "dbg_recon_depth", "dbg_valid"):
            assert np.array_equal(got[k][0], np.asarray(ref[k], np.float32).reshape(got[k][0].shape)), k
        for k, tol in (("dbg_depth_diff", 1e-5), ("dbg_upsampled", 2e-5), ("dbg_motion_hr", 1e-5),
                       ("dbg_counter", 1e-5), ("dbg_w", 1e-5), ("history_out", 1e-4),
                       ("output", 1e-3)):
            err = np.abs(got[k][0] - ref[k]).max()
            assert err < tol, (f, k, err)
        assert np.mean(got["dbg_ghost"][0, 0] != ref["dbg_ghost"]) < 0.01   # threshold ties only
        hist = got["history_out"][0]


# ---------------------------------------------------------------- behaviour
def run_static(mode, frames=8, **kw):
    up = upscaler(mode, **kw)
    depth = plane_depth()
    outs, counters = [], []
    for f in range(frames):
        out = up.step(render(JIT[f]), depth, np.zeros((h, w, 2), np.float32), JIT[f])
        assert np.isfinite(out).all() and np.isfinite(up.state["history"]).all()
        outs.append(out)
        counters.append(up.debug["dbg_counter"])
    return up, outs, counters


def test_rule_static_scene_converges():
    up, outs, counters = run_static("rule", cap=4)
    for f, c in enumerate(counters):
        assert np.all(c == min(f, 4)), (f, np.unique(c))
    target = reference_image(48, 64)
    p0, p7 = psnr(outs[0], target), psnr(outs[7], target)
    # Measured 18.5 dB -> 22.3 dB (cap 0, i.e. bicubic alone, stays at 18.2-18.9 dB).
    assert p7 > p0 + 2.0, (p0, p7)
    assert not up.debug["dbg_ghost"].any()


class _VisibilityFromDepthDiff:
    """A hand-made classifier: ghost-visibility logit = 40 * depth difference - 2, the
    others 0; aliasing logits 0.  It makes net mode follow the rule, so the net path
    can be checked with expectations that can fail."""

    @staticmethod
    def build(gain=40.0):
        """gain 0: a classifier that never says visibility ghosting (logit -2 < 0)."""
        from onnx import helper, numpy_helper, TensorProto
        from clss.methods.clss.networks import (CLASSIFIER_CHANNELS, CLASSIFIER_INPUTS,
                                                channel_slices)
        wgt = np.zeros((6, CLASSIFIER_CHANNELS, 2, 2), np.float32)
        # gain x the average of the 2x2 block of depth_difference
        wgt[0, channel_slices(CLASSIFIER_INPUTS)["depth_difference"]] = gain / 4
        b = np.array([-2, 0, 0, 0, 0, 0], np.float32)
        g = helper.make_graph(
            [helper.make_node("Conv", ["x", "W", "B"], ["logits"], kernel_shape=[2, 2], strides=[2, 2])],
            "handmade", [helper.make_tensor_value_info("x", TensorProto.FLOAT,
                                                       [1, CLASSIFIER_CHANNELS, None, None])],
            [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, 6, None, None])],
            initializer=[numpy_helper.from_array(wgt, "W"), numpy_helper.from_array(b, "B")])
        m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 18)])
        m.ir_version = 10
        return m


def _networks(handmade=False):
    from clss.methods.clss.networks import build_classifier, build_composition
    cls = _VisibilityFromDepthDiff.build() if handmade else build_classifier(widths=(4, 8, 8, 8))
    return dict(classifier=cls, composition=build_composition(hidden=8))


def test_net_static_scene_with_reset():
    up = upscaler("net", cap=32, **_networks(handmade=True))
    depth = plane_depth()
    for f in range(8):
        reset = f == 4
        out = up.step(render(JIT[f]), depth, np.zeros((h, w, 2), np.float32), JIT[f], reset=reset)
        dbg = up.debug
        assert np.isfinite(out).all() and np.isfinite(up.state["history"]).all()
        want = f - 4 if f >= 4 else f
        assert np.all(dbg["dbg_counter"] == want), (f, np.unique(dbg["dbg_counter"]))
        # The logits are stored in the history and come back warped (static: unchanged).
        assert np.allclose(up.state["history"][:, O.H_LOGITS], dbg["dbg_logits"])
        w_ = dbg["dbg_w"]
        if f in (0, 4):
            assert np.all(w_ == 1)              # a reset drops the history: w = 1
        else:
            assert np.all((w_ > 0) & (w_ < 1))
        if reset:
            # Invalid history is re-initialised to the current frame: out = upsampled.
            assert np.allclose(dbg["dbg_blend_history"], dbg["dbg_upsampled"])
            assert np.allclose(out, C.pq_decode(dbg["dbg_upsampled"][0]).transpose(1, 2, 0), rtol=1e-4, atol=1e-6)


def test_rule_reset_zeroes_counter():
    up, _, _ = run_static("rule", frames=3, cap=8)
    out = up.step(render(JIT[3]), plane_depth(), np.zeros((h, w, 2), np.float32), JIT[3], reset=True)
    assert np.all(up.debug["dbg_counter"] == 0) and np.all(up.debug["dbg_w"] == 1)
    assert np.all(up.state["history"][:, O.H_COUNTER] == 0)
    assert np.allclose(out, C.pq_decode(up.debug["dbg_upsampled"][0]).transpose(1, 2, 0), rtol=1e-4, atol=1e-6)
    up.step(render(JIT[4]), plane_depth(), np.zeros((h, w, 2), np.float32), JIT[4])
    assert np.all(up.debug["dbg_counter"] == 1)


@pytest.mark.parametrize("mode", ["rule", "net"])
def test_translation_keeps_history(mode):
    """Scene and depth move 1 render px right per frame, motion (-1, 0): the warp is an
    exact 2-output-pixel shift, so the warped history equals the previous output shifted
    (tolerance 1e-5, GridSample's coordinate round trip), and the counter keeps growing
    except in the two entering columns."""
    kw = _networks(handmade=True) if mode == "net" else {}
    up = upscaler(mode, cap=6, **kw)
    motion = np.zeros((h, w, 2), np.float32)
    motion[..., 0] = -1.0
    prev = None
    for f in range(8):
        up.step(render(JIT[f], shift=f), plane_depth(shift=f), motion, JIT[f], reset=(f == 0))
        dbg, hist = up.debug, up.state["history"]
        assert np.isfinite(hist).all()
        if prev is not None:
            assert np.abs(dbg["dbg_warped"][:, :, :, 2:] - prev[:, :, :, :-2]).max() < 1e-5
            assert np.all(dbg["dbg_valid"][..., :2] == 0) and np.all(dbg["dbg_valid"][..., 2:] == 1)
            assert not dbg["dbg_ghost"][..., 2:].any()
        cnt = dbg["dbg_counter"][0, 0]
        assert np.all(cnt[:, :2] == 0)
        assert np.all(cnt[:, 2 * f:] == min(f, 6)), (f, cnt[0])
        prev = hist


def moving_square(f, x_start=6, speed=2, jitter=(0.0, 0.0)):
    """Static textured background (depth 0.2) and a near square (depth 0.8) moving
    `speed` render px right per frame; returns colour, depth, motion, left edge."""
    x0 = x_start + speed * f
    color = render(jitter)
    depth = np.full((h, w), 0.2, np.float32)
    motion = np.zeros((h, w, 2), np.float32)
    sq = (slice(6, 18), slice(x0, x0 + 8))
    color[sq] = (0.9, 0.2, 0.1)
    depth[sq] = 0.8
    motion[sq + (0,)] = -speed
    return color, depth, motion, x0


@pytest.mark.parametrize("mode", ["rule", "net"])
def test_disocclusion_is_flagged(mode):
    kw = _networks(handmade=True) if mode == "net" else {}
    up = upscaler(mode, **kw)
    for f in range(6):
        c, d, m, x0 = moving_square(f, jitter=JIT[f])
        up.step(c, d, m, JIT[f])
        if f == 0:
            continue
        ghost = up.debug["dbg_ghost"][0, 0]
        dd = up.debug["dbg_depth_diff"][0, 0]
        rows = slice(2 * 7, 2 * 17)              # output rows well inside the square's span
        # Newly visible background: render column x0-2 (x0-1 takes the square's depth by
        # dilation, the TAA blind spot); its depth difference is (0.8-0.2)/0.8.
        assert np.allclose(dd[7:17, x0 - 2], 0.75), dd[7:17, x0 - 2]
        assert ghost[rows, 2 * (x0 - 2):2 * (x0 - 2) + 2].all()
        assert np.all(up.debug["dbg_counter"][0, 0][rows, 2 * (x0 - 2):2 * (x0 - 2) + 2] == 0)
        # Background away from the square, and the square's interior, keep their history.
        assert not ghost[:, :2 * (x0 - 5)].any()
        assert not ghost[:, 2 * (x0 + 11):].any()
        assert not ghost[rows, 2 * (x0 + 1):2 * (x0 + 7)].any()


@pytest.mark.parametrize("depth_threshold, flagged", [(O.DEPTH_THRESHOLD, True), (2.0, False)])
def test_net_depth_test_is_a_floor(depth_threshold, flagged):
    """Net mode rejects the history where the rule's depth test fires even when the
    classifier never says visibility ghosting (reference.md s7); a threshold above 1
    turns the floor off, and then only the classifier decides."""
    from clss.methods.clss.networks import build_composition
    up = upscaler("net", classifier=_VisibilityFromDepthDiff.build(gain=0.0),
                  composition=build_composition(hidden=8), depth_threshold=depth_threshold)
    for f in range(4):
        c, d, m, x0 = moving_square(f, jitter=JIT[f])
        up.step(c, d, m, JIT[f])
        if f == 0:
            continue
        ghost, w_ = up.debug["dbg_ghost"][0, 0], up.debug["dbg_w"][0, 0]
        vis = up.debug["dbg_logits"][0, 0]
        assert (vis < 0).all()                   # the classifier says "no visibility" everywhere
        cols = slice(2 * (x0 - 2), 2 * (x0 - 2) + 2)
        rows = slice(2 * 7, 2 * 17)
        assert ghost[rows, cols].all() if flagged else not ghost[rows, cols].any()
        if flagged:
            assert np.all(w_[rows, cols] == 1)   # the history is dropped
        assert not ghost[:, :2 * (x0 - 5)].any()


def test_net_graph_inlines_networks_exactly():
    """Odd output size (42 x 54 pads to 48 x 64): the inlined classifier's logits equal
    running it alone on the edge-padded input, bilinear x2 and cropped; the composition
    likewise."""
    from clss.methods.clss.networks import build_classifier, build_composition
    cls, comp = build_classifier(widths=(4, 8, 8, 8), seed=1), build_composition(hidden=8, seed=1)
    up = O.OracleUpscaler((21, 27), 2.0, "net", cls, comp, debug=True, session_options=_opts())
    rng = np.random.default_rng(0)
    for f in range(2):
        up.step(rng.uniform(0, 4, (21, 27, 3)).astype(np.float32),
                rng.uniform(0.1, 0.9, (21, 27)).astype(np.float32),
                rng.uniform(-1, 1, (21, 27, 2)).astype(np.float32), JIT[f])
    dbg = up.debug
    x = np.pad(dbg["dbg_cls_input"], ((0, 0), (0, 0), (0, 6), (0, 10)), mode="edge")
    half = ort.InferenceSession(cls.SerializeToString(), _opts()).run(None, {"x": x})[0]
    # Resize linear half_pixel x2: output i reads (i + 0.5) / 2 - 0.5, clamped.
    u = np.clip((np.arange(64) + 0.5) / 2 - 0.5, 0, 31)
    v = np.clip((np.arange(48) + 0.5) / 2 - 0.5, 0, 23)
    full = np_sample(half[0], u[None, :] + 0 * v[:, None], v[:, None] + 0 * u[None, :], False)
    assert np.abs(full[:, :42, :54] - dbg["dbg_logits"][0]).max() < 1e-4
    wgt = ort.InferenceSession(comp.SerializeToString(), _opts()).run(None, {"x": dbg["dbg_comp_input"]})[0]
    wgt = np.where(dbg["dbg_ghost"] > 0.5, 1.0, wgt)       # a ghost drops its history
    assert np.abs(np.maximum(wgt, dbg["dbg_reactive_hr"]) - dbg["dbg_w"]).max() < 1e-6
    ch = {n: s for n, s in zip(("up", "warped", "depth", "motion", "inv", "mn", "mx", "dd", "logits",
                                "measure"),
                                np.split(np.arange(27), np.cumsum([3, 3, 1, 2, 1, 3, 3, 1, 6])))}
    cin = dbg["dbg_cls_input"][0]
    assert cin.shape[0] == 27
    assert np.allclose(cin[ch["up"]], dbg["dbg_upsampled"][0])
    assert np.allclose(cin[ch["dd"]], dbg["dbg_depth_diff_hr"][0])
    assert np.allclose(cin[ch["inv"]], 1 / (1 + dbg["dbg_warped"][0, 3:4]))
    assert np.array_equal(cin[ch["measure"]], dbg["dbg_measurements_hr"][0])


@pytest.mark.parametrize("render_size, scale", [((13, 9), 1.5), ((7, 11), 1.7), ((9, 7), 3.0),
                                                ((5, 6), 4.0), ((15, 17), 2.0)])
@pytest.mark.parametrize("mode", ["rule", "net"])
def test_scales_and_odd_sizes(render_size, scale, mode):
    hh, ww = render_size
    H, W = C.output_size(hh, ww, scale)
    kw = _networks() if mode == "net" else {}
    up = O.OracleUpscaler(render_size, scale, mode, session_options=_opts(), **kw)
    rng = np.random.default_rng(1)
    for f in range(3):
        j = C.jitter_for_frame(f, scale)
        out = up.step(render(j, shift=0.5 * f, hh=hh, ww=ww), plane_depth(hh, ww),
                      np.full((hh, ww, 2), (-0.5, 0.25), np.float32), j,
                      reactive=rng.uniform(0, 1, (hh, ww)).astype(np.float32))
        assert out.shape == (H, W, 3) and np.isfinite(out).all()
        assert up.state["history"].shape == (1, 16, H, W)
        assert out.min() >= 0 and out.max() < 1.5


def test_options_exposure_ldr_motion_scale_sanitize():
    c = render(JIT[0])
    d, m = plane_depth(), np.zeros((h, w, 2), np.float32)
    base = upscaler().step(c, d, m, JIT[0])
    # Exposure divides on entry and multiplies on exit.
    assert np.allclose(upscaler(exposure=4.0).step(c * 4, d, m, JIT[0]), base * 4, rtol=1e-4)
    # Standard-Z depth is converted; UV motion with motion_scale gives the same result.
    a = upscaler(depth_inverted=False)
    assert np.allclose(a.step(c, 1 - d, m, JIT[0]), base, atol=1e-6)
    mv = np.full((h, w, 2), (-1.0, 0.5), np.float32)
    r1, r2 = upscaler(), upscaler(motion_scale=(w, h))
    for f in range(2):
        o1 = r1.step(c, d, mv, JIT[f])
        o2 = r2.step(c, d, (mv / (w, h)).astype(np.float32), JIT[f])
    assert np.allclose(o1, o2, atol=1e-5)
    # LDR: no transfer function; frame 0 is the clamped bicubic of the clamped input.
    ldr = upscaler(hdr=False).step(c * 1.3, d, m, JIT[0])
    u = np.clip((np.arange(64) + 0.5) / 2 - 0.5 - JIT[0][0], 0, w - 1)[None, :] + np.zeros((48, 1))
    v = np.clip((np.arange(48) + 0.5) / 2 - 0.5 - JIT[0][1], 0, h - 1)[:, None] + np.zeros((1, 64))
    want = np.clip(np_sample(np.clip(c * 1.3, 0, 1).transpose(2, 0, 1), u, v, True), 0, 1)
    assert np.abs(ldr - want.transpose(1, 2, 0)).max() < 1e-5
    # sanitize: a NaN frame does not reach the history.
    s = upscaler(sanitize=True)
    bad = c.copy()
    bad[3, 4] = np.nan
    s.step(bad, d, m, JIT[0])
    assert s.last_report == {"color": 3} and np.isfinite(s.state["history"]).all()
    with pytest.raises(C.FrameInputError):
        upscaler().step(bad, d, m, JIT[0])


def test_graph_is_plain_onnx():
    m = O.build_frame_graph("rule", (8, 8), 2.0)
    assert m.ir_version == 10 and m.opset_import[0].version == 18
    ops = {n.op_type for n in m.graph.node}
    assert {"GridSample", "ScatterElements", "ArgMax", "GatherElements", "MaxPool"} <= ops
    assert [o.name for o in m.graph.output] == ["output", "history_out"]
    onnx.checker.check_model(m, full_check=True)
    with pytest.raises(ValueError, match="needs both"):
        O.build_frame_graph("net", (8, 8), 2.0)
    from clss.methods.clss.networks import build_classifier, build_composition
    # A classifier built for a fixed size must match the padded output size (21x27 -> 48x64).
    comp = build_composition(hidden=4)
    O.build_frame_graph("net", (21, 27), 2.0, build_classifier((2, 2, 2, 2), height=48, width=64), comp)
    with pytest.raises(ValueError, match="fixed H = 32"):
        O.build_frame_graph("net", (21, 27), 2.0, build_classifier((2, 2, 2, 2), height=32, width=64), comp)
