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

from clss import scene
from weights_tools.blender import convert, render_validation as rv

BLENDER = shutil.which("blender")


def test_jitter_matches_clss_scene():
    for scale in (1.5, 2.0, 3.0):
        for i in range(80):
            assert rv.halton_jitter(i, scale) == scene.halton_jitter(i, scale)


@pytest.mark.skipif(BLENDER is None, reason="blender not installed")
def test_pan_test_conventions(tmp_path):
    script = os.path.join(os.path.dirname(rv.__file__), "render_validation.py")
    h, w = 18, 32
    subprocess.run([BLENDER, "-b", "--factory-startup", "-P", script, "--",
                    "--out", str(tmp_path), "--scenes", "pan_test", "--frames", "3",
                    "--size", f"{h}x{w}", "--spp", "2", "--ref-spp", "16"],
                   check=True, capture_output=True, timeout=300)
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
