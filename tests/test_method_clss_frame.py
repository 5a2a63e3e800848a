"""The frame-step oracle test: the OpenCL Upscaler against OracleUpscaler (one ONNX graph
run by onnxruntime), frame by frame with the state carried and a reset in the middle.

Tolerances (reference.md s11), per frame:
  fp32  output |d| <= 1e-4 * max|ref| + 1e-4 * |ref| (linear, after the PQ decode, which
        amplifies); history |d| <= 1e-4 (PQ colour, range, counter, logits; net mode's
        logits 5e-4, see helpers.compare_frame and reference.md s11); the sample
        counter (an integer decided by a threshold or an argmax) may differ on <= 1 % of
        pixels, which are left out of the other comparisons.  Measured: 1.6e-5 relative,
        no counter differs; net mode's logits within 1.6e-4.
  fp16  (half storage of the encoded colour, history and network tensors) output within
        1e-2 * max|ref| + 1e-2 * |ref| on >= 99 % of the pixels whose counters agree (a
        flipped ghost decision drops or keeps the history, w = 1 or not); history colour within 2e-3
        on 99 % of the pixels whose counters agree; counters differ on <= 1 % (rules) or
        <= 15 % (net: the untrained classifier's visibility logits sit close to ties and
        half rounding of its inputs flips a few; a flipped counter then stays different).

Net mode's sequence test runs at two visibility margins (reference.md s7), not at the
default: the seeded networks' leads spread over about -3..3, and at contract.VIS_MARGIN
(2.0) one pixel of this sequence leads by 2 + 1.7e-5, so the two sides' logits (within
5e-4, s11) decide it differently at frame 1; the history they then keep differs there and
reaches the neighbours through the warp and, by the classifier's receptive field, the
logits of a wide area in the following frames, which a per-frame exclusion of differing
counters cannot follow. Margin 0 is the argmax (the seeded classifier rejects ~97 % of
the pixels; nearest lead 2.9e-4 from it) and 3.0 lies above every lead of the sequence
(nearest 0.23 below: the classifier never rejects, the history and composition run on
every pixel). The default margin runs in the odd-size and measurement tests; the
decision at a margin is checked exactly with a hand-made classifier
(test_visibility_margin_matches_oracle).
"""
from __future__ import annotations

import numpy as np
import pytest

from clss import Upscaler
from clss.methods.clss.oracle import OracleUpscaler
from clss.methods.clss.frame import LR_MEASURE
from helpers import RENDER, RESET_AT, compare_frame, frames, networks

def _oracle(render, scale, mode, **kw):
    import onnxruntime as ort
    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    if mode == "net":
        kw["classifier"], kw["composition"] = networks()
    return OracleUpscaler(render, scale, mode, session_options=so, **kw)


def _ours(scale, mode, precision, **kw):
    if mode == "net":
        kw["classifier"], kw["composition"] = networks()
    return Upscaler(scale, mode="rules" if mode == "rule" else "net", precision=precision, **kw)


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("mode, vis_margin", [("rule", None), ("net", 0.0), ("net", 3.0)])
def test_frames_match_oracle(mode, vis_margin, precision):
    seq = frames()
    kw = {} if vis_margin is None else dict(vis_margin=vis_margin)
    ours = _ours(2.0, mode, precision, **kw)
    ora = _oracle(RENDER, 2.0, mode, **kw)
    for i, f in enumerate(seq):
        reset = i == RESET_AT
        a = ours.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        b = ora.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        assert a.shape == b.shape == (46, 74, 3) and a.dtype == np.float32
        assert np.isfinite(a).all()
        compare_frame(a, b, ours.state["history"][0], ora.state["history"][0], precision, mode,
                      f"{mode}/{precision} frame {i}")
    if mode == "net":
        assert ours.classifier_backend_name == "clss.Model"


