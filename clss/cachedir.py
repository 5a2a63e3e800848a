"""Where clss keeps what it caches between runs: the fast-path self-check verdicts
(clss.selfcheck, selfcheck.json) and the tuning database (clss.tuning, tuning.json).

`$CLSS_CACHE_DIR` when set, else the platform's user cache directory through
platformdirs: `$XDG_CACHE_HOME/clss` on Linux (`~/.cache/clss` when XDG_CACHE_HOME is
unset), the same directory PoCL's own kernel cache (`pocl/`) sits in; `~/Library/Caches/clss`
on macOS; `%LOCALAPPDATA%\\clss\\Cache` on Windows. Read at each call, never
remembered, so a changed environment (a test's monkeypatch, a child process) moves it."""
from __future__ import annotations

import os
from pathlib import Path

import platformdirs


def cache_dir() -> Path:
    """clss's cache directory (not created here; the writers create it)."""
    base = os.environ.get("CLSS_CACHE_DIR")
    if base:
        return Path(base).expanduser()
    return Path(platformdirs.user_cache_dir("clss", appauthor=False))
