"""The evaluation command (weights_tools.evaluate) and the metrics it adds to clss.metrics
(running tPSNR with cuts, FLIP). Tiny shapes: the whole file runs in seconds."""
import json
import math

import numpy as np
import pytest

from clss import metrics
from weights_tools import evaluate
from weights_tools.__main__ import main as wt_main


# ---------------------------------------------------------------- metrics

def test_temporal_psnr_hand_made():
    # reference steps by +0.1 per frame; the test steps by +0.1, then +0.3: one difference
    # off by 0.2 everywhere, one exact -> MSE 0.02 over the two differences
    ref = [np.full((4, 5, 3), v, np.float32) for v in (0.2, 0.3, 0.4)]
    test = [np.full((4, 5, 3), v, np.float32) for v in (0.2, 0.3, 0.6)]
    want = 10 * math.log10(1 / 0.02)
    assert metrics.temporal_psnr(test, ref, tonemapped=True) == pytest.approx(want, abs=1e-4)
    acc = metrics.TemporalPSNR()
    assert math.isnan(acc.value())
    for t, r in zip(test, ref):
        acc.add(t, r)
    assert acc.value() == pytest.approx(want, abs=1e-4) and acc.pairs == 2 * 4 * 5 * 3
    # a cut before the last frame drops the bad difference: what is left is exact
    acc = metrics.TemporalPSNR()
    acc.add(test[0], ref[0])
    acc.add(test[1], ref[1])
    acc.cut()
    acc.add(test[2], ref[2])
    assert acc.value() == math.inf
    # a constant offset does not count (it is not flicker)
    assert metrics.temporal_psnr([r + 0.1 for r in ref], ref, tonemapped=True) > 100


def test_flip_range():
    rng = np.random.default_rng(0)
    a = rng.random((24, 32, 3), dtype=np.float32)
    assert metrics.flip(a, a, tonemapped=True) == 0.0
    worst = metrics.flip(np.zeros_like(a), np.ones_like(a), tonemapped=True)
    assert 0.9 < worst <= 1.0
    noisy = np.clip(a + 0.05 * rng.standard_normal(a.shape).astype(np.float32), 0, 1)
    m, emap = metrics.flip(noisy, a, tonemapped=True, error_map=True)
    assert 0.0 < m < worst and emap.shape == (24, 32)
    assert emap.min() >= 0 and emap.max() <= 1 and float(emap.mean()) == pytest.approx(m, rel=1e-4)
    # linear HDR input goes through the same tone mapping as psnr/ssim
    assert metrics.flip(a * 50, a * 50) == 0.0
    with pytest.raises(ValueError, match="shapes differ"):
        metrics.flip(a, a[:8])


def test_scored_frames():
    reset = [True, False, False, False, True, False, False]
    assert evaluate.scored_frames(reset, 2) == [2, 3, 6]
    assert evaluate.scored_frames(reset, 0) == list(range(7))
    assert evaluate.scored_frames(reset, 9) == []


# ---------------------------------------------------------------- the command

def _tiny_sequence(path, n=6, hw=(18, 26), scale=2.0, reset_at=()):
    """A DATA.md sequence from the built-in scene (different frames from the demo's)."""
    from clss.demo.scene import render_frame
    frames = [render_frame(20 + i, hw, scale, spp_ref=4) for i in range(n)]
    reset = np.array([i == 0 or i in reset_at for i in range(n)])
    np.savez(path, color=np.stack([f.color for f in frames]),
             depth=np.stack([f.depth for f in frames]),
             motion=np.stack([f.motion for f in frames]),
             jitter=np.array([f.jitter for f in frames], np.float32), reset=reset,
             reference=np.stack([f.reference for f in frames]), scale=np.float32(scale),
             meta=np.array(json.dumps({"generator": "clss.demo.scene", "test": True})))
    return str(path)


@pytest.fixture(scope="module")
def tiny_seq(tmp_path_factory):
    return _tiny_sequence(tmp_path_factory.mktemp("seq") / "tiny.npz")


def test_eval_writes_table_json_pictures(tiny_seq, tmp_path, capsys):
    from clss import io as cio
    out = tmp_path / "eval"
    rc = wt_main(["eval", tiny_seq, "--weights", "untrained", "--warmup", "2",
                  "--out", str(out), "--json", str(tmp_path / "e.json")])
    assert rc == 0
    text = capsys.readouterr().out
    for col in ("PSNR dB", "SSIM", "tPSNR dB", "FLIP", "jitter-aware bicubic", "CLSS rules",
                "CLSS net (untrained)"):
        assert col in text
    rec = json.loads((tmp_path / "e.json").read_text())
    assert json.loads((out / "eval.json").read_text()) == rec
    seq = rec["sequences"][0]
    assert seq["scored_frames"] == [2, 3, 4, 5] and seq["tpsnr_pairs"] == 3
    assert seq["output_size"] == [36, 52]
    for m in evaluate.METHODS:
        r = seq["methods"][m]
        assert len(r["psnr_frames"]) == 4 and 5 < r["psnr"] < 60 and 0 < r["ssim"] <= 1
        assert 0 < r["flip"] < 1 and math.isfinite(r["tpsnr"])
    # the jitter-aware bicubic is what the frame step upsamples without history
    assert seq["methods"]["jbicubic"]["psnr"] != seq["methods"]["bicubic"]["psnr"]
    pics = seq["pictures"]
    for k in ("temporal_profile", "side_by_side", "side_by_side_crop"):
        img, _ = cio.read_exr(pics[k])
        assert img.ndim == 3 and img.shape[2] == 3
    # profile: one column per method and the reference, 4 scored frames each
    prof, _ = cio.read_exr(pics["temporal_profile"])
    assert prof.shape[1] == 5 * 4 * 40 + 4 * 4


