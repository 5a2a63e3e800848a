"""Several processes sharing clss's caches at once (issue 52 part 3: three `clss upscale
--method nsrr` started together on a cold cache, one failed with "kernels/conv.cl failed to
build" and a traceback).

- clss.cachedir: files written whole (temp file + rename), read-modify-writes behind a lock,
  the lock degrading to none where it cannot be taken;
- selfcheck.json and tuning.json: processes storing entries at once keep every entry;
- kernel builds of one program take turns across processes (clss.device: PoCL 3.0/3.1's
  kcache fails two writers of one entry);
- a build that fails even around the caches is one line on the command line;
- the stress test: N `clss upscale` processes on a cold cache (fresh CLSS_CACHE_DIR,
  XDG_CACHE_HOME and POCL_CACHE_DIR), repeated, every frame written and bit-identical to a
  serial run. The default run is 3 processes x 2 repeats of `--method nss` (its U-Net
  builds conv.cl), about a minute on 2 busy cores; `make stress` runs more
  (CLSS_STRESS_PROCS, CLSS_STRESS_REPEATS, CLSS_STRESS_METHODS).
"""
from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from clss import cachedir, selfcheck, tuning
from clss.cachedir import locked, update_json, write_atomic

STRESS_PROCS = int(os.environ.get("CLSS_STRESS_PROCS", "3"))
STRESS_REPEATS = int(os.environ.get("CLSS_STRESS_REPEATS", "2"))
STRESS_METHODS = os.environ.get("CLSS_STRESS_METHODS", "nss").split(",")


# --- clss.cachedir ---------------------------------------------------------------------

def test_write_atomic_replaces_whole_with_a_plain_files_mode(tmp_path):
    p = tmp_path / "sub" / "x.json"
    write_atomic(p, "one")
    write_atomic(p, b"two")
    assert p.read_text() == "two"
    mask = os.umask(0o022)
    os.umask(mask)
    assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~mask      # not mkstemp's 0600
    assert [q.name for q in p.parent.iterdir()] == ["x.json"]     # no temporary left


def test_write_atomic_leaves_the_old_file_when_writing_fails(tmp_path, monkeypatch):
    p = tmp_path / "x.json"
    write_atomic(p, "old")

    def broken(*a):
        raise OSError("disk full")
    monkeypatch.setattr(os, "replace", broken)
    with pytest.raises(OSError, match="disk full"):
        write_atomic(p, "new")
    assert p.read_text() == "old" and [q.name for q in tmp_path.iterdir()] == ["x.json"]


def test_locked_excludes_another_holder_and_times_out(tmp_path):
    p = tmp_path / "db.json"
    with locked(p) as held:
        assert held and cachedir.lock_path(p).exists()
        t = time.monotonic()
        with locked(p, timeout=0.2) as second:      # another open file: flock excludes it
            assert not second
        assert time.monotonic() - t >= 0.2
    with locked(p, timeout=0) as again:             # released on leaving the block
        assert again


def test_locked_degrades_to_no_lock(tmp_path, monkeypatch):
    # no fcntl (Windows): the block still runs, unlocked
    monkeypatch.setitem(sys.modules, "fcntl", None)
    with locked(tmp_path / "a.json") as held:
        assert held is False
    monkeypatch.undo()
    # a cache directory that cannot be created (a file stands where it should be)
    (tmp_path / "file").write_text("")
    with locked(tmp_path / "file" / "a.json") as held:
        assert held is False


def test_update_json_starts_afresh_from_an_unreadable_file(tmp_path):
    p = tmp_path / "t.json"
    p.write_text("{half a fi")
    assert update_json(p, lambda d: {"was": d}) == {"was": None}
    assert json.loads(p.read_text()) == {"was": None}


# --- selfcheck.json and tuning.json from several processes --------------------------------

_WRITER = textwrap.dedent("""
    import sys, time
    from clss import selfcheck, tuning
    who, n, start = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    while time.time() < start:
        time.sleep(0.001)
    for i in range(n):
        selfcheck._store(f"{who}-{i}", selfcheck.Verdict(f"fp{i}", "conv", "fp32", who, True))
        tuning.store(f"dev-{who}", "conv2d", f"k{i}", {"TILE": i})
""")


def test_processes_storing_at_once_keep_every_entry(tmp_path):
    """4 processes store 30 verdicts and 30 tuning entries each into one cache at the same
    moment (before the lock, each read-modify-write lost the entries stored between its
    read and its rename); a reader meanwhile always finds whole JSON."""
    env = dict(os.environ, CLSS_CACHE_DIR=str(tmp_path))
    env.pop("CLSS_TUNING_DB", None)
    start, n, who = time.time() + 2.0, 30, ["a", "b", "c", "d"]
    procs = [subprocess.Popen([sys.executable, "-c", _WRITER, w, str(n), str(start)], env=env)
             for w in who]
    torn = []
    while any(p.poll() is None for p in procs):     # read while they write
        for name in ("selfcheck.json", "tuning.json"):
            text = (tmp_path / name).read_text() if (tmp_path / name).exists() else "{}"
            try:
                json.loads(text)
            except ValueError:
                torn.append(name)
        time.sleep(0.002)
    assert [p.wait() for p in procs] == [0] * len(who)
    assert not torn, f"a reader saw a half-written file: {torn[:3]}"
    verdicts = json.loads((tmp_path / "selfcheck.json").read_text())
    assert sorted(verdicts) == sorted(f"{w}-{i}" for w in who for i in range(n))
    devices = json.loads((tmp_path / "tuning.json").read_text())["devices"]
    assert {d: len(e["conv2d"]) for d, e in devices.items()} == {f"dev-{w}": n for w in who}
    assert not [q.name for q in tmp_path.iterdir() if q.name.endswith(".tmp")]


