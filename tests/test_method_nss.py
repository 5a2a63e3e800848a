"""The NSS room (clss/methods/nss/): the OpenCL frame step against its whole-frame ONNX
twin in fp32 and fp16 (both kernel presets, an odd render size the network pads to
multiples of 8, a reset mid-sequence), with the carried state (history, luma
derivative) and the reconstructed depth compared too; the portable depth path against
the atomic one; each kernel against its own twin (clss verify's cases); the registry
entry; the scale; step_device and flat memory over 300 frames; `clss upscale --method nss`.

Tolerances (per frame): fp32 |d| <= 3e-4 * max|ref| on every output pixel (the
neighbourhood clamp takes the square root of a variance E[c^2] - E[c]^2 whose
cancellation depends on the summation order), the reconstructed depth bit-equal to
onnxruntime's ScatterElements; fp16 (half storage of the network's tensors) 5e-3 * max|ref|.
"""
from __future__ import annotations

import numpy as np
import pytest

import clss
from clss import methods
from clss.methods.nss import networks as nets
from helpers import RESET_AT, assert_case, frames

RENDER = (13, 17)          # odd: the network runs on 16 x 24 inside


def _weights(quality="mid", seed=3):
    cfg = nets.make_config(2.0, quality)
    w = nets.init_weights(cfg, seed=seed)
    w["kpn.weight"] = w["kpn.weight"] * 10      # head outputs that vary
    w["tp.weight"] = w["tp.weight"] * 10
    return cfg, w


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("quality", ["mid", "high"])
def test_frame_step_matches_its_onnx_twin(quality, precision, dev):
    cfg, w = _weights(quality)
    ours = clss.Upscaler(method="nss", scale=2, device=dev, precision=precision, weights=(cfg, w))
    twin = methods.twin("nss", RENDER, 2.0, weights=(cfg, w))
    tol = 3e-4 if precision == "fp32" else 5e-3
    for i, f in enumerate(frames(RENDER, 7, scale=2.0)):
        reset = i == RESET_AT
        a = ours.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        b = twin.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        assert a.shape == b.shape == (26, 34, 3) and a.dtype == np.float32
        d = np.abs(a - b).max()
        assert d <= tol * np.abs(b).max(), f"{quality} {precision} frame {i}: max |d| {d:.3g}"
        fs = ours._fs
        rec = fs.dev.to_host(fs.recon).view(np.float32)
        assert np.array_equal(rec, twin.last["recon"]), f"frame {i}: reconstructed depth"
        for name, mine, ref, t in (("hist", fs.hist, twin.st["hist"][0], tol * 4),
                                   ("deriv", fs.deriv, twin.st["deriv"][0], 1e-5 if precision == "fp32" else 1e-3)):
            dd = np.abs(fs.dev.to_host(mine) - ref).max()
            assert dd <= t, f"{precision} frame {i}: {name} max |d| {dd:.3g}"
    x = fs.dev.to_host(fs.x).astype(np.float32)
    # the network's input is used: some disocclusion, some history, a derivative somewhere
    assert 0 < x[0, 6].mean() < 1 and x[0, 0:3].max() > 0 and x[0, 7:11].max() > 0


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_kernel_conformance_cases(precision, dev):
    """Each nss.cl kernel (and the atomic depth path) against its own twin
    (oracle.inputs_graph / depth_graph / pre_graph / post_graph), as `clss verify` runs them."""
    from clss.verify.cases import nss, scatter
    cases = nss.cases("quick")
    assert {c.op for c in cases} == {"nss_inputs", "nss_depth_gather", "nss_depth_atomic",
                                     "nss_pre", "nss_post"}
    assert {c.name for c in cases} <= {c.name for c in scatter.cases("quick")}
    for case in cases:
        assert_case(case, dev, precision)


def test_the_portable_depth_path_matches_the_atomic_one(dev):
    """The gather reconstruction (no atomics) equals the atomic scatter on these frames
    (their motion varies by less than the search radius around each contributor)."""
    cfg, w = _weights()
    ups = {p: clss.Upscaler(method="nss", scale=2, device=dev, weights=(cfg, w), depth_scatter=p)
           for p in ("atomic", "gather")}
    for i, f in enumerate(frames(RENDER, 5, scale=2.0)):
        outs = {p: up.step(f.color, f.depth, f.motion, f.jitter) for p, up in ups.items()}
        recs = {p: up._fs.dev.to_host(up._fs.recon) for p, up in ups.items()}
        assert np.array_equal(recs["atomic"], recs["gather"]), f"frame {i}"
        assert np.array_equal(outs["atomic"], outs["gather"])
    with pytest.raises(ValueError, match="depth_scatter"):
        clss.Upscaler(method="nss", scale=2, device=dev, weights="untrained", depth_scatter="x")