@pytest.mark.parametrize("render,scale,mode", [
    ((17, 29), 1.5, "rule"), ((17, 29), 3.0, "rule"), ((11, 13), 4.0, "rule"),
    ((19, 27), 1.5, "net"),
])
def test_scales_and_odd_sizes_match_oracle(render, scale, mode):
    seq = frames(render, 4, scale)
    ours, ora = _ours(scale, mode, "fp32"), _oracle(render, scale, mode)
    for i, f in enumerate(seq):
        a = ours.step(f.color, f.depth, f.motion, f.jitter)
        b = ora.step(f.color, f.depth, f.motion, f.jitter)
        assert a.shape == b.shape
        compare_frame(a, b, ours.state["history"][0], ora.state["history"][0], "fp32", mode,
                      f"{render} x{scale} {mode} frame {i}")


def _random_frame(rng, hh, ww):
    """Colour over the PQ range, depth edges, motion up to 2.5 px (some of it off screen)."""
    color = rng.uniform(0, 3, (hh, ww, 3)).astype(np.float32)
    depth = np.where(rng.random((hh, ww)) < 0.3, 0.8, 0.2).astype(np.float32)
    depth += rng.uniform(0, 0.01, (hh, ww)).astype(np.float32)
    motion = rng.uniform(-2.5, 2.5, (hh, ww, 2)).astype(np.float32)
    motion[::3, ::2] = np.round(motion[::3, ::2]) + 0.5      # ties of the nearest-pixel tap
    return color, depth, motion


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_measurements_match_oracle(precision):
    """Net mode's classifier measurements (reference.md s4b) and its render-res state, the
    OpenCL step against the oracle at an odd size (13 x 17 x1.5 -> 20 x 26, padded to
    32 x 32) over 5 frames: a refused frame before frame 2 (the state must not move),
    a reset at frame 3. The render-res planes (lr planes LR_MEASURE to LR_MEASURE + 3, of the pixel's own depth and
    motion: the random depth edges make the dilated ones differ by up to 0.9), the
    classifier input 23-26 (the render pixel holding each output pixel's centre: exactly
    the kernel's own planes moved, in fp16 rounded to half once; against the oracle's
    within the render-res tolerance, fp16: plus the half rounding) and the state (the
    pixel's own depth, bitwise): previous-depth difference and depth edge exact but for
    the division, colour change and spread within the encoders' 1e-5 times the knee's
    slope (s11; fp16: the half rounding of X times the slope). Measured: fp32 tdd and edge
    bitwise, cc 4.3e-5, spread 3.6e-6; fp16 cc 4.5e-3, spread 6.1e-4, the classifier
    input's tdd and edge 2.4e-4 (half rounding)."""
    from clss.pipeline.contract import FrameInputError
    from clss.methods.clss.contract import MEASURE_KNEES
    rng = np.random.default_rng(7)
    hh, ww, scale = 13, 17, 1.5
    ours = _ours(scale, "net", precision)
    ora = _oracle((hh, ww), scale, "net", debug=True)
    fp32 = precision == "fp32"
    tol = np.array([1e-6, 1e-3, 1e-6, 1e-3] if fp32 else [1e-6, 3e-2, 1e-6, 3e-2])
    tol_hr = tol if fp32 else np.array([1e-3, 3e-2, 1e-3, 3e-2])
    for i in range(5):
        color, depth, motion = _random_frame(rng, hh, ww)
        jitter = (0.25 * (-1) ** i, -0.125)
        reset = i == 3
        if i == 2:
            bad = _random_frame(rng, hh, ww)
            bad[0][4, 5, 1] = np.nan
            with pytest.raises(FrameInputError):
                ours.step(*bad, jitter)
        ours.step(color, depth, motion, jitter, reset=reset)
        ora.step(color, depth, motion, jitter, reset=reset)
        fs = ours._fs
        got, want = fs.lr.get()[LR_MEASURE:LR_MEASURE + 4], ora.debug["dbg_measurements"][0]
        got_hr = fs.dev.to_host(fs.cls_in)[0, 23:27, :fs.H, :fs.W]
        want_hr = ora.debug["dbg_cls_input"][0, 23:27]
        ri = (2 * np.arange(fs.H) + 1) * hh // (2 * fs.H)
        rj = (2 * np.arange(fs.W) + 1) * ww // (2 * fs.W)
        moved = got[:, ri][:, :, rj]
        np.testing.assert_array_equal(got_hr, moved if fp32 else moved.astype(np.float16))
        if i in (0, 3):          # no previous frame: those two are 0
            assert not got[:2].any() and not want[:2].any(), i
        else:                    # off screen: the largest change, 1 / (1 + knee)
            off = np.float32(1) / (np.float32(1) + np.float32(MEASURE_KNEES[0]))
            assert (want[0] == off).any() and (got[0] == off).any(), i
        for k in range(4):
            err = np.abs(got[k] - want[k]).max()
            assert err <= tol[k], f"{precision} frame {i} measurement {k}: {err:.3g}"
            err = np.abs(got_hr[k] - want_hr[k]).max()
            assert err <= tol_hr[k], f"{precision} frame {i} classifier input {23 + k}: {err:.3g}"
        pa, pb = ours.state["prev"], ora.state["prev"]
        assert pa.shape == pb.shape == (1, 4, hh, ww)
        np.testing.assert_array_equal(pa[0, 3], pb[0, 3])          # the pixel's own depth
        np.testing.assert_array_equal(pa[0, 3], depth)
        np.testing.assert_allclose(pa[0, :3], pb[0, :3], rtol=0, atol=2e-5 if fp32 else 5e-4)


