"""The jitter patterns engines send (clss.io.jitter.PATTERNS), as an engine sends them
(as_sent, converted back by clss.Contract's jitter_scale), the training mix that draws
them (weights_tools/jitter_mix.py) and the generator's record of the draw (issue 53)."""
import json

import numpy as np
import pytest

import clss
from clss.io import jitter as J
from clss.pipeline.contract import jitter_at
from weights_tools import jitter_mix as M
from weights_tools import scenegen as sg
from weights_tools.__main__ import main


def test_patterns_phases_and_range():
    assert set(J.PATTERNS) == {"zero", "2x2", "halton8", "halton16", "halton", "r2"}
    for name, period in (("2x2", 4), ("halton8", 8), ("halton16", 16), ("halton", 32)):
        j = J.pattern_jitter(name, 2 * period + 3, 2.0)
        assert np.array_equal(j[:period], j[period:2 * period]), name
        assert len({tuple(v) for v in j[:period]}) == period, name     # distinct phases
    assert not J.pattern_jitter("zero", 5).any()
    assert J.pattern_name("None") == "zero"
    # Halton 16 is the contract's default sequence, cut to 16 phases
    h16 = J.pattern_jitter("halton16", 16, 2.0)
    assert np.allclose(h16, [jitter_at(i, 2.0) for i in range(16)])
    r2 = J.pattern_jitter("r2", 200)
    assert len({tuple(v) for v in r2}) == 200 and np.abs(r2).max() <= 0.5
    # the 2x2 grid at 2x lands each phase on one of the four output pixel centres
    assert {tuple(v) for v in J.pattern_jitter("2x2", 4)} == {(a, b) for a in (-.25, .25)
                                                            for b in (-.25, .25)}
    for name in J.PATTERNS:
        assert np.abs(J.pattern_jitter(name, 40, 3.0)).max() <= 0.5, name
    with pytest.raises(ValueError, match="unknown jitter pattern 'halton7'.*known: zero"):
        J.pattern_name("halton7")


def test_flip_and_phase():
    base = J.pattern_jitter("halton8", 12)
    assert np.array_equal(J.pattern_jitter("halton8", 10, phase=2), base[2:12])
    assert np.array_equal(J.pattern_jitter("halton8", 12, flip=(-1, 1)), base * (-1, 1))
    with pytest.raises(ValueError, match="flip"):
        J.pattern_jitter("halton8", 2, flip=(2, 1))


@pytest.mark.parametrize("units,negate", [("pixel", False), ("pixel", True), ("ndc", False),
                                          ("ndc", True), ("uv", False), ("uv", True)])
def test_as_sent_round_trips_through_the_contract(units, negate):
    """What an engine sends (negated, NDC +y up, UV) times the contract's jitter_scale is the
    contract's jitter again, frame by frame."""
    j = J.pattern_jitter("r2", 6)
    values, scale = J.as_sent(j, units, negate=negate, render_size=(90, 160))
    if units == "ndc":
        up = -1 if negate else 1          # NDC's y points up: the sign flips once more
        assert np.sign(values[:, 1]).tolist() == (-np.sign(j[:, 1]) * up).tolist()
    contract = clss.Contract(jitter_scale=scale)
    back = np.array([contract.jitter(v) for v in values])
    assert np.allclose(back, j, atol=1e-6)
    with pytest.raises(ValueError, match="units"):
        J.as_sent(j, "mm")


def test_read_sequence_takes_a_pattern_name(tmp_path):
    """`read_sequence(jitter=NAME)` / `clss upscale --jitter NAME` for every pattern."""
    import clss.io as cio
    d = np.zeros((2, 3, 6), np.float32)
    for n in range(5):
        cio.write_exr(str(tmp_path / f"s.{n}.exr"), d, half=False,
                      channel_names=["R", "G", "B", "Z", "mv.x", "mv.y"])
    pat = str(tmp_path / "s.%d.exr")
    for name in ("2x2", "halton16", "r2", "none"):
        seq = cio.read_sequence(pat, jitter=name)
        assert np.allclose([f.jitter for f in seq], J.pattern_jitter(name, 5)), name
    with pytest.raises(cio.InputError, match="needs scale"):
        cio.read_sequence(pat, jitter="halton")


def test_mix_parse_and_draw():
    mix = M.parse_mix(M.DEFAULT_MIX)
    assert dict(mix)["zero"] > 0 and abs(sum(w for _, w in mix) - 1) < 1e-12
    assert M.parse_mix("2x2") == [("2x2", 1.0)]
    assert M.parse_mix("legacy") == M.parse_mix(M.LEGACY_MIX)
    for bad, what in (("halton:x", "number"), ("zero:0", "positive"), ("", "no pattern"),
                      ("bogus", "unknown")):
        with pytest.raises(ValueError, match=what):
            M.parse_mix(bad)
    rng = np.random.default_rng(0)
    draws = [M.draw(mix, rng) for _ in range(400)]
    seen = {d["pattern"] for d in draws}
    assert seen == set(J.PATTERNS)                      # every pattern, zero included
    assert {tuple(d["flip"]) for d in draws} == {(-1, -1), (-1, 1), (1, -1), (1, 1)}
    assert len({d["phase"] for d in draws}) > 20
    assert M.draw("2x2", rng) == {"pattern": "2x2", "flip": [1, 1], "phase": 0}


def test_generator_records_the_draw_and_keeps_the_content(tmp_path, capsys):
    """The same seed gives the same scene whatever the mix (the jitter draws from its own
    stream); meta records the draw and the frames carry its jitter."""
    a = sg.SceneSpec.random(3, 1, 6, "zero")
    b = sg.SceneSpec.random(3, 1, 6, "2x2")
    assert a.objects == b.objects and a.cameras == b.cameras and a.cut == b.cut
    assert a.jitter["pattern"] == "zero" and not a.jittered and b.jittered
    js = [sg.frame_jitter(b, i, 2.0) for i in range(6)]
    assert np.allclose(js, J.pattern_jitter("2x2", 6))
    out = tmp_path / "g"
    assert main(["gen", "--out", str(out), "--sequences", "1", "--frames", "2", "--size",
                 "8x12", "--spp", "1", "--workers", "1", "--quiet", "--jitter-mix", "r2"]) == 0
    z = np.load(out / "seq_0000.npz")
    meta = json.loads(str(z["meta"]))
    assert meta["content"]["jitter"] == {"pattern": "r2", "flip": [1, 1], "phase": 0}
    assert np.allclose(z["jitter"], J.pattern_jitter("r2", 2))
    assert json.load(open(out / "stats.json"))["jitter_mix"] == "r2"
    assert main(["gen", "--out", str(tmp_path / "h"), "--jitter-mix", "halton:-1"]) == 2
    err = capsys.readouterr().err
    assert "--jitter-mix" in err and "Traceback" not in err


def test_legacy_mix_is_the_old_generator():
    """--jitter-mix legacy gives the sequences of before issue 53 exactly: Halton(2,3) of
    the contract's length when the content's own draw says jittered, else zero."""
    for index in range(12):
        spec = sg.SceneSpec.random(1000, index, 4, "legacy")
        assert spec.jitter == {}
        want = [jitter_at(i, 2.0) if spec.jittered else (0.0, 0.0) for i in range(4)]
        assert [sg.frame_jitter(spec, i, 2.0) for i in range(4)] == want
