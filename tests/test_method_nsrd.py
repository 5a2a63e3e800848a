"""The NSRD room (clss/methods/nsrd/): the OpenCL frame step against its whole-frame ONNX
twin in fp32 and fp16 at 2x and 4x over a reset, with the carried state (render-res
history, previous output lighting, ConvLSTM h) compared too; the two ablation configs;
the named error without G-buffers; the registry entry; flat device memory.

Tolerances (per frame): fp32 |d| <= 1e-4 * max|ref| + 1e-4 * |ref| on every output pixel
(the PQ decode near its peak is ill-conditioned in float32), 2e-5 on the state, the
history and h; fp16 (half storage of the network's tensors) 2e-2 * max|ref| + 2e-2 *
|ref| on the output, 1e-2 on the history and h.
"""
from __future__ import annotations

import numpy as np
import pytest

import clss
from clss import methods
from clss.methods.nsrd import networks as nets
from clss.pipeline.contract import MissingInputError
from helpers import RESET_AT, frames

RENDER = (13, 17)          # odd: the network runs on an even padded size inside
GB = ("albedo", "normal", "albedo_hr")


def _gb(f):
    return {k: f.gbuffers[k] for k in GB}


def _weights(scale, **kw):
    cfg = nets.make_config(scale, **kw)
    w = nets.init_weights(cfg, seed=3)
    w["out.weight"] = w["out.weight"] * 10      # a network output that matters
    return cfg, w


def _run(dev, scale, precision, n=7, **kw):
    cfg, w = _weights(scale, **kw)
    ours = clss.Upscaler(method="nsrd", scale=scale, device=dev, precision=precision,
                         weights=(cfg, w))
    twin = methods.twin("nsrd", RENDER, scale, weights=(cfg, w))
    tol = 1e-4 if precision == "fp32" else 2e-2
    stol = 2e-5 if precision == "fp32" else 1e-2
    for i, f in enumerate(frames(RENDER, n, scale=scale)):
        reset = i == RESET_AT
        a = ours.step(f.color, f.depth, f.motion, f.jitter, reset=reset, **_gb(f))
        b = twin.step(f.color, f.depth, f.motion, f.jitter, reset=reset, **_gb(f))
        assert a.shape == b.shape == (*ours.output_size, 3) and a.dtype == np.float32
        d = np.abs(a - b)
        assert (d <= tol * np.abs(b).max() + tol * np.abs(b)).all(), \
            f"{precision} x{scale} frame {i}: max |d| {d.max():.3g}"
        fs = ours._fs
        for name, mine, ref in (("state", fs.state, twin.st["state"][0]),
                                ("hist", fs.hist, twin.st["hist"][0]),
                                ("h", fs.lstm[0], twin.st["h"])):
            dd = np.abs(fs.dev.to_host(mine).reshape(ref.shape) - ref).max()
            # the state is float32 in both precisions
            assert dd <= (2e-5 if name == "state" else stol), \
                f"{precision} x{scale} frame {i}: {name} max |d| {dd:.3g}"
    return ours, twin


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("scale", [2.0, 4.0])
def test_frame_step_matches_its_onnx_twin(scale, precision, dev):
    ours, _ = _run(dev, scale, precision)
    st = ours._fs.dev.to_host(ours._fs.state)
    # the history is used: the mask is 1 in places (this scene's camera moves fast, and a
    # depth test without the camera's own depth change rejects much of it) and frame
    # i-2's lighting is there
    assert (st[3] == 1).mean() > 0.2 and np.abs(st[4:7]).max() > 0


@pytest.mark.parametrize("kw,precision", [({"demod": False}, "fp32"), ({"mask": False}, "fp32"),
                                          ({"remod": "learned"}, "fp32"),
                                          ({"remod": "learned"}, "fp16"),
                                          ({"warp_state": True}, "fp32"),
                                          ({"warp_state": True}, "fp16"),
                                          ({"base": "guided", "remod": "learned"}, "fp32"),
                                          ({"base": "guided", "remod": "learned"}, "fp16"),
                                          ({"base": "guided", "demod": False}, "fp32")])
def test_ablations_and_learned_remod_match_the_twin(kw, precision, dev):
    ours, _ = _run(dev, 2.0, precision, n=6, **kw)
    st = ours._fs.dev.to_host(ours._fs.state)
    if "mask" in kw:
        assert (st[3] == 1).all()


