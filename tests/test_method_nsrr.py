"""The NSRR room (clss/methods/nsrr/): the OpenCL frame step against its whole-frame ONNX
twin in fp32 and fp16 at 2x and 4x, over a reset, with the history compared too; the
reset fills and a shortened history; weights files; the registry entry.

Tolerances (per frame): fp32 |d| <= 1e-4 * max|ref| + 1e-4 * |ref| on every output pixel
and 1e-4 on the history (features in [0, ~3]); fp16 (half storage of every tensor,
~20 layers) 1e-2 * max|ref| + 1e-2 * |ref| on the output and 2e-2 on the history.
"""
from __future__ import annotations

import numpy as np
import pytest

import clss
from clss import methods
from clss.methods.nsrr import networks as nets
from helpers import RESET_AT, frames, mover

RENDER = (13, 17)          # odd: the output is padded to a multiple of 4 inside


def _hist(up):
    fs = up._fs
    h = fs.dev.to_host(fs.hist).reshape(-1, fs.Hp, fs.Wp)
    return h[:, :fs.H, :fs.W]


def _run(dev, scale, precision, n=7, weights="untrained", seq=None, **kw):
    seq = frames(RENDER, n, scale=scale) if seq is None else seq
    ours = clss.Upscaler(method="nsrr", scale=scale, device=dev, precision=precision,
                         weights=weights, **kw)
    twin = methods.twin("nsrr", RENDER, scale, weights=weights, **kw)
    tol = 1e-4 if precision == "fp32" else 1e-2
    htol = 1e-4 if precision == "fp32" else 2e-2
    for i, f in enumerate(seq):
        reset = i == RESET_AT
        a = ours.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        b = twin.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        assert a.shape == b.shape == (*ours.output_size, 3) and a.dtype == np.float32
        d = np.abs(a - b)
        assert (d <= tol * np.abs(b).max() + tol * np.abs(b)).all(), \
            f"{precision} x{scale} frame {i}: max |d| {d.max():.3g}"
        dh = np.abs(_hist(ours) - twin.hist[0]).max()
        assert dh <= htol, f"{precision} x{scale} frame {i}: history max |d| {dh:.3g}"
    return ours, twin


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("scale", [2.0, 4.0])
def test_frame_step_matches_its_onnx_twin(scale, precision, dev):
    ours, _ = _run(dev, scale, precision)
    # the history really is used: slot 1 (frame i-2, warped twice) is not empty
    assert np.abs(_hist(ours)[12:24]).max() > 0


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_leaky_activation_matches_its_onnx_twin(precision, dev):
    """act "leaky" (the shipped weights' hidden activation: LeakyRelu, alpha 0.1)."""
    cfg = nets.make_config("default", act="leaky")
    w = nets.init_weights(cfg, seed=4)
    w["un.9.weight"] = w["un.9.weight"] * 10        # the U-Net's output matters
    ours, twin = _run(dev, 4.0, precision, weights=(cfg, w))
    assert any(n.op_type == "LeakyRelu" for n in twin.model.graph.node)
    assert np.abs(_hist(ours)[12:24]).max() > 0


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("scale", [2.0, 4.0])
def test_depth_rejection_matches_its_onnx_twin(scale, precision, dev):
    """reject "depth" (networks.REJECTS) on a moving square: its trail's history emptied
    in the OpenCL step as in the twin, and only there."""
    cfg = nets.make_config("default", act="leaky", reject="depth")
    w = nets.init_weights(cfg, seed=5)
    w["un.9.weight"] = w["un.9.weight"] * 10
    seq = mover(RENDER)
    ours, twin = _run(dev, scale, precision, weights=(cfg, w), seq=seq)
    plain = methods.twin("nsrr", RENDER, scale, weights=({k: v for k, v in cfg.items() if k != "reject"}, w))
    for i, f in enumerate(seq):
        plain.step(f.color, f.depth, f.motion, f.jitter, reset=i == RESET_AT)
    a, b = twin.hist[0, 12:], plain.hist[0, 12:]
    emptied = (a == 0).all(0) & (b != 0).any(0)
    assert 0 < emptied.mean() < 0.2, emptied.mean()
    assert np.abs(_hist(ours)[12:24]).max() > 0


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("scale", [2.0, 4.0])
def test_rules_base_matches_its_onnx_twin(scale, precision, dev):
    """base "rules" (networks.BASES, issue 53): clss-rules' frame step inside NSRR's, its
    PQ output the residual's base and 3 more U-Net inputs, over a reset, with the depth
    rejection on; the twin inlines clss-rules' own frame graph. The base is the rules'
    output: with the U-Net's output conv at zero, NSRR's output is clss-rules'."""
    cfg = nets.make_config("default", act="leaky", reject="depth", base="rules")
    w = nets.init_weights(cfg, seed=6)
    w["un.9.weight"] = w["un.9.weight"] * 10
    ours, twin = _run(dev, scale, precision, weights=(cfg, w))
    assert {"rules_hist", "jitter"} <= {i.name for i in twin.model.graph.input}
    assert np.abs(_hist(ours)[12:24]).max() > 0
    w["un.9.weight"][:], w["un.9.bias"][:] = 0.0, 0.0
    up = clss.Upscaler(method="nsrr", scale=scale, device=dev, precision=precision, weights=(cfg, w))
    rules = clss.Upscaler(method="clss-rules", scale=scale, device=dev, precision=precision)
    # (fp16: NSRR's output passes through half storage once more than the rules')
    tol = 1e-5 if precision == "fp32" else 1e-2
    for i, f in enumerate(frames(RENDER, 6, scale=scale)):
        a = up.step(f.color, f.depth, f.motion, f.jitter, reset=i == RESET_AT)
        b = rules.step(f.color, f.depth, f.motion, f.jitter, reset=i == RESET_AT)
        assert (np.abs(a - b) <= tol * np.abs(b).max() + tol * np.abs(b)).all(), f"frame {i}"


