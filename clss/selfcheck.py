"""Fast paths that check themselves.

A fast path is a build variant of one kernel source (``-D`` options) that is
faster on some compilers (vector de-interleaves, builtin-free loads, several
pixels per work-item) and has a portable reference variant on the same source.
Compilers miscompile fast paths (PoCL 3.0-rc2 on AVX-512 returned garbage from
``uint16.even``), so before the engine first uses a fast variant on a (device,
driver, kernel source, build options), it runs the op once on a small seeded
input with the fast and with the reference variant and compares the two:
bit-exact for data movement, the op's tolerance otherwise. A variant that
disagrees (or fails to build) is disabled with one warning naming the kernel,
the variant and the device, and the op uses the reference variant.

Verdicts are kept on disk (selfcheck.json in clss's cache directory, `clss.cachedir`:
$CLSS_CACHE_DIR, else $XDG_CACHE_HOME/clss, default ~/.cache/clss, on Linux), keyed like
the program cache: device, driver, hash of the kernel source, build options.
``CLSS_SELFCHECK`` chooses:

    auto   (default) check once, then trust the cached verdict
    force  check again in this process, whatever is cached
    skip   no check: fast variants are used as they are
    defer  a variant with no cached verdict is not used in this process (its reference
           variant is, unchecked, as it needs no check) and is checked afterwards in one
           background process, so the next run has its verdict

`clss upscale` runs inside `deferring()`, which defers as `defer` does while
CLSS_SELFCHECK is unset: its first frame on a cold cache waits for no self-check (they
spawn a chain of child processes and cost a minute or more on 2 cores), only for the
builds that frame needs. Within one process the choice, once made, stays: every frame
of a run uses the same variants.

Ops ask with ``defines(dev, prec, name)`` (or ``enabled``) and size their
launches from the answer, since a variant may change the work per work-item.
Each op module registers its fast paths with ``register(FastPath(...))``.
"""
from __future__ import annotations

import datetime
import hashlib
import json
import os
import threading
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .cachedir import cache_dir, read_json, update_json
from .device import kernel_label

MODES = ("auto", "force", "skip", "defer")


class FastPathDisabled(UserWarning):
    """A fast variant disagreed with its reference on this device and is not used."""


@dataclass(frozen=True)
class FastPath:
    """One fast variant of a kernel source and its portable reference. ``kernel`` is the
    source as clss.device takes it: a stem of kernels/ ("conv") or the path of a room's
    own .cl file; its file name without .cl is the family `check_all` filters by.

    ``check(dev, prec) -> list of host arrays`` runs the op on a small seeded
    input; the registry calls it once with the fast and once with the reference
    variant forced. ``tolerance(prec)`` is EXACT for data movement, else the op's
    Tolerance (clss/tolerance.py), or a list of those, one per output."""
    name: str
    kernel: str | os.PathLike
    fast: dict
    reference: dict
    check: Callable = field(compare=False)
    tolerance: Callable = field(compare=False)
    what: str = ""
    isolate: bool = True     # check in a child process (see _check_isolated)
    # Does the op use the fast variant on dev at all? A speed choice measured per kind of
    # device (a CPU layout that a GPU runs slower, a PoCL-only load form): where it does
    # not apply, enabled() is False without a check and the reference variant runs.
    applies: Callable = field(default=lambda dev: True, compare=False)
    # A speed choice (fused stages, a CPU load form) that a device's measurement overrides:
    # clss tune times the frame steps that use it with and without it and stores the
    # faster (clss.tuning.measured_choice); `applies` answers where nothing was measured.
    measured: bool = False
    # Further kernel sources the fast variant runs (stems or paths, as ``kernel``): their text
    # is part of the verdict's key too, so that a change to any of them checks it again.
    sources: tuple = ()

    def applies_on(self, dev) -> bool:
        """Whether the op uses the fast variant on dev at all (before any self-check)."""
        if self.measured:
            from .tuning import FAST_PATH_OP, measured_choice
            use = measured_choice(dev, FAST_PATH_OP, self.name)
            if use is not None:
                return use
        return bool(self.applies(dev))

    @property
    def family(self) -> str:
        """The source's file name without .cl ("conv"): what `clss verify --family` takes."""
        return Path(self.kernel).stem

    def options(self, fast: bool) -> str:
        d = self.fast if fast else self.reference
        return " ".join(f"-D{k}={v}" for k, v in sorted(d.items()))


