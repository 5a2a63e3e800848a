"""Where clss keeps what it caches between runs, and how it writes there safely when several
processes share it (issue 52: three `clss upscale` started together on a cold cache).

What lives there: the fast-path self-check verdicts (clss.selfcheck, selfcheck.json), the
tuning database (clss.tuning, tuning.json), the build logs of failed kernel builds
(build-logs/) and the lock files of kernel builds (locks/; clss.device). PoCL keeps its own
compiled kernels in `pocl/kcache` beside it (docs/devices.md#caches).

`$CLSS_CACHE_DIR` when set, else the platform's user cache directory through
platformdirs: `$XDG_CACHE_HOME/clss` on Linux (`~/.cache/clss` when XDG_CACHE_HOME is
unset), the same directory PoCL's own kernel cache (`pocl/`) sits in; `~/Library/Caches/clss`
on macOS; `%LOCALAPPDATA%\\clss\\Cache` on Windows. Read at each call, never
remembered, so a changed environment (a test's monkeypatch, a child process) moves it.

Every file is written whole to a temporary file in its own directory and renamed over the
old one (`write_atomic`): a reader sees the old file or the new one, never a part. A
read-modify-write (`update_json`) holds an inter-process lock (`locked`: flock on a lock
file beside the file), so that two processes adding an entry each both keep theirs."""
from __future__ import annotations

import json
import os
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import platformdirs

from .filemode import new_file_mode


def cache_dir() -> Path:
    """clss's cache directory (not created here; the writers create it)."""
    base = os.environ.get("CLSS_CACHE_DIR")
    if base:
        return Path(base).expanduser()
    return Path(platformdirs.user_cache_dir("clss", appauthor=False))


def lock_path(path: Path) -> Path:
    """The lock file of `path`: beside it, `<name>.lock`. Never deleted (deleting a lock
    file another process has just opened would let a third take a second lock)."""
    return path.with_name(path.name + ".lock")


@contextmanager
def locked(path: Path, timeout: float | None = None):
    """Hold the inter-process lock of `path` (an exclusive flock on `lock_path(path)`) inside
    the block; yields whether it is held. Degrades to no lock, never to an error, where there
    is none to take: no fcntl (Windows), a read-only or full cache directory, a file system
    that refuses locks (ENOLCK on some NFS), or `timeout` seconds spent waiting (a process
    stopped with Ctrl-Z while it holds the lock must not hang every other one). The kernel
    drops a dead process's flock, so a killed holder leaves nothing stale behind."""
    try:
        import fcntl
    except ImportError:     # Windows: atomic renames still keep every file whole
        yield False
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(lock_path(path), os.O_RDWR | os.O_CREAT, new_file_mode())
    except OSError:
        yield False
        return
    try:
        yield _flock(fcntl, fd, timeout)
    finally:
        os.close(fd)        # releases the lock


def _flock(fcntl, fd: int, timeout: float | None) -> bool:
    if timeout is None:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            return True
        except OSError:
            return False
    deadline, wait = time.monotonic() + timeout, 0.01
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            if time.monotonic() >= deadline:
                return False
            time.sleep(wait)
            wait = min(wait * 2, 0.5)
        except OSError:
            return False


def write_atomic(path: Path, data: str | bytes) -> None:
    """Write `data` to `path` whole or not at all: a temporary file in the same directory
    (same file system, so the rename is atomic), then os.replace. The file gets the mode a
    plain open() would give (mkstemp's is 0600). Not fsynced: a cache file lost to a power
    cut is read as missing, which costs a re-check, not a wrong answer."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data.encode() if isinstance(data, str) else data)
        os.chmod(tmp, new_file_mode())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def read_json(path: Path):
    """The JSON in `path`, or None where it is missing or unreadable."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def update_json(path: Path, change, timeout: float | None = 60.0, **dumps) -> object:
    """Read-modify-write `path` behind its lock: `change(data)` gets what the file holds now
    (None where it is missing or unreadable) and returns what to write, which is written
    atomically and returned. Read inside the lock, never from a copy kept before it, so an
    entry another process wrote meanwhile is kept. `dumps`: json.dumps's options."""
    with locked(path, timeout):
        data = change(read_json(path))
        write_atomic(path, json.dumps(data, **dumps))
    return data