def test_reset_clears_the_history(dev):
    seq = frames(RENDER, 3, scale=2.0)
    cfg, w = _weights()
    up = clss.Upscaler(method="nss", scale=2, device=dev, weights=(cfg, w))
    fresh = clss.Upscaler(method="nss", scale=2, device=dev, weights=(cfg, w))
    for f in seq:
        up.step(f.color, f.depth, f.motion, f.jitter)
    f = seq[0]
    a = up.step(f.color, f.depth, f.motion, f.jitter, reset=True)
    b = fresh.step(f.color, f.depth, f.motion, f.jitter)
    assert np.array_equal(a, b)
    x = up._fs.dev.to_host(up._fs.x).astype(np.float32)
    assert (x[0, 6] == 1).all() and not x[0, 0:3].any() and not x[0, 7:12].any()


def test_scale_and_weights_are_checked(dev):
    with pytest.raises(ValueError, match="scale"):
        clss.Upscaler(method="nss", scale=3, device=dev, weights="untrained")
    with pytest.raises(ValueError, match="quality"):
        clss.Upscaler(method="nss", scale=2, device=dev, weights="untrained", quality="ultra")
    cfg, w = _weights()
    del w["tp.bias"]
    with pytest.raises(Exception, match="tp.bias"):
        clss.Upscaler(method="nss", scale=2, device=dev, weights=(cfg, w))


def test_network_shape_and_size():
    for q, params, kmacs in (("mid", 142676, 10.944), ("high", 148456, 11.304)):
        cfg = nets.make_config(2, q)
        assert nets.parameter_count(cfg) == params
        assert abs(nets.macs_per_pixel(cfg) / 1e3 - kmacs) < 1e-3
        assert len(nets.layer_shapes(cfg)) == 14


def test_registry_entry():
    s = methods.spec("nss")
    assert s.gbuffers == () and s.twin and s.scales == (2.0, 2.0) and s.room == "nss"


def test_step_device_and_300_frames_hold_memory_flat(dev):
    """The state stays on the device in buffers allocated once: step_device equals the
    host step, and 300 frames allocate nothing per frame (device bytes constant; the
    process's peak resident memory grows by under 20 MB after the first 20 frames)."""
    import resource

    import pyopencl.array as cla
    seq = frames(RENDER, 4, scale=2.0)
    up = clss.Upscaler(method="nss", scale=2, device=dev, weights="untrained")
    ref = clss.Upscaler(method="nss", scale=2, device=dev, weights="untrained")
    q = up.dev.queue
    for f in seq:
        d = [cla.to_device(q, np.ascontiguousarray(v, np.float32)) for v in (f.color, f.depth, f.motion)]
        assert np.array_equal(up.step_device(*d, f.jitter).get(),
                              ref.step(f.color, f.depth, f.motion, f.jitter))
    out = cla.empty(q, (26, 34, 3), np.float32)
    sizes = set()
    for i in range(300):
        f = seq[i % 4]
        up.step_device(*d, f.jitter, reset=i % 100 == 0, out=out)
        sizes.add(up.device_bytes())
        if i == 19:
            rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    assert len(sizes) == 1
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0 < 20 * 1024
    assert np.isfinite(out.get()).all()


def test_upscale_cli(tmp_path, capsys):
    """`clss upscale --method nss` on the demo's EXR frames (untrained weights asked for);
    without weights the one-line error naming the way out."""
    import glob

    from clss.cli import main
    demo = tmp_path / "demo"
    assert main(["demo", "-o", str(demo), "--frames", "3", "--size", "32x18", "--scale", "2",
                 "--methods", "bicubic", "--workers", "1", "--exr"]) == 0
    out = tmp_path / "up"
    assert main(["upscale", str(demo / "input"), "--method", "nss", "--scale", "2",
                 "--weights", "untrained", "-o", str(out)]) == 0
    assert len(glob.glob(str(out / "frame.*.exr"))) == 3
    if methods.spec("nss").weights() != "trained":
        capsys.readouterr()
        assert main(["upscale", str(demo / "input"), "--method", "nss", "--scale", "2",
                     "-o", str(tmp_path / "none")]) == 2
        err = capsys.readouterr().err
        assert "no trained weights" in err and "Traceback" not in err


def test_kernel_defaults_are_the_networks_constants():
    # nss.cl builds on its own (a porter's build, tests/test_device.py) with #ifndef defaults;
    # they must be the very values frame.py passes as -D, or the two builds would differ.
    import re
    from clss.device import _define_value
    from clss.methods.nss import networks as nets
    from clss.methods.nss.frame import KERNEL, kernel_defines
    src = open(KERNEL).read()
    defaults = dict(re.findall(r"#ifndef (\w+)\n#define \1 (\S+)\n#endif", src))
    passed = kernel_defines(nets.make_config(2, "mid"))
    assert set(passed) <= set(defaults), set(passed) - set(defaults)
    assert {k: _define_value(v) for k, v in passed.items()} == {k: defaults[k] for k in passed}