@pytest.mark.parametrize("opts", [dict(depth_inverted=False, motion_scale=(-1.0, 0.5)),
                                  dict(sanitize=True)])
def test_measurements_entry_conversions_match_oracle(opts):
    """Net mode's measurements read the pixel's own depth and motion after the entry
    conversions (reference.md s1, s4b): standard Z and a motion scale, and SANITIZE's
    replacements (depth far, motion 0), as the oracle's graph inputs have them; fp32, the
    tolerances of test_measurements_match_oracle, the state's depth bitwise. Measured:
    cc 4.6e-5, spread 3.6e-6, the rest bitwise."""
    rng = np.random.default_rng(3)
    hh, ww = 13, 17
    ours = _ours(1.5, "net", "fp32", **opts)
    ora = _oracle((hh, ww), 1.5, "net", debug=True, **opts)
    tol = [1e-6, 1e-3, 1e-6, 1e-3]
    for i in range(3):
        color, depth, motion = _random_frame(rng, hh, ww)
        if opts.get("sanitize"):
            depth[2, 3] = np.nan
            motion[5, 6, 0] = np.nan
            motion[7, 7, 1] = np.inf
        ours.step(color, depth, motion, (0.1, -0.2))
        ora.step(color, depth, motion, (0.1, -0.2))
        got, want = ours._fs.lr.get()[LR_MEASURE:LR_MEASURE + 4], ora.debug["dbg_measurements"][0]
        for k in range(4):
            err = np.abs(got[k] - want[k]).max()
            assert err <= tol[k], f"{opts} frame {i} measurement {k}: {err:.3g}"
        np.testing.assert_array_equal(ours.state["prev"][0, 3], ora.state["prev"][0, 3])


@pytest.mark.parametrize("opts", [
    dict(exposure=2.5), dict(hdr=False), dict(motion_scale=(-1.0, -1.0)),
    dict(depth_inverted=False), dict(cap=2, depth_threshold=0.05),
    dict(depth_slope=0.0), dict(depth_slope=1.5, depth_threshold=0.05),
])
def test_options_match_oracle(opts):
    seq = frames()[:4]
    ours = Upscaler(2.0, mode="rules", **opts)
    ora = _oracle(RENDER, 2.0, "rule", **opts)
    for i, f in enumerate(seq):
        color, depth, motion = f.color, f.depth, f.motion
        if opts.get("hdr") is False:
            color = np.clip(color, 0, 1)
        if "motion_scale" in opts:
            motion = -motion
        if opts.get("depth_inverted") is False:
            depth = (1 - depth).astype(np.float32)
        reactive = np.linspace(0, 1, depth.size, dtype=np.float32).reshape(depth.shape) ** 4
        a = ours.step(color, depth, motion, f.jitter, reactive=reactive)
        b = ora.step(color, depth, motion, f.jitter, reactive=reactive)
        compare_frame(a, b, ours.state["history"][0], ora.state["history"][0], "fp32", "rule",
                      f"{opts} frame {i}")