@dataclass
class Verdict:
    name: str
    kernel: str
    precision: str
    device: str
    ok: bool
    detail: str = ""
    options: str = ""
    checked: str = ""

    def as_dict(self) -> dict:
        return dict(self.__dict__)


REGISTRY: dict[str, FastPath] = {}
_lock = threading.RLock()
_local = threading.local()          # .forced: {name: bool} while a check runs a variant
_verdicts: dict[tuple, Verdict] = {}   # (device key, name, options) -> verdict, this process
_checked_here: set = set()          # keys checked in this process (CLSS_SELFCHECK=force)
_warned: set = set()
_memo: dict = {}                    # (device id, prec, name, mode, extra options) -> ok
_defer_depth = 0                    # deferring() blocks open
_deferred: dict = {}                # (device index, prec, name) -> None: to check afterwards


def register(fp: FastPath) -> FastPath:
    REGISTRY[fp.name] = fp
    return fp


def mode() -> str:
    m = os.environ.get("CLSS_SELFCHECK", "auto").strip().lower() or "auto"
    if m not in MODES:
        raise ValueError(f"CLSS_SELFCHECK={m!r}: expected one of {', '.join(MODES)}")
    return m


def cache_path() -> Path:
    return cache_dir() / "selfcheck.json"


@contextmanager
def forcing(name: str, fast: bool):
    """Inside the block, variant `name` is used (fast) or not (reference), unchecked."""
    forced = _forced()
    old = forced.get(name)
    forced[name] = fast
    try:
        yield
    finally:
        if old is None:
            forced.pop(name, None)
        else:
            forced[name] = old


def _forced() -> dict:
    """{name: fast?} of the variants a running check forces in this thread; a check's
    child process inherits its parent's ($CLSS_SELFCHECK_FORCED, "name=0,name=1"), so a
    variant another variant's check uses is not checked again in a loop of processes."""
    forced = getattr(_local, "forced", None)
    if forced is None:
        inherited = os.environ.get("CLSS_SELFCHECK_FORCED", "")
        forced = _local.forced = {k: v == "1" for k, _, v in
                                  (item.partition("=") for item in inherited.split(",") if item)}
    return forced


def defines(dev, prec: str, name: str) -> dict:
    """The -D options for variant `name`: its fast ones when they are enabled on
    dev in prec, else the reference ones."""
    fp = REGISTRY[name]
    return dict(fp.fast if enabled(dev, prec, name) else fp.reference)


def enabled(dev, prec: str, name: str) -> bool:
    """Whether the fast variant `name` may be used on dev in prec (checking it first if
    no verdict is known)."""
    if _asked is not None:
        _asked.add(name)
    forced = _forced()
    if name in forced:
        return forced[name]
    # The real device: a model's dry run hands its ops a PlannedDevice whose launches do nothing.
    dev = getattr(dev, "base", dev)
    m = mode()
    memo = (id(dev), prec, name, m, os.environ.get("CLSS_BUILD_OPTIONS", ""))
    ok = _memo.get(memo)
    if ok is not None:       # ops ask at every launch: no source hashing after the first
        return ok
    fp = REGISTRY[name]
    if m == "skip" or not fp.applies_on(dev):     # skip: used unchecked where it applies
        _memo[memo] = fp.applies_on(dev)
        return _memo[memo]
    v = verdict(dev, prec, name, _mode=m)
    _memo[memo] = bool(v and v.ok)
    return _memo[memo]