@pytest.mark.parametrize("kw", [{"reset_fill": "duplicate"}, {"history": 2}])
def test_reset_fill_and_short_history_match_the_twin(kw, dev):
    ours, _ = _run(dev, 4.0, "fp32", n=6, **kw)
    h = _hist(ours)
    if kw.get("history") == 2:
        assert not h[24:].any()          # slots beyond the history stay empty


def test_reset_empties_the_history(dev):
    seq = frames(RENDER, 3, scale=2.0)
    up = clss.Upscaler(method="nsrr", scale=2.0, device=dev, weights="untrained")
    for f in seq:
        up.step(f.color, f.depth, f.motion, f.jitter)
    assert _hist(up)[12:].any()
    f = seq[0]
    up.step(f.color, f.depth, f.motion, f.jitter, reset=True)
    h = _hist(up)
    assert h[:12].any() and not h[12:].any()     # only the current frame's features


def test_fractional_scale_and_step_device(dev):
    seq = frames(RENDER, 2, scale=3.0)
    up = clss.Upscaler(method="nsrr", scale=3.0, device=dev, weights="untrained")
    twin = methods.twin("nsrr", RENDER, 3.0, weights="untrained")
    for f in seq:
        a = up.step_device(dev.to_device(f.color), dev.to_device(f.depth),
                           dev.to_device(f.motion), f.jitter).get()
        b = twin.step(f.color, f.depth, f.motion, f.jitter)
        assert np.abs(a - b).max() <= 1e-4 * np.abs(b).max() + 1e-4


