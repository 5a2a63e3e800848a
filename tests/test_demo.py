"""`clss demo` and `clss upscale` end to end, at tiny sizes."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

from clss.cli import main


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    assert main(["demo", "-o", str(out), "--frames", "6", "--size", "64x36", "--workers", "1",
                 "--exr"]) == 0
    return out


def test_demo_outputs(demo_dir, capsys):
    for name in ("demo.png", "demo.gif", "temporal_profile.png", "metrics.json", "metrics.md",
                 "input/jitter.json", "input/frame.0005.exr", "input/reference.0005.exr"):
        assert (demo_dir / name).is_file(), name
    # every method the scene can feed with weights for the demo's scale (2), each in a
    # folder of its name; a method without shipped weights there (nss today) is left out
    from clss.cli.demo import scene_methods
    ran = scene_methods(2)
    assert {"bicubic", "jbicubic", "clss-rules", "clss"} <= set(ran)
    for m in set(scene_methods()) - set(ran):
        assert not (demo_dir / m).exists(), m
    for m in ran:
        for ext in ("png", "exr"):
            assert (demo_dir / m / f"frame.0005.{ext}").is_file()
    for v in ("ghost", "blend_weight", "counter", "depth_difference"):
        assert (demo_dir / "debug" / f"clss-rules_{v}.0005.png").is_file()
        assert (demo_dir / "debug" / f"clss_{v}.0005.png").is_file()
    assert (demo_dir / "debug" / "clss_ghost_class.0005.png").is_file()
    assert (demo_dir / "debug" / "clss_alias_class.0005.png").is_file()
    summary = json.loads((demo_dir / "metrics.json").read_text())
    from clss.methods.clss.upscaler import SHIPPED_WEIGHTS
    assert summary["net_weights"] == ("trained" if os.path.isfile(SHIPPED_WEIGHTS)
                                      else "untrained (seeded)")
    ps = {m: summary["methods"][m]["psnr_mean"] for m in ran}
    assert all(np.isfinite(v) and v > 10 for v in ps.values()), ps
    assert ps["clss-rules"] > ps["bicubic"], ps
    assert set(summary["stage_ms"]["clss"]) == {"prepare", "depth_diff", "resolve", "classifier",
                                                "compose"}
    # warm step times apart from the first frame's (which builds the kernels) and the I/O
    for m in ran:
        r = summary["methods"][m]
        assert len(r["step_ms"]) == 6 and r["ms_per_frame"] > 0 and r["first_frame_ms"] > 0
    assert summary["io_s"] > 0
    side = json.loads((demo_dir / "input" / "jitter.json").read_text())
    assert side["frames"] == list(range(6)) and len(side["jitter"]) == 6 and side["resets"] == [0]


def _png_size(path):
    import OpenImageIO as oiio
    inp = oiio.ImageInput.open(str(path))
    n = 0
    while inp.seek_subimage(n, 0):
        n += 1
    spec = inp.spec()
    inp.close()
    return spec.width, spec.height, n


def test_demo_default_writes_pictures_only(tmp_path):
    """By default the demo writes what a visitor looks at (a few MB at the defaults, here
    a few hundred kB) and no EXR: the full sequences only with --exr."""
    out = tmp_path / "d"
    assert main(["demo", "-o", str(out), "--frames", "5", "--size", "64x36", "--workers", "1",
                 "--methods", "bicubic,clss-rules"]) == 0
    files = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())
    assert files == ["demo.gif", "demo.png", "metrics.json", "metrics.md", "temporal_profile.png"]
    assert sum((out / f).stat().st_size for f in files) < 1_000_000
    # the grid: 4 columns at most, so a 1200 px page shows it whole; the GIF has every frame
    w, h, _ = _png_size(out / "demo.png")
    assert w <= 1200 and h < w
    assert _png_size(out / "demo.gif")[2] == 5
    summary = json.loads((out / "metrics.json").read_text())
    y0, y1, x0, x1 = summary["window"]
    assert 0 <= y0 < y1 <= 72 and 0 <= x0 < x1 <= 128
    md = (out / "metrics.md").read_text()
    for m in ("bicubic", "CLSS rules"):
        assert f"| {m} | {summary['methods'][m.lower().replace(' ', '-')]['psnr_mean']:.2f} |" in md


def test_demo_grid_is_labelled(tmp_path):
    """Each tile is named with its method and PSNR: the label band above it holds text."""
    from clss import pictures
    tiles = [np.full((40, 60, 3), 0.5, np.float32) for _ in range(5)]
    plain = pictures.grid(tiles, [""] * 5, cols=4, band=24)
    named = pictures.grid(tiles, ["bicubic  21.93 dB"] * 5, cols=4, band=24)
    assert plain.shape == named.shape == (2 * (40 + 24) + 6, 4 * 60 + 3 * 6, 3)
    band = named[:24, :60]
    assert band.max() > 0.5 and plain[:24, :60].max() < 0.2     # light text on the dark band
    assert np.array_equal(named[24:64, :60], tiles[0])


def test_hardest_box():
    from clss import pictures
    err = np.random.default_rng(0).uniform(0, 0.1, (90, 160))
    err[50:60, 100:120] = 1.0               # the wires
    y0, y1, x0, x1 = pictures.hardest_box(err, 20, 40)
    assert (y1 - y0, x1 - x0) == (20, 40)
    assert y0 <= 50 and 60 <= y1 and x0 <= 100 and 120 <= x1
    assert pictures.hardest_box(err, 200, 400) == (0, 90, 0, 160)   # larger than the image


def test_upscale_cli(demo_dir, tmp_path, capsys):
    out = tmp_path / "up"
    rc = main(["upscale", str(demo_dir / "input"), "-o", str(out), "--mode", "rules", "--png",
               "--debug-views"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert (out / "frame.0005.exr").is_file() and (out / "frame.0005.png").is_file()
    assert (out / "debug" / "ghost.0005.png").is_file()
    assert "per-stage time per frame" in cap.out and "resolve" in cap.out
    assert "against the reference frames: PSNR" in cap.out
    assert "clss upscale: first frame in" in cap.err       # after its kernel builds
    # the same frames as the demo's rule mode (same inputs, read back from half EXR)
    from clss.io import read_exr
    a, _ = read_exr(out / "frame.0005.exr")
    b, _ = read_exr(demo_dir / "clss-rules" / "frame.0005.exr")
    assert np.abs(a - b).max() <= 2e-3 * max(np.abs(b).max(), 1)


def test_upscale_cli_errors(demo_dir, tmp_path, capsys):
    assert main(["upscale", str(tmp_path / "nothing"), "-o", str(tmp_path / "o")]) == 2
    assert "clss upscale:" in capsys.readouterr().err
    # a NaN in frame 2: frames 0-1 are written, the error names the frame and the input
    from clss.io import read_exr, write_exr
    src = tmp_path / "seq"
    src.mkdir()
    for i in range(4):
        data, names = read_exr(demo_dir / "input" / f"frame.{i:04d}.exr")
        if i == 2:
            data[3, 4, 0] = np.nan
        write_exr(src / f"frame.{i:04d}.exr", data, half=False, channel_names=names)
    (src / "jitter.json").write_text((demo_dir / "input" / "jitter.json").read_text())
    out = tmp_path / "o2"
    assert main(["upscale", str(src), "-o", str(out), "--mode", "rules"]) == 2
    err = capsys.readouterr().err
    assert "frame 2" in err and "color" in err and "2 frames written" in err
    assert sorted(os.listdir(out)) == ["frame.0000.exr", "frame.0001.exr"]