def verdict(dev, prec: str, name: str, *, _mode: str | None = None) -> Verdict | None:
    """The self-check verdict of fast path `name` on dev in prec, whether or not it applies
    there (a tuner asks before it measures a variant the device does not use yet): cached,
    else checked now; None when deferred (mode defer, or inside `deferring()`)."""
    dev = getattr(dev, "base", dev)
    m = _mode or mode()
    fp = REGISTRY[name]
    key = _key(dev, prec, fp)
    with _lock:
        v = _verdicts.get(key)
        if v is None or (m == "force" and key not in _checked_here):
            rec = None if m == "force" else _load().get(_disk_key(key))
            try:
                v = Verdict(**rec) if isinstance(rec, dict) else None
            except TypeError:   # a record of another clss version: check again
                v = None
            if v is None and _defers(m):     # the reference variant, unchecked, this process
                _deferred[(_device_index(dev), prec, name)] = None
                return None
            if v is None:
                v = _check_isolated(dev, prec, fp) if fp.isolate else _run_check(dev, prec, fp)
                _checked_here.add(key)
                _store(_disk_key(key), v)
            _verdicts[key] = v
        if not v.ok and key not in _warned:
            _warned.add(key)
            warnings.warn(f"fast path {fp.name} ({fp.options(True)}) of {kernel_label(fp.kernel)} disabled "
                          f"on {v.device} [{prec}]: {v.detail}; using the reference variant "
                          f"({fp.options(False)})", FastPathDisabled, stacklevel=4)
        return v


# Checks that are not build variants, by the prefix of their names ("precision"): what the
# background checker (deferred_main) calls for a deferred one, handler(dev, prec, name).
# clss.selfcheck_runner, above every room, registers them.
DEFERRED_CHECKS: dict = {}


def remembered(dev, name: str, family: str, prec: str, digest: str, options: str, compute,
               defer: bool = False) -> Verdict | None:
    """A check that is not a build variant (precision="auto"'s fp16 check of a method) kept
    like the fast paths' verdicts: the stored one for (device, name, digest, options), else
    compute() -> (ok, detail), stored; a check that raises is a failed verdict. defer=True:
    None where a fast path's check would be deferred (the background checker then runs it
    through DEFERRED_CHECKS by its name's prefix)."""
    dev = getattr(dev, "base", dev)
    key = (_device_name(dev), name, digest, options)
    with _lock:
        v = _verdicts.get(key)
        if v is None:
            rec = _load().get(_disk_key(key))
            try:
                v = Verdict(**rec) if isinstance(rec, dict) else None
            except TypeError:   # a record of another clss version: check again
                v = None
        if v is None and defer and _defers(mode()):
            _deferred[(_device_index(dev), prec, name)] = None
            return None
        if v is None:
            now = datetime.datetime.now().isoformat(timespec="seconds")
            try:
                ok, detail = compute()
            except Exception as e:
                ok, detail = False, f"fails: {type(e).__name__}: {str(e).splitlines()[0][:200]}"
            v = Verdict(name, family, prec, _device_name(dev), bool(ok), detail, options, now)
            _store(_disk_key(key), v)
        _verdicts[key] = v
        return v


_asked: set | None = None           # names asked by enabled() inside asking()


@contextmanager
def asking():
    """Inside the block, the names of the fast paths ops ask about (enabled(), defines()) are
    collected into the set it yields: what a frame step uses, for clss tune's fast-path step."""
    global _asked
    old, _asked = _asked, set()
    try:
        yield _asked
    finally:
        asked, _asked = _asked, old
        if old is not None:
            old |= asked


@contextmanager
def deferring():
    """Inside the block (when CLSS_SELFCHECK is unset), a fast path with no cached verdict
    is deferred as mode `defer` does; when the outermost block ends, the deferred ones are
    checked in one background process (`check_deferred`)."""
    global _defer_depth
    _defer_depth += 1
    try:
        yield
    finally:
        _defer_depth -= 1
        if not _defer_depth:
            check_deferred()


def _defers(m: str) -> bool:
    return m == "defer" or (m == "auto" and _defer_depth > 0
                            and not os.environ.get("CLSS_SELFCHECK", "").strip())


