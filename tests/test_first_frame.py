"""The first frame on a cold cache (issue 52 part 4): fast-path self-checks deferred to a
background checker, so that the frame waits only for its own builds, and the progress
line shown while it builds."""
from __future__ import annotations

import io
import os
import time

import numpy as np
import pytest

from clss import selfcheck
from clss.device import get_device
from clss.progress import Waiting
from clss.tolerance import EXACT

NAME = "test.first_frame_dummy"


@pytest.fixture
def dummy(tmp_path, monkeypatch):
    """A registered fast path whose check counts its calls, and a cold cache directory."""
    monkeypatch.setenv("CLSS_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("CLSS_SELFCHECK", raising=False)
    calls = []

    def check(dev, prec):
        calls.append(prec)
        return [np.zeros(3, np.float32)]
    selfcheck.register(selfcheck.FastPath(NAME, "conv", {"CLSS_DUMMY": 1}, {"CLSS_DUMMY": 0},
                                          check=check, tolerance=lambda prec: EXACT,
                                          isolate=False))
    selfcheck.forget()
    yield calls
    selfcheck.REGISTRY.pop(NAME, None)
    selfcheck._deferred.clear()
    selfcheck.forget()


def test_deferred_check_runs_later(dummy, monkeypatch):
    dev = get_device()
    started = []
    monkeypatch.setattr(selfcheck, "check_deferred", lambda: started.append(dict(selfcheck._deferred)))
    with selfcheck.deferring():
        # no verdict on disk: the reference variant, no check in this process
        assert selfcheck.enabled(dev, "fp32", NAME) is False
        assert selfcheck.defines(dev, "fp32", NAME) == {"CLSS_DUMMY": 0}
    assert dummy == [] and len(started) == 1
    (index, prec, name), = started[0]
    assert (prec, name) == ("fp32", NAME)
    assert not selfcheck.cache_path().exists()
    # the background checker's work (a process of its own; here this one, forgetting its
    # choice first): the verdict lands on disk
    selfcheck.forget()
    assert selfcheck.deferred_main([f"{index}:{prec}:{name}"]) == 0
    assert dummy == ["fp32", "fp32"]        # the reference and the fast variant
    assert not selfcheck.cache_path().with_suffix(".lock").exists()
    selfcheck.forget()
    with selfcheck.deferring():             # the next run uses the fast variant, unchecked again
        assert selfcheck.enabled(dev, "fp32", NAME) is True
    assert dummy == ["fp32", "fp32"]


def test_explicit_mode_is_not_deferred(dummy, monkeypatch):
    """CLSS_SELFCHECK=auto (e.g. a run that must match a warm one bit for bit) checks at once."""
    monkeypatch.setenv("CLSS_SELFCHECK", "auto")
    with selfcheck.deferring():
        assert selfcheck.enabled(get_device(), "fp32", NAME) is True
    assert dummy == ["fp32", "fp32"] and not selfcheck._deferred


def test_one_checker_at_a_time(dummy):
    """A checker that finds the lock held by a live process leaves without checking."""
    lock = selfcheck.cache_path().with_suffix(".lock")
    lock.parent.mkdir(parents=True)
    lock.write_text(str(os.getpid()))
    assert selfcheck.deferred_main([f"0:fp32:{NAME}"]) == 0
    assert dummy == [] and lock.exists()
    lock.write_text("999999999")            # a checker that died: its lock is taken over
    assert selfcheck.deferred_main([f"0:fp32:{NAME}"]) == 0
    assert dummy == ["fp32", "fp32"] and not lock.exists()


def test_waiting_line():
    out = io.StringIO()
    n = [0]

    def status():
        n[0] += 1
        return f"building: {n[0]} programs"
    w = Waiting(status, file=out, interval=0.02)
    time.sleep(0.2)
    w.done("first frame in 0.2 s")
    lines = out.getvalue().splitlines()
    assert lines[0] == "building: 1 programs" and lines[-1] == "first frame in 0.2 s"
    w.done("again")                         # once only
    assert out.getvalue().splitlines()[-1] == "first frame in 0.2 s"
