"""Blender training data (weights_tools/blender/shards.py, families.py; issue 31): the
split plan (held-out families never render into training), the command's errors, and
smoke renders of 2 tiny frames in this process and through Ray. The renders need the
[data] extra (bpy; ray) and are skipped, saying so, without it: about 20 s."""
import json
import os

import numpy as np
import pytest

from weights_tools.__main__ import main as wt_main
from weights_tools.blender import families as fam
from weights_tools.blender import shards


def test_plan_holds_test_families_out(tmp_path):
    jobs = shards.plan(str(tmp_path), ["train", "validation", "test"], None, 2)
    by = {s: {(f, seed) for sp, f, seed, _ in jobs if sp == s} for s in fam.SPLITS}
    assert {f for f, _ in by["test"]} == set(fam.TEST_FAMILIES)
    assert not {f for f, _ in by["train"] | by["validation"]} & set(fam.TEST_FAMILIES)
    seeds = {s: {seed for _, seed in v} for s, v in by.items()}
    assert not seeds["train"] & seeds["validation"] and not seeds["train"] & seeds["test"]
    assert all(p.startswith(str(tmp_path / sp)) and p.endswith(f"{f}_{seed:06d}.npz")
               for sp, f, seed, p in jobs)
    with pytest.raises(shards.UsageError, match="--families: interior belongs to the test"):
        shards.plan(str(tmp_path), ["train"], ["interior"], 1)
    with pytest.raises(shards.UsageError, match="--split: unknown split 'tset'"):
        shards.plan(str(tmp_path), ["tset"], None, 1)


def test_game_family_is_held_out_and_asked_for(tmp_path):
    """The game family (issue 53 part 4) renders into the test split only, and only when
    named: the test split's default families (make train-data-blender) stay as they were."""
    assert "game" in fam.HELD_OUT and "game" not in fam.TEST_FAMILIES
    assert all("game" not in fam.SPLITS[s] for s in ("train", "validation"))
    jobs = shards.plan(str(tmp_path), ["test"], ["game"], 2)
    assert [(f, seed) for _, f, seed, _ in jobs] == [("game", 200000), ("game", 200001)]
    with pytest.raises(shards.UsageError, match="--families: game belongs to the test"):
        shards.plan(str(tmp_path), ["train"], ["game"], 1)


def test_twin_flag(tmp_path):
    t = shards.parse_twin("d:zero", (90, 160), 2.0)
    assert t == {"dir": "d", "mix": "zero", "size": (90, 160), "scale": 2.0}
    assert shards.parse_twin("d:halton:45x80", (90, 160), 2.0)["scale"] == 4.0
    for bad, msg in (("d", "expected DIR:MIX"), ("d:nope", "unknown jitter pattern"),
                     ("d:zero:40x80", "does not scale to the output size 180x320"),
                     ("d:zero:30x53", "does not scale"), ("d:zero:9x", "is not HxW")):
        with pytest.raises(shards.UsageError, match=msg):
            shards.parse_twin(bad, (90, 160), 2.0)
    out = str(tmp_path / "o")
    assert wt_main(["blender", "--out", out, "--twin", "x:zero:7x7"]) == 2


def test_errors_speak_in_flags(tmp_path, capsys):
    out = str(tmp_path / "o")
    assert wt_main(["blender", "--out", out, "--families", "trees"]) == 2
    assert "--families: unknown family 'trees'" in capsys.readouterr().err
    assert wt_main(["blender", "--out", out, "--frames", "0"]) == 2
    assert "--frames must be at least 1" in capsys.readouterr().err
    assert wt_main(["blender", "--out", out, "--scale", "5"]) == 2
    assert "--scale must be in [1, 4]" in capsys.readouterr().err
    assert wt_main(["blender", "--out", out, "--jitter-mix", "halton:0"]) == 2
    assert "--jitter-mix: 'halton:0': the weight must be positive" in capsys.readouterr().err
    assert not os.path.exists(out)


def test_shard_jitter_draws_from_the_mix(tmp_path):
    """Each shard draws its jitter pattern from --jitter-mix on its own (family, seed)
    stream (issue 53): the same shard the same draw, the training split every pattern."""
    from clss.io.jitter import PATTERNS
    jobs = shards.plan(str(tmp_path), ["train"], None, 12)
    opts = dict(shards.DEFAULTS)
    draws = [shards.shard_jitter(j, opts) for j in jobs]
    assert draws == [shards.shard_jitter(j, opts) for j in jobs]
    assert {d["pattern"] for d in draws} == set(PATTERNS)
    assert shards.shard_jitter(jobs[0], dict(opts, jitter_mix="2x2"))["pattern"] == "2x2"


TINY = ["--sequences", "1", "--frames", "2", "--size", "12x20", "--spp", "2", "--ref-spp", "4"]