def test_reset_clears_the_history(dev):
    seq = frames(RENDER, 3, scale=2.0)
    up = clss.Upscaler(method="nsrd", scale=2, device=dev, weights="untrained")
    for f in seq:
        up.step(f.color, f.depth, f.motion, f.jitter, **_gb(f))
    st = up._fs.dev.to_host(up._fs.state)
    assert st[3].any() and st[4:7].any()
    f = seq[0]
    up.step(f.color, f.depth, f.motion, f.jitter, reset=True, **_gb(f))
    st = up._fs.dev.to_host(up._fs.state)
    assert st[0:3].any() and not st[3:7].any()     # only the current frame's lighting


def test_missing_gbuffers_is_the_named_error(dev):
    f = frames(RENDER, 1, scale=2.0)[0]
    up = clss.Upscaler(method="nsrd", scale=2, device=dev, weights="untrained")
    with pytest.raises(MissingInputError, match="nsrd.*albedo, normal, albedo_hr"):
        up.step(f.color, f.depth, f.motion, f.jitter)
    with pytest.raises(MissingInputError, match="albedo_hr"):
        up.step(f.color, f.depth, f.motion, f.jitter, albedo=f.gbuffers["albedo"],
                normal=f.gbuffers["normal"])


def test_scale_must_be_an_integer(dev):
    with pytest.raises(ValueError, match="integer scales"):
        clss.Upscaler(method="nsrd", scale=2.5, device=dev, weights="untrained")
    cfg, w = _weights(2.0)
    with pytest.raises(ValueError, match="trained for scale 2"):
        clss.Upscaler(method="nsrd", scale=4, device=dev, weights=(cfg, w))


def test_step_device_and_flat_memory(dev):
    import pyopencl.array as cla
    seq = frames(RENDER, 4, scale=2.0)
    up = clss.Upscaler(method="nsrd", scale=2, device=dev, weights="untrained")
    ref = clss.Upscaler(method="nsrd", scale=2, device=dev, weights="untrained")
    q = up.dev.queue
    sizes = set()
    for _ in range(3):
        for f in seq:
            arrs = {k: cla.to_device(q, np.ascontiguousarray(v, np.float32)) for k, v in
                    (("color", f.color), ("depth", f.depth), ("motion", f.motion))}
            gb = {k: cla.to_device(q, v) for k, v in _gb(f).items()}
            a = up.step_device(arrs["color"], arrs["depth"], arrs["motion"], f.jitter, **gb).get()
            b = ref.step(f.color, f.depth, f.motion, f.jitter, **_gb(f))
            assert np.array_equal(a, b)
            sizes.add(up.device_bytes())
    assert len(sizes) == 1          # nothing allocated per frame
    with pytest.raises(MissingInputError):
        up.step_device(arrs["color"], arrs["depth"], arrs["motion"], f.jitter)


def test_registry_entry():
    s = methods.spec("nsrd")
    assert s.gbuffers == GB and s.twin and "nsrd" not in methods.PLANNED


