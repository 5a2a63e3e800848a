"""precision="auto", every method's default (clss/pipeline/precision.py): fp32 on a CPU; on a
GPU fp16 storage where the method's fp16 frame step verifies against its fp32 one on that
device (checked once, kept in selfcheck.json), else fp32."""
import dataclasses

import numpy as np
import pytest

import clss
from clss import methods, selfcheck
from clss.pipeline import precision as P


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("CLSS_CACHE_DIR", str(tmp_path))
    P._memo.clear()
    selfcheck.forget()
    yield tmp_path
    P._memo.clear()
    selfcheck.forget()


class _Gpu:
    is_cpu = False

    class info:
        name, driver, platform, vendor = "Some GPU", "1.0", "NVIDIA CUDA", "NVIDIA Corporation"


def test_auto_is_the_default_and_runs_fp32_on_a_cpu(dev):
    for name in ("bicubic", "clss-rules", "nss"):
        up = clss.Upscaler(method=name, scale=2, device=dev)
        assert up.precision == "fp32", name
    assert clss.Upscaler(method="bicubic", device=dev, precision="fp16").precision == "fp16"
    with pytest.raises(ValueError, match="'auto' or 'fp32' or 'fp16'"):
        clss.Upscaler(method="bicubic", device=dev, precision="fp8")


def test_a_gpu_gets_fp16_only_where_it_verified(monkeypatch, tmp_path):
    monkeypatch.setenv("CLSS_TUNING_DB", str(tmp_path / "tuning.json"))
    spec = methods.spec("bicubic")
    verdicts = {True: selfcheck.Verdict("precision.bicubic", "bicubic", "fp16", "gpu", True),
                False: selfcheck.Verdict("precision.bicubic", "bicubic", "fp16", "gpu", False, "differs")}
    for ok, want in ((True, "fp16"), (False, "fp32")):
        monkeypatch.setattr(P, "verdict", lambda s, d, ok=ok: verdicts[ok])
        assert P.resolve(spec, _Gpu(), "auto") == want
        assert P.resolve(spec, _Gpu(), "fp32") == "fp32"      # an explicit precision is kept


def test_the_check_passes_a_real_fp16_step_and_fails_a_wrong_one(dev):
    spec = methods.spec("bicubic")
    ok, detail = P.check(spec, dev)
    assert ok and "dB of fp32" in detail
    real = spec.create

    class Noisy:        # an fp16 step that is off by 2 % of the signal: a broken half kernel
        def __init__(self, up):
            self.up = up

        def step(self, *a, **k):
            out = self.up.step(*a, **k)
            return out * (1 + 0.02 * np.random.default_rng(0).standard_normal(out.shape)).astype(np.float32)

    def create(**kw):
        up = real(**kw)
        return Noisy(up) if kw["precision"] == "fp16" else up
    ok, detail = P.check(dataclasses.replace(spec, create=create), dev)
    assert not ok and "needs 50 dB" in detail


def test_the_verdict_is_checked_once_and_kept_on_disk(dev, cache, monkeypatch):
    spec = methods.spec("bicubic")
    calls = []
    real = P.check
    monkeypatch.setattr(P, "check", lambda s, d: calls.append(1) or real(s, d))
    v = P.verdict(spec, dev)
    assert v.ok and v.name == "precision.bicubic" and calls == [1]
    P._memo.clear()
    selfcheck.forget()          # a new process: the disk has it
    assert P.verdict(spec, dev).ok and calls == [1]
    assert "precision.bicubic" in (cache / "selfcheck.json").read_text()


def test_a_check_that_raises_is_a_failed_verdict(dev, cache, monkeypatch):
    spec = methods.spec("bicubic")
    monkeypatch.setattr(P, "check", lambda s, d: 1 / 0)
    v = P.verdict(spec, dev)
    assert not v.ok and "ZeroDivisionError" in v.detail