def check_deferred():
    """Start one detached, low-priority process (`python -m clss.selfcheck_runner
    --deferred`) that checks the variants deferred so far and stores their verdicts;
    returns it (None when nothing was deferred). It checks as mode `auto` does, each
    variant in its own child, and holds a lock in the cache directory, so that runs
    started together start one checker, not one each."""
    import subprocess
    import sys
    todo = list(_deferred)
    _deferred.clear()
    if not todo:
        return None
    args = [f"{i}:{prec}:{name}" for i, prec, name in todo]
    return subprocess.Popen([sys.executable, "-m", "clss.selfcheck_runner", "--deferred", *args],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True,
                            env=dict(os.environ, CLSS_SELFCHECK="auto"))


def deferred_main(items) -> int:
    """The background checker (`--deferred INDEX:PREC:NAME ...`, run at the lowest
    priority): the lock's holder checks each variant that still has no verdict; another
    checker already running means this one leaves (the next run defers and starts one)."""
    from .device import get_device
    lock = cache_path().with_suffix(".lock")
    if not _take_lock(lock):
        return 0
    try:
        for item in items:
            index, prec, name = item.split(":", 2)
            if name in REGISTRY:
                enabled(get_device(index), prec, name)
            elif name.partition(".")[0] in DEFERRED_CHECKS:
                DEFERRED_CHECKS[name.partition(".")[0]](get_device(index), prec, name)
    finally:
        lock.unlink(missing_ok=True)
    return 0


def _take_lock(lock: Path) -> bool:
    """Create `lock` holding this pid; a lock whose process is gone is taken over once."""
    for _ in range(2):
        try:
            lock.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                os.kill(int(lock.read_text().strip() or 0), 0)
                return False            # a live checker holds it
            except (ValueError, OSError):
                lock.unlink(missing_ok=True)
                continue
        except OSError:
            return False
        with os.fdopen(fd, "w") as fh:
            fh.write(str(os.getpid()))
        return True
    return False


def check_all(dev, precisions, kernels=None) -> list[Verdict]:
    """Verdicts of every registered fast path on dev (of `kernels`, the families of
    their sources (FastPath.family), if given), checking what is not yet known. Only the variants
    registered so far: clss.selfcheck_runner.check_all imports every registering
    module first."""
    dev = getattr(dev, "base", dev)
    out = []
    for name in sorted(REGISTRY):
        if (kernels is not None and REGISTRY[name].family not in kernels) or not REGISTRY[name].applies_on(dev):
            continue
        for prec in precisions:
            if prec == "fp16-native" and not dev.has_fp16:
                continue
            enabled(dev, prec, name)
            out.append(_verdicts.get(_key(dev, prec, REGISTRY[name])) or Verdict(
                name, REGISTRY[name].family, prec, _device_name(dev), True, "not checked (CLSS_SELFCHECK=skip)"))
    return out


def disabled(dev=None) -> list[Verdict]:
    """The variants disabled in this process (on dev, if given)."""
    name = None if dev is None else _device_name(dev)
    return [v for v in _verdicts.values() if not v.ok and (name is None or v.device == name)]


def forget() -> None:
    """Drop this process's verdicts (the disk cache stays): the next use checks or reloads."""
    with _lock:
        for d in (_verdicts, _memo):
            d.clear()
        _checked_here.clear()
        _warned.clear()


# --- internals -------------------------------------------------------------------

def _device_index(dev) -> int:
    """The device's index in clss.device.list_devices(), as a child process names it."""
    from .device import list_devices
    return next(i for i, (_, d) in enumerate(list_devices()) if d == dev.cl_device)


def _device_name(dev) -> str:
    return f"{dev.info.platform} / {dev.info.name} ({dev.info.driver})"


def _key(dev, prec: str, fp: FastPath) -> tuple:
    """(device, driver, source hash, build options of the fast variant): as the program cache."""
    src = "".join(dev.source(k) for k in (fp.kernel,) + tuple(fp.sources))
    opts = dev.build_options(prec, **fp.fast)
    return (_device_name(dev), fp.name, hashlib.sha1(src.encode()).hexdigest()[:16], opts)


