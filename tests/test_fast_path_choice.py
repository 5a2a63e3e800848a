"""Fast paths that are speed choices (FastPath.measured: fused frame stages, pixels as vectors)
are used where a measurement on the device or its class says so (the tuning database, then the
shipped table), else where they were measured first (CPUs); `clss tune --level` measures them
(bench/tune_fastpaths.py) and `make gpu-report` ships its choices."""
import json

import pytest

from bench.suite import all_cases
from bench.tune_fastpaths import format_paths, measured_paths, tune_paths
from clss import selfcheck, tuning

FUSED = "bicubic.fused8"        # a measured path of the bicubic room, CPU-only by default


@pytest.fixture
def db(tmp_path, monkeypatch):
    monkeypatch.setenv("CLSS_TUNING_DB", str(tmp_path / "tuning.json"))
    selfcheck.forget()
    yield tmp_path / "tuning.json"
    selfcheck.forget()


def _bicubic_frame():
    import clss.methods  # noqa: F401  (registers the rooms' fast paths)
    cases, _ = all_cases("default", ("tiny",))
    return [c for c in cases if c.kind == "frame" and c.name.startswith("frame step bicubic")]


class _Gpu:
    """A stand-in for a GPU device for applies_on, which reads only the name and class."""
    is_cpu = False

    class info:
        name, driver, platform, vendor = "Some GPU", "1.0", "NVIDIA CUDA", "NVIDIA Corporation"


def test_the_measured_paths_are_the_cpu_ones_and_the_conv_layouts_are_not():
    import clss.methods  # noqa: F401
    measured = {n for n, fp in selfcheck.REGISTRY.items() if fp.measured}
    assert {FUSED, "frame.pixel_vectors.rule", "mlp_upscale.fused", "nsrr.reproject_vectors"} <= measured
    # the conv layouts are chosen per layer by the conv variant chooser, not here
    assert not any(n.startswith(("conv.", "model.")) for n in measured)


def test_a_stored_choice_beats_the_default_on_either_kind_of_device(dev, db):
    _bicubic_frame()
    fp = selfcheck.REGISTRY[FUSED]
    assert fp.applies_on(dev) and not fp.applies_on(_Gpu())          # not measured: CPUs only
    tuning.store(dev, tuning.FAST_PATH_OP, FUSED, {"use": False})
    tuning.store(_Gpu(), tuning.FAST_PATH_OP, FUSED, {"use": True})
    assert not fp.applies_on(dev) and fp.applies_on(_Gpu())
    assert not selfcheck.enabled(dev, "fp32", FUSED)                  # the op runs the reference
    tuning.store(dev, tuning.FAST_PATH_OP, FUSED, {"use": "yes"})   # not a bool: ignored
    assert fp.applies_on(dev)


def test_the_shipped_table_answers_for_a_device_nobody_measured(db, monkeypatch):
    _bicubic_frame()
    fp = selfcheck.REGISTRY[FUSED]
    monkeypatch.setattr(tuning, "shipped", lambda dev: {tuning.FAST_PATH_OP: {FUSED: True}})
    assert fp.applies_on(_Gpu())
    tuning.store(_Gpu(), tuning.FAST_PATH_OP, FUSED, {"use": False})   # the device's own first
    assert not fp.applies_on(_Gpu())


def test_asking_collects_the_fast_paths_a_frame_step_uses(dev, db):
    (case,) = _bicubic_frame()
    with selfcheck.asking() as asked:
        case.build(dev, "fp32", dict(case.defaults)).run()
        dev.queue.finish()
    assert FUSED in asked
    assert measured_paths([case], dev, ["fp32"])[FUSED][0][0] is case


def test_the_tuner_times_the_frame_step_with_and_without_and_stores_the_choice(dev, db):
    cases = _bicubic_frame()
    (res,) = [r for r in tune_paths(cases, dev, ["fp32"], runs=2, db=db) if r.name == FUSED]
    assert res.use is not None and len(res.cases) == 1 and res.total(2) > 0 and res.total(3) > 0
    assert res.use == (res.total(3) <= res.total(2) * 0.95)
    stored = json.loads(db.read_text())["devices"][tuning.device_key(dev)][tuning.FAST_PATH_OP][FUSED]
    assert stored["params"] == {"use": res.use} and stored["cases"]
    assert FUSED in format_paths([res])


def test_a_path_whose_self_check_fails_is_stored_unused_without_timing(dev, db, monkeypatch):
    cases = _bicubic_frame()
    bad = selfcheck.Verdict(FUSED, "bicubic", "fp32", "x", False, "differs")
    monkeypatch.setattr(selfcheck, "verdict", lambda *a, **k: bad)
    (res,) = [r for r in tune_paths(cases, dev, ["fp32"], runs=1, db=db) if r.name == FUSED]
    assert res.use is False and not res.cases and "self-check" in res.note
    tuning.load()   # re-read
    assert tuning.measured_choice(dev, tuning.FAST_PATH_OP, FUSED) is False


def test_the_gpu_reports_shipped_candidate_carries_the_fast_path_choices(dev, db, tmp_path):
    from bench.gpu_report import shipped_candidate
    tuning.store(dev, tuning.FAST_PATH_OP, FUSED, {"use": False}, path=db)
    path = shipped_candidate(db, tmp_path)
    table = json.loads(path.read_text())
    assert table[tuning.FAST_PATH_OP][FUSED] is False and "conv2d" in table["ops"]