def test_the_sequence_carries_every_g_buffer_a_method_reads():
    for name in methods.names():
        spec = methods.spec(name)
        frames = P.sequence(spec, P._scale(spec), frames=2)
        gb = frames[0][4]
        assert set(spec.gbuffers) <= set(gb), name
        assert all(np.isfinite(a).all() for a in gb.values())


def test_clss_verify_lists_what_auto_and_the_measured_fast_paths_choose(dev, monkeypatch):
    from clss.selfcheck_runner import load_registrations
    from clss.verify.conformance import format_device_choices
    load_registrations()
    text = format_device_choices(dev)
    assert "bicubic.fused8" in text and "default: measured on CPUs" in text and "fp32 on a CPU" in text

    monkeypatch.setattr(P, "verdict", lambda spec, d: selfcheck.Verdict(
        f"precision.{spec.name}", spec.name, "fp16", "gpu", spec.name != "nss", "checked"))
    text = format_device_choices(_Gpu())
    assert "not used (default: not measured on this class)" in text
    lines = {ln.split()[0]: ln.split()[1] for ln in text.splitlines() if ln.startswith("  ")}
    assert lines["bicubic"] == "fp16" and lines["nss"] == "fp32"


def test_a_gpu_measured_slower_in_fp16_keeps_fp32_without_a_check(monkeypatch, tmp_path):
    from clss import tuning
    monkeypatch.setenv("CLSS_TUNING_DB", str(tmp_path / "tuning.json"))

    spec = methods.spec("bicubic")
    ok = selfcheck.Verdict("precision.bicubic", "bicubic", "fp16", "gpu", True)
    monkeypatch.setattr(P, "verdict", lambda s, d: ok)
    assert P.resolve(spec, _Gpu(), "auto") == "fp16"
    tuning.store(_Gpu(), tuning.FP16_OP, "bicubic", {"use": False})
    monkeypatch.setattr(P, "verdict", lambda s, d: 1 / 0)      # not asked
    assert P.resolve(spec, _Gpu(), "auto") == "fp32"


def test_the_tuner_times_each_method_in_both_precisions_and_stores_the_choice(dev, cache, monkeypatch):
    import json
    from bench.tune_fastpaths import format_precisions, tune_precisions
    from clss import tuning
    db = cache / "tuning.json"
    monkeypatch.setenv("CLSS_TUNING_DB", str(db))
    (r,) = tune_precisions(dev, (16, 32), 2.0, runs=2, db=db, names=["bicubic"])
    assert r.fp32_ms > 0 and r.fp16_ms > 0 and r.use == (r.fp16_ms <= 0.95 * r.fp32_ms)
    stored = json.loads(db.read_text())["devices"][tuning.device_key(dev)][tuning.FP16_OP]["bicubic"]
    assert stored["params"] == {"use": r.use}
    assert "bicubic" in format_precisions([r])


def test_a_run_that_defers_self_checks_keeps_fp32_and_the_background_checks_fp16(dev, cache, monkeypatch):
    """Inside selfcheck.deferring() (clss upscale on a cold cache) the fp16 check is not run:
    the run keeps fp32 and the background checker (selfcheck_runner --deferred) checks it."""
    from clss.selfcheck_runner import load_registrations
    monkeypatch.delenv("CLSS_SELFCHECK", raising=False)
    load_registrations()
    spec = methods.spec("bicubic")
    spawned = []
    monkeypatch.setattr(selfcheck, "check_deferred", lambda: spawned.append(list(selfcheck._deferred)))
    with selfcheck.deferring():
        assert P.verdict(spec, dev) is None
    (items,) = spawned
    assert any(name == "precision.bicubic" for _, _, name in items)
    assert selfcheck.deferred_main([f"{i}:{p}:{n}" for i, p, n in items if n == "precision.bicubic"]) == 0
    selfcheck.forget()
    P._memo.clear()
    calls = []
    monkeypatch.setattr(P, "check", lambda s, d: calls.append(1) or (False, "not asked"))
    assert P.verdict(spec, dev).ok and not calls          # the background's verdict, from disk