def test_weights_round_trip_and_widths(tmp_path):
    for widths in nets.WIDTHS:
        cfg = nets.make_config(widths)
        w = nets.init_weights(cfg, seed=3)
        p = tmp_path / f"{widths}.safetensors"
        nets.save(str(p), cfg, w)
        cfg2, w2 = nets.load(str(p))
        assert cfg2 == cfg and all(np.array_equal(w[k], w2[k]) for k in w)
    fast, default = (nets.macs_per_pixel(nets.make_config(n), 4)["reconstruction"]
                     for n in ("fast", "default"))
    assert fast < 0.4 * default
    bad = dict(w)
    bad["un.0.weight"] = bad["un.0.weight"][:, :5]
    with pytest.raises(ValueError, match="un.0.weight"):
        nets.check_weights(cfg, bad)


def test_registry_entry():
    s = methods.spec("nsrr")
    assert "nsrr" in methods.names() and "nsrr" not in methods.PLANNED
    assert s.scales == (2.0, 4.0) and s.twin and s.doc == "docs/methods/nsrr.md"
    assert s.weights() in ("trained", "untrained")


def test_paper_output_without_residual_matches_its_twin(dev):
    """residual=False: the U-Net's output is the image, as in the paper (no base input)."""
    cfg = nets.make_config("fast", residual=False)
    w = nets.init_weights(cfg, seed=2)
    seq = frames(RENDER, 3, scale=2.0)
    up = clss.Upscaler(method="nsrr", scale=2.0, device=dev, weights=(cfg, w))
    twin = methods.twin("nsrr", RENDER, 2.0, weights=(cfg, w))
    assert "base_grid" not in {i.name for i in twin.model.graph.input}
    for f in seq:
        a = up.step(f.color, f.depth, f.motion, f.jitter)
        b = twin.step(f.color, f.depth, f.motion, f.jitter)
        assert np.abs(a - b).max() <= 1e-4 * np.abs(b).max() + 1e-4


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
@pytest.mark.parametrize("scale, kw", [(2.0, {}), (4.0, {"history": 2}), (1.5, {"reset_fill": "duplicate"})])
def test_fast_reprojection_is_the_reference_bit_for_bit(any_dev, prec, scale, kw, monkeypatch):
    """nsrr_reproject on 8-pixel runs in plane groups (with nsrr_warp_coords; the fast path
    nsrr.reproject_vectors) against one pixel per work-item: every stack plane and the
    base, over a reset (both fills), a shortened history, noisy motion (gathered taps), a
    uniform pan (window loads) and a pan off the edge, at an odd width that leaves a
    partial run and padding columns."""
    from clss import selfcheck
    from clss.methods.nsrr import frame as fr
    cfg = nets.make_config("fast")
    w = nets.init_weights(cfg, 2)
    g = np.random.default_rng(int(scale * 10))
    h, wd = RENDER
    inputs = [[any_dev.to_device(np.ascontiguousarray(a, np.float32)) for a in
               (g.uniform(0, 4, (h, wd, 3)), g.uniform(0.1, 0.9, (h, wd)), mv)]
              for mv in fr.reproject_motions(g, (h, wd, 2))]
    defines = selfcheck.defines
    results = []
    for variant in (fr.REPROJECT_FAST, {"VEC": 1}):
        monkeypatch.setattr(selfcheck, "defines", lambda d, p, n, v=variant: dict(v) if n == fr.REPROJECT_VECTORS
                            else defines(d, p, n))
        fs = fr.NsrrFrameStep(any_dev, prec, RENDER, scale, cfg, w, **kw)
        assert ("coords" in fs.L) == (variant["VEC"] == 8)
        outs = []
        for t, f in enumerate(inputs + inputs[:1]):
            out, ev = fs.run(*f, ((0.25, -0.375), (-0.125, 0.25))[t % 2], t in (0, 4))
            ev.wait()
            outs += [any_dev.to_host(fs.stacks[fs.cur]), any_dev.to_host(fs.base), any_dev.to_host(out)]
        results.append(outs)
    for i, (a, b) in enumerate(zip(*results)):
        assert np.array_equal(a.view(np.uint8), b.view(np.uint8)), f"array {i}"