def test_device_path_equals_host_path(dev):
    seq = frames()[:3]
    host, devp = Upscaler(2.0, mode="rules"), Upscaler(2.0, mode="rules")
    for f in seq:
        a = host.step(f.color, f.depth, f.motion, f.jitter)
        arrs = [dev.to_device(x) for x in (f.color, f.depth, f.motion)]
        b = devp.step_device(*arrs, f.jitter).get()
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(host.state["history"], devp.state["history"])


@pytest.mark.parametrize("mode", ["rule", "net"])
def test_pixels_per_work_item_variants_agree(mode, monkeypatch):
    """VEC = 8 (CPUs), 4 and 1 (GPUs) are one source; they must give the same frames up to
    the device's vector and scalar exp2/log2 (measured 4e-5 relative after the PQ decode)."""
    seq = frames()[:3]
    outs = {}
    for vec in ("8", "4", "1"):
        monkeypatch.setenv("CLSS_FRAME_VEC", vec)
        up = _ours(2.0, mode, "fp32")
        outs[vec] = [up.step(f.color, f.depth, f.motion, f.jitter) for f in seq]
        outs[vec].append(up.state["history"])
    for vec in ("4", "1"):
        for a, b in zip(outs[vec][:-1], outs["8"][:-1]):
            np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)
        ha, hb = outs[vec][-1][0], outs["8"][-1][0]
        np.testing.assert_allclose(ha[:10], hb[:10], rtol=1e-4, atol=1e-6)
        # the logits: net mode's classifier reads differences of encoded colours with a
        # slope of up to 50 (reference.md s4b, s11), so the encoders' rounding reaches its
        # logits, near 0, as up to 5e-6 absolute (measured)
        np.testing.assert_allclose(ha[10:], hb[10:], rtol=1e-4, atol=3e-5 if mode == "net" else 1e-6)


def _lead_classifier(h16, w16):
    """A hand-made classifier with known leads (reference.md s7): 2x2 stride-2 Conv on the
    classifier input's depth channel alone, visibility logit = 8 * depth - 3, the other two
    0 and -1, so lead = 8 * depth - 3: -1 at depth 0.25, exactly 0 (a tie of logits 0 and
    1) at 0.375, 1 at 0.5, 3 at 0.75. Inside a band every value on the way (dyadic depths,
    bilinear weights 1/4 and 3/4 at scale 2 without jitter, the Conv's sums) is exact in
    float, so the two sides compute the same leads there, ties included; the mixtures at
    the bands' edges agree to an ulp."""
    from onnx import TensorProto, helper, numpy_helper
    from clss.methods.clss.networks import CLASSIFIER_CHANNELS, CLASSIFIER_INPUTS, channel_slices
    wgt = np.zeros((6, CLASSIFIER_CHANNELS, 2, 2), np.float32)
    wgt[0, channel_slices(CLASSIFIER_INPUTS)["depth"]] = 8.0 / 4
    b = np.array([-3, 0, -1, 0, 0, 0], np.float32)
    g = helper.make_graph(
        [helper.make_node("Conv", ["x", "W", "B"], ["logits"], kernel_shape=[2, 2], strides=[2, 2])],
        "leads", [helper.make_tensor_value_info("x", TensorProto.FLOAT,
                                                [1, CLASSIFIER_CHANNELS, h16, w16])],
        [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, 6, h16 // 2, w16 // 2])],
        initializer=[numpy_helper.from_array(wgt, "W"), numpy_helper.from_array(b, "B")])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 18)])
    m.ir_version = 10
    return m