def test_eval_resets_and_subset(tmp_path, capsys):
    p = _tiny_sequence(tmp_path / "cut.npz", n=7, reset_at=(4,))
    r = evaluate.run_eval([p], ["jbicubic", "rules"], warmup=1, out_dir=None)   # rules: an alias
    seq = r["sequences"][0]
    assert seq["scored_frames"] == [1, 2, 3, 5, 6] and seq["resets"] == 2
    assert seq["tpsnr_pairs"] == 3            # (1,2) (2,3) (5,6): none across the cut
    assert list(seq["methods"]) == ["jbicubic", "clss-rules"]
    assert not (tmp_path / "cut").exists()


def test_eval_bad_input(tmp_path, capsys):
    good = _tiny_sequence(tmp_path / "good.npz", n=2)
    z = dict(np.load(good))
    del z["reference"]
    np.savez(tmp_path / "noref.npz", **z)
    z = dict(np.load(good))
    z["depth"] = z["depth"][:, :5]
    np.savez(tmp_path / "badshape.npz", **z)
    cases = [([str(tmp_path / "missing.npz")], "missing.npz: no such file"),
             ([str(tmp_path / "noref.npz")], "noref.npz: missing reference"),
             ([str(tmp_path / "badshape.npz")], "badshape.npz: depth: expected shape [2, 18, 26]"),
             ([good, "--warmup", "5"], "no frame left to score")]
    for args, msg in cases:
        assert wt_main(["eval", *args, "--methods", "bicubic", "--out", str(tmp_path / "o")]) == 1
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err
    for args, msg in [(["--methods", "bicubic,taa"], "--methods: expected a subset"),
                      (["--weights", str(tmp_path / "nope")], "--weights:"),
                      (["--precision", "fp64"], "--precision")]:
        with pytest.raises(SystemExit):
            wt_main(["eval", good, *args])
        assert msg in capsys.readouterr().err


def test_eval_skips_a_method_without_its_gbuffers(tiny_seq):
    """A method that needs a G-buffer the sequence does not carry (NSRD: albedo, normal,
    ...; the tiny sequence has none) skips that sequence with a line saying why; the
    other methods are scored and the run goes on (issue 31)."""
    from clss import methods
    need = methods.spec("nsrd").gbuffers
    import io
    log = io.StringIO()
    r = evaluate.run_eval([tiny_seq], ["jbicubic", "nsrd"], warmup=2, out_dir=None, log=log)
    err = log.getvalue()
    assert f"skip nsrd on tiny: it needs the G-buffer(s) {', '.join(need)}" in err
    seq = r["sequences"][0]
    assert list(seq["methods"]) == ["jbicubic"]
    assert seq["skipped"] == {"nsrd": {"missing_gbuffers": list(need)}}
    # every method skipped: the sequence is left out, the run still ends normally
    log = io.StringIO()
    r = evaluate.run_eval([tiny_seq, tiny_seq], ["nsrd"], warmup=2, out_dir=None, log=log)
    assert r["sequences"] == [] and "skip tiny: no method left to score" in log.getvalue()
    # the mean over sequences takes each method over the sequences that scored it
    a = {"methods": {"jbicubic": {"psnr": 20.0}, "nsrd": {"psnr": 30.0}}}
    b = {"methods": {"jbicubic": {"psnr": 22.0}}}
    mean = evaluate.mean_over_sequences([b, a])
    assert mean["jbicubic"]["psnr"] == 21.0 and mean["nsrd"]["psnr"] == 30.0


def test_eval_skips_a_sequence_too_short_for_the_warmup(tmp_path):
    """A sequence cut so often that the warm-up leaves no frame (Blender's `cuts` family
    beside longer shots) is skipped with a line saying why; alone, it is the error."""
    import io
    long = _tiny_sequence(tmp_path / "long.npz", n=4)
    cut = _tiny_sequence(tmp_path / "cut.npz", n=4, reset_at=(2, 3))
    log = io.StringIO()
    r = evaluate.run_eval([cut, long], ["bicubic"], warmup=2, out_dir=None, log=log)
    assert [s["name"] for s in r["sequences"]] == ["long"]
    assert "skip cut: no frame left to score after a warm-up of 2" in log.getvalue()
    with pytest.raises(ValueError, match="cut.npz: no frame left to score"):
        evaluate.run_eval([cut], ["bicubic"], warmup=2, out_dir=None, log=io.StringIO())