def test_the_writers_use_the_cache_lock(tmp_path, monkeypatch):
    """selfcheck._store and tuning.store wait for the file's lock (here held by the test)."""
    monkeypatch.setenv("CLSS_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("CLSS_TUNING_DB", raising=False)
    for path, store in ((selfcheck.cache_path(),
                         lambda: selfcheck._store("k", selfcheck.Verdict("fp", "conv", "fp32", "d", True))),
                        (tuning.db_path(), lambda: tuning.store("d", "op", "k", {"X": 1}))):
        with locked(path):
            t = threading.Thread(target=store)
            t.start()
            t.join(0.5)
            assert t.is_alive() and not path.exists(), f"{path.name} written past its lock"
        t.join(10)
        assert path.exists()


# --- kernel builds ----------------------------------------------------------------------------

def test_builds_of_one_program_take_turns(dev, tmp_path, monkeypatch):
    """A build holds its program's lock (a stripe in the cache's locks/): a second builder of
    the same program, here another thread with the lock held by the test, waits for it."""
    from clss.device import Device
    monkeypatch.setenv("CLSS_CACHE_DIR", str(tmp_path))
    src = tmp_path / "tiny.cl"
    src.write_text(f"__kernel void f(__global float *a) {{ a[0] = {time.time_ns() % 997}; }}\n")
    fresh = Device(dev.cl_device)
    lock = fresh._build_lock(Device.source(src), Device.build_options("fp32"))
    assert lock.parent == tmp_path / "locks"
    with locked(lock):
        t = threading.Thread(target=fresh.program, args=(src,))
        t.start()
        t.join(1.5)
        assert t.is_alive() and fresh.builds == 0, "built while another builder held the lock"
    t.join(60)
    assert fresh.builds == 1


def test_a_build_that_fails_around_the_caches_is_one_line(dev, tmp_path, monkeypatch, capsys):
    """`clss upscale` and every other command print a real build failure as one line: the
    kernel, the device, the compiler's first error and where the whole log is; no traceback."""
    from clss import device as D
    from clss.cli.main import run_command
    monkeypatch.setenv("CLSS_CACHE_DIR", str(tmp_path / "cache"))
    (tmp_path / "broken.cl").write_text("__kernel void f(__global float *x) { x[0] = undefined_thing; }\n")

    def command(argv):
        D.Device(dev.cl_device).kernel(tmp_path / "broken.cl", "f", "fp32")
    assert run_command("clss upscale", command, []) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "broken.cl failed to build on" in err and "undefined_thing" in err
    log = Path(err.split("(the whole log: ")[1].rstrip().rstrip(")"))
    assert log.parent == tmp_path / "cache" / "build-logs" and "undefined_thing" in log.read_text()


# --- the stress test ------------------------------------------------------------------------

def _reference_variants() -> str:
    """CLSS_SELFCHECK_FORCED naming every fast path's reference variant: the runs then
    choose alike whatever each cache holds, and start no self-check processes."""
    from clss import selfcheck_runner
    selfcheck_runner.load_registrations()
    return ",".join(f"{name}=0" for name in sorted(selfcheck.REGISTRY))


def _env(root: Path | None, forced: str) -> dict:
    """The environment of one run: every cache under `root` (cold), or the user's own
    PoCL cache with a fresh clss cache (root None: the serial run)."""
    env = dict(os.environ, CLSS_SELFCHECK_FORCED=forced)
    for var in ("CLSS_CACHE_DIR", "XDG_CACHE_HOME", "POCL_CACHE_DIR", "CLSS_TUNING_DB", "CLSS_SELFCHECK"):
        env.pop(var, None)
    if root is not None:
        env.update(CLSS_CACHE_DIR=str(root / "clss"), XDG_CACHE_HOME=str(root / "xdg"),
                   POCL_CACHE_DIR=str(root / "pocl"))
    return env


def _upscale(seq: Path, out: Path, method: str, env: dict) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "clss", "upscale", "--method", method, str(seq),
                             "-o", str(out)], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _frames(out: Path) -> dict:
    from clss.io import read_exr
    return {p.name: read_exr(p)[0] for p in sorted(out.glob("frame.*.exr"))}


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    from clss.demo.scene import render_sequence
    from clss.io import write_sample_sequence
    seq = tmp_path_factory.mktemp("stress") / "seq"
    write_sample_sequence(render_sequence(3, (16, 24), 2.0, spp_ref=0), seq)
    return seq


@pytest.mark.parametrize("method", STRESS_METHODS)
def test_processes_on_a_cold_cache_write_every_frame_bit_identical(method, sequence, tmp_path):
    forced = _reference_variants()
    serial = _upscale(sequence, tmp_path / "serial", method, _env(None, forced))
    _, err = serial.communicate(timeout=600)
    assert serial.returncode == 0, err
    want = _frames(tmp_path / "serial")
    assert len(want) == 3
    failures = []
    for r in range(STRESS_REPEATS):
        root = tmp_path / f"repeat{r}"
        procs = [_upscale(sequence, root / f"out{i}", method, _env(root, forced))
                 for i in range(STRESS_PROCS)]
        for i, p in enumerate(procs):
            _, err = p.communicate(timeout=900)
            got = _frames(root / f"out{i}") if p.returncode == 0 else {}
            if p.returncode or "Traceback" in err or got.keys() != want.keys() or any(
                    not np.array_equal(got[k], want[k]) for k in want):
                failures.append(f"repeat {r} process {i}: status {p.returncode}, "
                                f"{sorted(got)} written; {err.strip()[-400:]}")
    print(f"stress {method}: {STRESS_PROCS} processes x {STRESS_REPEATS} repeats, "
          f"{len(failures)} failed")
    assert not failures, "\n".join(failures)