def _disk_key(key: tuple) -> str:
    return " | ".join(key)


def _run_check(dev, prec: str, fp: FastPath) -> Verdict:
    from .tolerance import compare
    now = datetime.datetime.now().isoformat(timespec="seconds")
    v = Verdict(fp.name, fp.family, prec, _device_name(dev), True, "", fp.options(True), now)
    with forcing(fp.name, False):
        ref = fp.check(dev, prec)      # a reference that fails is the op's own error: raised
    try:
        with forcing(fp.name, True):
            out = fp.check(dev, prec)
    except Exception as e:  # the fast variant does not build or run here: disable it
        v.ok, v.detail = False, f"fails: {type(e).__name__}: {str(e).splitlines()[0][:200]}"
        return v
    tols = fp.tolerance(prec)    # one for every output, or a list, one per output
    for i, (o, r) in enumerate(zip(out, ref)):
        c = compare(np.asarray(o), np.asarray(r), tols[i] if isinstance(tols, list) else tols)
        if not c.passed:
            v.ok = False
            v.detail = f"differs from the reference variant (output {i}: {c.detail or c.tol})"
            break
    if len(out) != len(ref):
        v.ok, v.detail = False, f"{len(out)} outputs, the reference variant {len(ref)}"
    return v


def _check_isolated(dev, prec: str, fp: FastPath) -> Verdict:
    """_run_check in a child process (`python -m clss.selfcheck_runner`): a miscompiled fast
    variant can crash the process rather than give wrong numbers (Debian's PoCL 3.1
    segfaults in pool.cl's 8-lane fp16 global max), and a crash must cost the variant,
    not the caller. The child prints its verdict as JSON on its last line."""
    import subprocess
    index = _device_index(dev)
    now = datetime.datetime.now().isoformat(timespec="seconds")
    try:
        env = dict(os.environ, CLSS_SELFCHECK_FORCED=",".join(
            f"{k}={int(v)}" for k, v in sorted(_forced().items())))
        r = subprocess.run(_child_command(index, prec, fp.name), capture_output=True, text=True,
                           timeout=_CHILD_TIMEOUT_S, env=env)
        last = r.stdout.strip().splitlines()[-1] if r.stdout.strip() else ""
        if r.returncode == 0 and last.startswith("{"):
            return Verdict(**json.loads(last))
        err = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
        why = (f"signal {-r.returncode}" if r.returncode < 0 else f"exit status {r.returncode}")
        detail = f"its self-check process died ({why})" + (f": {err[-1][:200]}" if err else "")
    except subprocess.TimeoutExpired:
        detail = f"its self-check process did not finish in {_CHILD_TIMEOUT_S} s"
    return Verdict(fp.name, fp.family, prec, _device_name(dev), False, detail, fp.options(True), now)


_CHILD_TIMEOUT_S = 600


def _child_command(index: int, prec: str, name: str) -> list[str]:
    import sys
    return [sys.executable, "-m", "clss.selfcheck_runner", str(index), prec, name]


def _child_main(argv) -> int:
    """DEVICE_INDEX PRECISION NAME: check one variant here (the child process, run as
    `python -m clss.selfcheck_runner`, which has imported every registration)."""
    from .device import get_device
    index, prec, name = argv
    v = _run_check(get_device(index), prec, REGISTRY[name])
    print(json.dumps(v.as_dict()))
    return 0


def _load() -> dict:
    data = read_json(cache_path())
    return data if isinstance(data, dict) else {}


def _store(key: str, v: Verdict) -> None:
    """Merge one verdict into the file: read, merged and replaced whole behind the file's
    lock (clss.cachedir.update_json), so that processes storing verdicts at once all keep
    theirs; an unwritable cache only costs a re-check."""
    def merge(data):
        data = data if isinstance(data, dict) else {}
        data[key] = v.as_dict()
        return data
    try:
        update_json(cache_path(), merge, indent=1, sort_keys=True)
    except OSError:
        pass

