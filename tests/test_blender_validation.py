"""The Blender validation renderer's conventions, on its pan test scene: the Vector
pass converted to DATA.md motion (prev = p + motion, +y down), the Depth pass to
reversed-Z, and the jitter's camera shift. The render test needs Blender (`apt-get
install blender`) and is skipped without it; about 10 s (mostly Blender's start)."""
import math
import os
import shutil
import subprocess

import numpy as np
import pytest

from clss.demo import scene
from weights_tools.blender import convert, render_validation as rv

BLENDER = shutil.which("blender")


def test_jitter_matches_clss_scene():
    for scale in (1.5, 2.0, 3.0):
        for i in range(80):
            assert rv.halton_jitter(i, scale) == scene.halton_jitter(i, scale)


def _has_bpy():
    import importlib.util
    return importlib.util.find_spec("bpy") is not None


@pytest.mark.parametrize("how", ["blender", "bpy"])
def test_pan_test_conventions(tmp_path, how):
    """Through Debian's blender (a subprocess) and through bpy (Blender 5 as a module,
    the [data] extra), each where installed."""
    h, w = 18, 32
    if how == "blender":
        if BLENDER is None:
            pytest.skip("blender not installed (apt-get install blender)")
        script = os.path.join(os.path.dirname(rv.__file__), "render_validation.py")
        subprocess.run([BLENDER, "-b", "--factory-startup", "-P", script, "--",
                        "--out", str(tmp_path), "--scenes", "pan_test", "--frames", "3",
                        "--size", f"{h}x{w}", "--spp", "2", "--ref-spp", "16"],
                       check=True, capture_output=True, timeout=300)
    else:
        if not _has_bpy():
            pytest.skip("bpy (Blender as a module) not installed: pip install -e '.[data]'")
        rv.render_scene("pan_test", str(tmp_path / "pan_test"), 3, (w, h), 2.0, 2, 16,
                        log=None)
    data = convert.convert_scene(str(tmp_path / "pan_test"))
    assert data["color"].shape == (3, h, w, 3) and data["reference"].shape == (3, 2 * h, 2 * w, 3)
    # The camera moves right and up: the plane's points were right (+x) and above (-y,
    # +y down) in the previous frame. Focal length in pixels: 60 degrees across w.
    f = (w / 2) / math.tan(math.radians(30))
    np.testing.assert_allclose(data["motion"][..., 0], rv.PAN_STEP[0] * f / rv.PAN_DISTANCE,
                               rtol=1e-3)
    np.testing.assert_allclose(data["motion"][..., 1], -rv.PAN_STEP[1] * f / rv.PAN_DISTANCE,
                               rtol=1e-3)
    # Planar depth (not ray length): constant on a plane facing the camera.
    np.testing.assert_allclose(data["depth"], rv.NEAR / rv.PAN_DISTANCE, rtol=1e-4)
    assert data["reset"].tolist() == [True, False, False]
    np.testing.assert_allclose(data["jitter"][1], rv.halton_jitter(1, 2.0), atol=1e-6)
    e = convert.jitter_check(data)
    assert e["recorded"] < 0.6 * e["flipped"], e


def _write_exr(path, channels):
    import OpenImageIO as oiio
    names = list(channels)
    h, w = channels[names[0]].shape
    spec = oiio.ImageSpec(w, h, len(names), oiio.FLOAT)
    spec.channelnames = tuple(names)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    out.write_image(np.stack([channels[n] for n in names], -1).astype(np.float32))
    out.close()


def test_convert_conventions(tmp_path):
    """Without Blender: EXRs laid out as Cycles writes them -> DATA.md arrays."""
    import json
    h, w, rng = 5, 7, np.random.default_rng(0)
    src = tmp_path / "scene"
    src.mkdir()
    frames = []
    for f in range(2):
        z = rng.uniform(0.5, 20, (h, w)).astype(np.float32)
        z[0, 0] = 1e10                                      # nothing hit
        lr = {f"ViewLayer.Combined.{c}": rng.random((h, w)).astype(np.float32) for c in "RGBA"}
        lr["ViewLayer.Depth.Z"] = z
        for c in "XYZW":
            lr[f"ViewLayer.Vector.{c}"] = rng.normal(size=(h, w)).astype(np.float32)
        ref = {f"ViewLayer.Combined.{c}": rng.random((2 * h, 2 * w)).astype(np.float32)
               for c in "RGBA"}
        _write_exr(src / f"lr_{f:04d}.exr", lr)
        _write_exr(src / f"ref_{f:04d}.exr", ref)
        frames.append(dict(lr=f"lr_{f:04d}.exr", ref=f"ref_{f:04d}.exr",
                           jitter=list(rv.halton_jitter(f, 2.0)), reset=f == 0, _lr=lr, _ref=ref))
    rec = dict(scene="scene", description="synthetic", render_size=[h, w], output_size=[2 * h, 2 * w],
               scale=2.0, near=0.1, spp=1, ref_spp=1, blender="test", seconds={},
               frames=[{k: v for k, v in fr.items() if not k.startswith("_")} for fr in frames])
    (src / "frames.json").write_text(json.dumps(rec))
    d = convert.convert_scene(str(src))
    lr, ref = frames[1]["_lr"], frames[1]["_ref"]
    np.testing.assert_array_equal(d["color"][1], np.stack([lr[f"ViewLayer.Combined.{c}"]
                                                           for c in "RGB"], -1))
    np.testing.assert_array_equal(d["motion"][1, ..., 0], lr["ViewLayer.Vector.X"])
    np.testing.assert_array_equal(d["motion"][1, ..., 1], -lr["ViewLayer.Vector.Y"])
    want = np.float32(0.1) / lr["ViewLayer.Depth.Z"]
    assert d["depth"][1, 0, 0] == 0
    np.testing.assert_allclose(d["depth"][1].ravel()[1:], want.ravel()[1:], rtol=1e-6)
    assert d["reference"].shape == (2, 2 * h, 2 * w, 3) and d["reset"].tolist() == [True, False]
    assert json.loads(str(d["meta"]))["renderer"].startswith("Blender test")
    assert convert.main([str(tmp_path / "missing"), str(tmp_path / "o")]) == 2