def _check_shard(path, scale, h=12, w=20):
    from clss.evaluate import load_sequence
    seq = load_sequence(path)                       # the reader of eval
    H, W = int(h * scale + 0.5), int(w * scale + 0.5)
    assert seq["color"].shape == (2, h, w, 3) and seq["reference"].shape == (2, H, W, 3)
    assert set(seq["gbuffers"]) == {"albedo", "normal", "albedo_hr", "depth_hr", "normal_hr"}
    assert seq["gbuffers"]["normal_hr"].shape == (2, H, W, 3)
    assert seq["reset"].tolist() == [True, False]
    assert np.isfinite(seq["color"]).all() and seq["color"].max() > 0
    meta = json.loads(str(np.load(path)["meta"]))
    assert meta["generator"] == "weights_tools.blender.shards" and meta["split"] in fam.SPLITS


def test_render_two_tiny_frames_here(tmp_path, capsys):
    pytest.importorskip("bpy", reason="bpy (Blender as a module) not installed: "
                                      "pip install -e '.[data]'")
    out = str(tmp_path / "data")
    args = ["blender", "--out", out, "--split", "train", "--families", "materials",
            "--scale", "3", "--no-ray"] + TINY
    assert wt_main(args) == 0
    path = os.path.join(out, "train", "materials_000000.npz")
    _check_shard(path, 3.0)
    assert os.path.isfile(os.path.join(out, "train", "READY"))
    assert not os.path.exists(os.path.join(out, ".exr"))
    first = np.load(path)["color"]
    # Resumes: a finished shard is kept, not rendered again.
    mtime = os.stat(path).st_mtime_ns
    capsys.readouterr()
    assert wt_main(args) == 0
    assert "nothing to render" in capsys.readouterr().out
    assert os.stat(path).st_mtime_ns == mtime
    # Seeded: the same family and seed render the same scene (Cycles' multi-threaded
    # accumulation changes the last float bits only).
    os.remove(path)
    assert wt_main(args) == 0
    np.testing.assert_allclose(np.load(path)["color"], first, rtol=1e-4, atol=1e-6)


def test_render_two_tiny_frames_on_ray(tmp_path):
    pytest.importorskip("bpy", reason="bpy (Blender as a module) not installed: "
                                      "pip install -e '.[data]'")
    pytest.importorskip("ray", reason="ray not installed: pip install -e '.[data]'")
    out = str(tmp_path / "data")
    assert wt_main(["blender", "--out", out, "--split", "test", "--families", "particles",
                    "--jobs", "1", "--threads", "1"] + TINY) == 0
    _check_shard(os.path.join(out, "test", "particles_200000.npz"), 2.0)
    stats = json.load(open(os.path.join(out, "test", "stats.json")))
    assert stats["ray"] and stats["threads"] == 1 and stats["frames"] == 2


def test_render_game_with_twins(tmp_path):
    """make validation-data-game's command at a tiny size: the game family with a hard cut
    recorded as a reset, its jitter-free and 4x twins beside it sharing the reference and
    the output-resolution G-buffers (about 10 s)."""
    pytest.importorskip("bpy", reason="bpy (Blender as a module) not installed: "
                                      "pip install -e '.[data]'")
    d = tmp_path / "data"
    assert wt_main(["blender", "--out", str(d / "game"), "--split", "test", "--families",
                    "game", "--sequences", "1", "--frames", "3", "--size", "12x20",
                    "--spp", "2", "--ref-spp", "4", "--no-ray", "--jitter-mix", "halton",
                    "--twin", f"{d / 'zero'}:zero", "--twin", f"{d / 'x4'}:halton:6x10"]) == 0
    from clss.evaluate import load_sequence
    seqs = {k: load_sequence(str(d / k / "test" / "game_200000.npz"))
            for k in ("game", "zero", "x4")}
    for k, seq in seqs.items():
        assert os.path.isfile(d / k / "test" / "READY")
        assert seq["reference"].shape == (3, 24, 40, 3)
        assert set(seq["gbuffers"]) == {"albedo", "normal", "albedo_hr", "depth_hr", "normal_hr"}
        assert seq["reset"][0] and seq["reset"][1:].sum() == 1          # one hard cut
        np.testing.assert_array_equal(seq["reference"], seqs["game"]["reference"])
        np.testing.assert_array_equal(seq["gbuffers"]["depth_hr"],
                                      seqs["game"]["gbuffers"]["depth_hr"])
    assert seqs["game"]["color"].shape == seqs["zero"]["color"].shape == (3, 12, 20, 3)
    assert seqs["x4"]["color"].shape == (3, 6, 10, 3) and seqs["x4"]["scale"] == 4.0
    assert not seqs["zero"]["jitter"].any() and seqs["game"]["jitter"].any()
    np.testing.assert_allclose(seqs["x4"]["jitter"], seqs["game"]["jitter"])   # Halton from 1
    meta = json.loads(str(np.load(d / "zero" / "test" / "game_200000.npz")["meta"]))
    assert meta["jitter"]["pattern"] == "zero" and meta["twin_of"].endswith("game_200000.npz")
