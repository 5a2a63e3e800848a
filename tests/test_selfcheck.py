"""The fast-path self-check (clss/selfcheck.py): a wrong fast variant is refused
with one warning and the op falls back to its reference variant, results right."""
import dataclasses
import json
import sys
import warnings

import numpy as np
import pytest

from clss import selfcheck
from clss.ops import space_to_depth as s2d

S2D = "space_to_depth.b2_vector_loads"


def _s2d_numpy(x, b):
    """DCR SpaceToDepth in numpy: the expected bits."""
    n, c, hh, ww = x.shape
    t = x.reshape(n, c, hh // b, b, ww // b, b).transpose(0, 3, 5, 1, 2, 4)
    return t.reshape(n, b * b * c, hh // b, ww // b)


@pytest.fixture
def fresh(tmp_path, monkeypatch):
    """An empty verdict cache and no verdicts in this process (before and after)."""
    monkeypatch.setenv("CLSS_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("CLSS_SELFCHECK", raising=False)
    selfcheck.forget()
    yield tmp_path
    selfcheck.forget()


@pytest.fixture
def broken_s2d(monkeypatch):
    """The space_to_depth fast path replaced by its deliberately wrong build
    (-DS2D_VEC=2 swaps the two output runs), checked in this process."""
    fp = selfcheck.REGISTRY[S2D]
    monkeypatch.setitem(selfcheck.REGISTRY, S2D, dataclasses.replace(fp, fast={"S2D_VEC": 2}, isolate=False))


def test_wrong_fast_variant_is_refused_and_the_reference_used(dev, fresh, broken_s2d):
    x = np.random.default_rng(7).standard_normal((1, 3, 6, 34)).astype(np.float32)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(3):   # one warning, however often the op runs
            y = s2d.space_to_depth(dev, "fp32", dev.to_device(x), 2).get()
            assert np.array_equal(y.view(np.uint32), _s2d_numpy(x, 2).view(np.uint32))
    mine = [w for w in caught if issubclass(w.category, selfcheck.FastPathDisabled)]
    assert len(mine) == 1, [str(w.message) for w in caught]
    msg = str(mine[0].message)
    assert S2D in msg and "kernels/space_to_depth.cl" in msg and dev.info.name in msg
    assert [v.name for v in selfcheck.disabled(dev)] == [S2D]
    # the verdict is on disk, keyed by device, driver, source hash and options
    (key, rec), = json.loads((fresh / "selfcheck.json").read_text()).items()
    assert rec["ok"] is False and dev.info.driver in key and "-DS2D_VEC=2" in key
    # a new process (forget) reads it back without checking again, and warns once more
    selfcheck.forget()
    monkeypatch_check = []
    fp = selfcheck.REGISTRY[S2D]
    selfcheck.REGISTRY[S2D] = dataclasses.replace(fp, check=lambda *a: monkeypatch_check.append(a) or [])
    try:
        with pytest.warns(selfcheck.FastPathDisabled):
            assert selfcheck.defines(dev, "fp32", S2D) == {"S2D_VEC": 0}
    finally:
        selfcheck.REGISTRY[S2D] = fp
    assert monkeypatch_check == []


def test_force_rechecks_and_skip_trusts(dev, fresh, broken_s2d, monkeypatch):
    with pytest.warns(selfcheck.FastPathDisabled):
        assert not selfcheck.enabled(dev, "fp32", S2D)
    monkeypatch.setenv("CLSS_SELFCHECK", "skip")
    assert selfcheck.enabled(dev, "fp32", S2D)       # unchecked: the broken build is used
    monkeypatch.setenv("CLSS_SELFCHECK", "force")   # a new process: checks despite the disk verdict
    selfcheck.forget()
    calls = []
    fp = selfcheck.REGISTRY[S2D]
    monkeypatch.setitem(selfcheck.REGISTRY, S2D, dataclasses.replace(
        fp, check=lambda d, p: calls.append(1) or fp.check(d, p)))
    with pytest.warns(selfcheck.FastPathDisabled):
        assert not selfcheck.enabled(dev, "fp32", S2D)
    assert len(calls) == 2                            # fast and reference, run again
    monkeypatch.setenv("CLSS_SELFCHECK", "sometimes")
    with pytest.raises(ValueError, match="CLSS_SELFCHECK='sometimes'"):
        selfcheck.enabled(dev, "fp32", S2D)


def test_a_check_that_crashes_disables_the_variant(dev, fresh, monkeypatch):
    # A miscompile can kill the process (Debian's PoCL 3.1 segfaults in pool.cl's
    # 8-lane fp16 global max): the check runs in a child, and its death costs only the variant.
    monkeypatch.setattr(selfcheck, "_child_command",
                        lambda *a: [sys.executable, "-c", "import os; os.abort()"])
    with pytest.warns(selfcheck.FastPathDisabled, match="self-check process died \\(signal 6\\)"):
        assert selfcheck.defines(dev, "fp16", S2D) == {"S2D_VEC": 0}


def test_real_variant_checked_in_a_child_process(dev, fresh):
    with warnings.catch_warnings():
        warnings.simplefilter("error", selfcheck.FastPathDisabled)
        assert selfcheck.enabled(dev, "fp32", S2D)
    (rec,) = json.loads((fresh / "selfcheck.json").read_text()).values()
    assert rec["ok"] is True and rec["name"] == S2D


@pytest.mark.parametrize("mode", ["auto", "force", "skip"])
def test_fast_path_that_does_not_apply_is_off_unchecked(dev, fresh, monkeypatch, mode):
    """A fast path whose `applies(dev)` is False (a CPU layout on a GPU, say) is off on that
    device in every mode, without running its check; CLSS_SELFCHECK_FORCED still wins."""
    monkeypatch.setenv("CLSS_SELFCHECK", mode)
    calls = []
    fp = selfcheck.REGISTRY[S2D]
    monkeypatch.setitem(selfcheck.REGISTRY, S2D, dataclasses.replace(
        fp, applies=lambda d: False, check=lambda *a: calls.append(a) or [], isolate=False))
    assert selfcheck.enabled(dev, "fp32", S2D) is False
    assert selfcheck.defines(dev, "fp32", S2D) == fp.reference and calls == []