def test_demo_and_upscale_cli(tmp_path, capsys):
    """`clss demo --methods nsrd` (the scene carries the G-buffers) and `clss upscale
    --method nsrd` on its EXR frames; without the material channels the named error, one
    line, nothing written."""
    import glob
    import json
    import os
    import shutil

    import OpenImageIO as oiio

    from clss.cli import main
    demo = tmp_path / "demo"
    assert main(["demo", "-o", str(demo), "--frames", "3", "--size", "32x18", "--scale", "2",
                 "--methods", "nsrd", "--workers", "1", "--exr"]) == 0
    assert "nsrd" in json.loads((demo / "metrics.json").read_text())["methods"]
    out = tmp_path / "up"
    assert main(["upscale", str(demo / "input"), "--method", "nsrd", "--scale", "2",
                 "-o", str(out)]) == 0
    assert len(glob.glob(str(out / "frame.*.exr"))) == 3
    bare = tmp_path / "bare"
    bare.mkdir()
    for p in sorted(glob.glob(str(demo / "input" / "frame.*.exr"))):
        buf = oiio.ImageBuf(p)
        names = buf.spec().channelnames
        keep = ("R", "G", "B", "Z", "mv.x", "mv.y")
        oiio.ImageBufAlgo.channels(buf, tuple(names.index(c) for c in keep),
                                   newchannelnames=keep).write(str(bare / os.path.basename(p)))
    shutil.copy(demo / "input" / "jitter.json", bare)
    capsys.readouterr()
    assert main(["upscale", str(bare), "--method", "nsrd", "--scale", "2",
                 "-o", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert "method 'nsrd' needs albedo, normal, albedo_hr" in err and "Traceback" not in err
    assert "nothing was written" in err
    assert not (tmp_path / "none").exists() or not os.listdir(tmp_path / "none")


def test_300_frames_hold_memory_flat(dev):
    """The state stays on the device in buffers allocated once: 300 frames through
    step_device allocate nothing per frame (device bytes constant; the process's peak
    resident memory grows by under 20 MB after the first 20 frames)."""
    import resource

    import pyopencl.array as cla
    f = frames(RENDER, 1, scale=2.0)[0]
    up = clss.Upscaler(method="nsrd", scale=2, device=dev, weights="untrained")
    q = up.dev.queue
    d = [cla.to_device(q, np.ascontiguousarray(v, np.float32)) for v in (f.color, f.depth, f.motion)]
    gb = {k: cla.to_device(q, v) for k, v in _gb(f).items()}
    out = cla.empty(q, (26, 34, 3), np.float32)
    sizes = set()
    for i in range(300):
        up.step_device(*d, f.jitter, reset=i % 100 == 0, out=out, **gb)
        sizes.add(up.device_bytes())
        if i == 19:
            rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    assert len(sizes) == 1
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0 < 20 * 1024
    assert np.isfinite(out.get()).all()


# --- the float8 output-resolution kernels (fast path nsrd.encode8) --------------------------

def _frame_kernel(any_dev, prec, name, scale):
    from clss import selfcheck
    from clss.methods.nsrd import frame as fr
    return any_dev.kernel(fr.KERNEL, name, prec, NSRD_SCALE=scale, NSRD_ENCODE8=1,
                          **selfcheck.defines(any_dev, prec, fr.INLINE_MATH), **fr.guide_defines())


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
@pytest.mark.parametrize("scale", [2, 3, 4])
def test_prev8_is_nsrd_prev_bit_for_bit(any_dev, prec, scale):
    # 8 output pixels a work-item on float8 lanes: the same operations as per pixel, with
    # motions large enough that taps fall outside the frame, and a row width (13 s) that
    # leaves a partial work-item
    h, w = 7, 13
    H, W = h * scale, w * scale
    g = np.random.default_rng(scale)
    hist = any_dev.to_device(g.uniform(0, 1, (3, H, W)).astype(np.float32))
    mv = any_dev.to_device(g.uniform(-9, 9, (2, h, w)).astype(np.float32))
    hp, wp = nets.pad2(h), nets.pad2(w)
    i32 = np.int32
    outs = []
    for name, gs in (("nsrd_prev8", (-(-W // 8), H)), ("nsrd_prev", (W, H))):
        prev = any_dev.empty((3 * scale * scale, hp, wp), prec)
        any_dev.zero(prev)
        any_dev.launch(_frame_kernel(any_dev, prec, name, scale), gs,
                       (hist.data, mv.data, prev.data, i32(h), i32(w), i32(H), i32(W), i32(hp), i32(wp),
                        i32(scale), np.float32(1)))
        outs.append(prev.get())
    assert np.array_equal(outs[0].view(np.uint8), outs[1].view(np.uint8))


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
@pytest.mark.parametrize("scale, learned, guided", [(2, 1, 0), (3, 0, 0), (4, 1, 0), (2, 1, 1), (3, 0, 1)])
def test_finish8_is_finish_then_decode_bit_for_bit(any_dev, prec, scale, learned, guided):
    h, w = 7, 13
    H, W = h * scale, w * scale
    hp, wp = nets.pad2(h), nets.pad2(w)
    g = np.random.default_rng(10 + scale)
    y = any_dev.to_device(g.uniform(-1, 1, ((3 + learned) * scale * scale, hp, wp)).astype(np.float32), prec)
    state = any_dev.to_device(g.uniform(0, 1, (8, h, w)).astype(np.float32))
    ahr = g.uniform(-0.2, 1, (H, W, 3)).astype(np.float32)
    ahr[1, 2, 0], ahr[3, 4, 1] = np.nan, np.inf     # fin() per tap, as the scalar kernel
    ahr = any_dev.to_device(ahr)
    alpha = any_dev.to_device(g.uniform(0, 1, (scale * scale * hp * wp,)).astype(np.float32))
    alb = g.uniform(-0.2, 1, (h, w, 3)).astype(np.float32)     # the guided base's guide
    alb[2, 3, 2] = np.nan
    alb = any_dev.to_device(alb)
    i32, f = np.int32, np.float32
    res = []
    for fused in (True, False):
        hist, out = any_dev.empty((3, H, W), dtype=np.float32), any_dev.empty((H, W, 3), dtype=np.float32)
        args = [y.data, state.data, ahr.data, hist.data, out.data, i32(h), i32(w), i32(H), i32(W), i32(hp),
                i32(wp), i32(scale), f(0.25), f(-0.25), i32(1), f(0.01), i32(learned), alpha.data]
        if fused:
            any_dev.launch(_frame_kernel(any_dev, prec, "nsrd_finish8", scale), (-(-W // 8), H),
                           args + [f(3.0), alb.data, i32(guided)])
        else:
            any_dev.launch(_frame_kernel(any_dev, prec, "nsrd_finish", scale), (W, H),
                           args + [alb.data, i32(guided)])
            any_dev.launch(_frame_kernel(any_dev, prec, "nsrd_decode", scale), (-(-H * W // 8),),
                           [hist.data, out.data, i32(H * W), f(3.0)])
        res.append((hist.get(), out.get()))
    for a, b in zip(*res):
        assert np.array_equal(a.view(np.uint8), b.view(np.uint8))


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
@pytest.mark.parametrize("w, warp_state, inverted", [(13, 1, 1), (16, 0, 0), (9, 1, 0)])
def test_prepare8_and_warp_state8_are_nsrd_prepare_bit_for_bit(any_dev, prec, w, warp_state, inverted):
    # render widths with and without padding (pad2) and a partial last work-item; NaN and
    # infinite inputs; motions reaching outside the frame; the warped ConvLSTM state
    h, hid = 7, 4
    hp, wp = nets.pad2(h), nets.pad2(w)
    g = np.random.default_rng(w)
    ins = [g.uniform(0, 4, (h, w, 3)), g.uniform(0.1, 0.9, (h, w)), g.uniform(-6, 6, (h, w, 2)),
           g.uniform(-0.1, 1, (h, w, 3)), g.uniform(-1, 1, (h, w, 3)), g.uniform(0, 1, (8, h, w))]
    ins[1][2, 3], ins[2][1, 1, 0], ins[3][0, 2, 1], ins[4][3, 3, 2] = np.nan, np.inf, np.nan, -np.inf
    ins = [any_dev.to_device(a.astype(np.float32)) for a in ins]
    hc = [any_dev.to_device(g.uniform(-1, 1, (hid, hp, wp)).astype(np.float32), prec) for _ in range(2)]
    i32, f = np.int32, np.float32
    outs = []
    for name, gs in (("nsrd_prepare8", (-(-wp // 8), hp)), ("nsrd_prepare", (wp, hp))):
        # every output starts from the same bits, so what neither kernel writes agrees too
        bufs = [any_dev.to_device(np.full(shape, 7.0, np.float32), p) for shape, p in
                (((8, h, w), "fp32"), ((10, hp, wp), prec), ((8, hp, wp), prec), ((2, h, w), "fp32"),
                 ((hid, hp, wp), prec), ((hid, hp, wp), prec))]
        sn, cur, warp, mv, hw, cw = bufs
        any_dev.launch(_frame_kernel(any_dev, prec, name, 2), gs, [
            *(a.data for a in ins), sn.data, cur.data, warp.data, mv.data, i32(w), i32(h), i32(wp), i32(hp),
            i32(inverted), f(1.0), f(-1.0), f(0.5), f(0.3), f(1.0), i32(1), i32(1), f(0.01), f(0.1), f(0.05),
            hc[0].data, hc[1].data, hw.data, cw.data, i32(hid), i32(warp_state)])
        if name == "nsrd_prepare8" and warp_state:       # its h and c warp, a kernel of its own
            any_dev.launch(_frame_kernel(any_dev, prec, "nsrd_warp_state8", 2), (-(-wp // 8), hp, hid), [
                mv.data, hc[0].data, hc[1].data, hw.data, cw.data, i32(w), i32(h), i32(wp), i32(hp), f(1.0)])
        outs.append([b.get() for b in bufs])
    for a, b in zip(*outs):
        assert np.array_equal(a.view(np.uint8), b.view(np.uint8))