def test_visibility_margin_matches_oracle():
    """Net mode's visibility decision, lead = logits[0] - max(logits[1], logits[2]) >=
    vis_margin (reference.md s7), the OpenCL step against the oracle: a static scene (the
    history valid everywhere after frame 0, no depth change; depth test off) whose depth
    bands give the leads -1, 0 (a tie), 1 and 3 (_lead_classifier) and mixtures at the
    bands' edges. Margin 0 rejects exactly where the argmax of logits 0-2 is 0 (first index
    on ties: the tie band too); margins 1 (the lead-1 band sits on it: >= rejects it) and
    2 move the decision; the ghost planes and the counters equal the oracle's exactly."""
    from clss.methods.clss.networks import build_composition
    hh, ww = 16, 24
    depth = np.repeat(np.array([0.25, 0.375, 0.5, 0.75], np.float32), ww // 4)[None].repeat(hh, 0)
    color = np.full((hh, ww, 3), 0.5, np.float32)
    motion = np.zeros((hh, ww, 2), np.float32)
    cls, comp = _lead_classifier(32, 48), build_composition(hidden=8)
    ghosts = {}
    for margin in (0.0, 1.0, 2.0):
        kw = dict(vis_margin=margin, depth_threshold=2.0, classifier=cls, composition=comp)
        ours = Upscaler(2.0, mode="net", debug=True, **kw)
        ora = OracleUpscaler((hh, ww), 2.0, "net", debug=True, **kw)
        for f in range(3):
            ours.step(color, depth, motion, (0.0, 0.0))
            ora.step(color, depth, motion, (0.0, 0.0))
            g_ours = ours.debug_views()["ghost"] > 0.5
            g_ora = ora.debug["dbg_ghost"][0, 0] > 0.5
            np.testing.assert_array_equal(g_ours, g_ora, err_msg=f"margin {margin} frame {f}")
            np.testing.assert_array_equal(ours.state["history"][0, 3], ora.state["history"][0, 3],
                                          err_msg=f"margin {margin} frame {f}: counters")
        lg = ora.debug["dbg_logits"][0, :3]
        np.testing.assert_allclose(ours.state["history"][0, 10:13], lg, rtol=0, atol=1e-6)
        lead = lg[0] - np.maximum(lg[1], lg[2])
        bands = np.isin(lead, [-1.0, 0.0, 1.0, 3.0])
        assert bands.mean() > 0.5 and set(lead[bands].tolist()) == {-1.0, 0.0, 1.0, 3.0}
        # the edges' mixtures (an ulp apart on the two sides) lie away from every margin
        assert (np.abs(lead[~bands][:, None] - np.array([0.0, 1.0, 2.0])) > 1e-3).all()
        assert ora.debug["dbg_valid"].all()
        np.testing.assert_array_equal(g_ora, lead >= np.float32(margin))
        if margin == 0:                                   # the paper's argmax
            np.testing.assert_array_equal(g_ora, np.argmax(lg, 0) == 0)
            assert g_ora[lead == 0].all()                 # ties: the first index wins
        ghosts[margin] = g_ora
    assert (ghosts[0.0] >= ghosts[1.0]).all() and (ghosts[1.0] >= ghosts[2.0]).all()
    assert ghosts[0.0].sum() > ghosts[1.0].sum() > ghosts[2.0].sum() > 0
    assert not ghosts[2.0].all()


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), "2.0", None, True])
def test_visibility_margin_rejects_bad_values(bad):
    """vis_margin must be a finite number: a ValueError naming it, from the OpenCL
    Upscaler (before any weights load) and the oracle."""
    from clss.methods.clss.oracle import build_frame_graph
    with pytest.raises(ValueError, match="vis_margin"):
        Upscaler(2.0, mode="net", vis_margin=bad)
    with pytest.raises(ValueError, match="vis_margin"):
        build_frame_graph("rule", (8, 8), 2.0, vis_margin=bad)


@pytest.mark.parametrize("bad", [float("nan"), -1.0, "4", None, True])
def test_depth_slope_rejects_bad_values(bad):
    """depth_slope must be a finite number >= 0: a ValueError naming it."""
    with pytest.raises(ValueError, match="depth_slope"):
        Upscaler(2.0, mode="rules", depth_slope=bad)


@pytest.mark.parametrize("mode", ["rules", "net"])
def test_depth_slope_passes_ramps_and_keeps_silhouettes(mode):
    """The depth test's slope term (reference.md s4). A surface receding 20 % a pixel (a
    grazing floor) moving half a pixel: the reconstruction's bilinear taps read the nearer
    neighbour's depth, dd = 0.11 > 0.1, which the plain test rejects and the slope-aware
    one keeps. A near block moving 2 pixels over a flat background: the strip it revealed
    is rejected by both (flat on one side: no tolerance). Net mode: the floor under the
    classifier (the untrained one, the margin out of reach, so only the floor decides)."""
    h, w = 12, 20
    color = np.full((h, w, 3), 0.3, np.float32)
    depth = np.full((h, w), 0.2, np.float32)
    motion = np.zeros((h, w, 2), np.float32)
    depth[:, :10] = 0.5 * 0.8 ** np.arange(10)
    motion[:, :10, 0] = 0.5
    depth[3:9, 13:18] = 0.8
    motion[3:9, 13:18, 0] = -2.0
    ghosts = {}
    for k in (0.0, 4.0):
        kw = dict(weights="untrained", vis_margin=1e6) if mode == "net" else {}
        up = Upscaler(2.0, mode=mode, depth_slope=k, debug=True, **kw)
        for _ in range(2):
            up.step(color, depth, motion, (0.0, 0.0))
        ghosts[k] = up.debug_views()["ghost"] > 0.5
    ramp = (slice(2, 22), slice(5, 15))       # output res: render columns 2-7
    hole = (slice(8, 16), slice(20, 24))      # render columns 10-11, rows 4-7: revealed
    assert ghosts[0.0][ramp].all() and not ghosts[4.0][ramp].any()
    assert ghosts[0.0][hole].all() and ghosts[4.0][hole].all()


OCLGRIND_SCRIPT = r"""
import numpy as np
from clss import Upscaler
from clss.demo.scene import render_sequence
seq = render_sequence(2, (5, 7), 2.0, spp_ref=0)
ups = []
for prec in ("fp32", "fp16"):
    for mode in ("rules", "net"):
        up = Upscaler(2.0, mode=mode, precision=prec, classifier_backend="onnxruntime", debug=True)
        ups.append(up)
        for f in seq:
            out = up.step(f.color, f.depth, f.motion, f.jitter)
            assert np.isfinite(out).all()
# The refused frames come last: oclgrind 21.10 flags the encoded-colour reads of a net-mode
# Upscaler created *after* a rule-mode one refused a frame (each alone is clean, and the
# values match the oracle); not understood yet, see docs/verify.md (oclgrind).
for up in ups:
    bad = seq[1].color.copy()
    bad[0, 0, 0] = np.nan
    try:
        up.step_device(*(up.dev.to_device(a) for a in (bad, f.depth, f.motion)), f.jitter)
    except ValueError:
        pass
print("frame kernels ok")
"""


@pytest.mark.oclgrind
# 8 pixels per work-item (CPUs; its tails are the harder indexing) in the default tier, with
# the builtins (the reference) and inline (the fast path frame.inline_math, which PoCL runs);
# 1 (GPUs) in the slow one
@pytest.mark.parametrize("vec, inline", [("8", "0"), ("8", "1"), pytest.param("1", "0", marks=pytest.mark.slow)])
def test_frame_kernels_clean_under_oclgrind(vec, inline, tmp_path):
    """prepare, depth_diff, resolve and compose on tiny frames under oclgrind's
    out-of-bounds, uninitialised-read and data-race checks (the classifier runs on
    onnxruntime here: its kernels have their own oclgrind tests)."""
    import os
    import subprocess
    import sys
    from helpers import DIAGNOSTIC, ICD, oclgrind_env
    if not os.path.exists(ICD):
        pytest.skip("oclgrind not installed (apt-get install oclgrind)")
    env = oclgrind_env(tmp_path)
    env["CLSS_FRAME_VEC"] = vec
    env["CLSS_FRAME_INLINE_MATH"] = inline
    env["PYTHONPATH"] = os.pathsep.join([os.getcwd(), env.get("PYTHONPATH", "")])
    p = subprocess.run([sys.executable, "-W", "ignore", "-c", OCLGRIND_SCRIPT], env=env,
                       capture_output=True, text=True, timeout=900)
    diags = [line for line in p.stderr.splitlines() if DIAGNOSTIC.search(line)]
    assert not diags, "oclgrind reported:\n" + "\n".join(p.stderr.splitlines()[:60])
    assert p.returncode == 0 and "frame kernels ok" in p.stdout, p.stdout[-3000:] + p.stderr[-3000:]
