"""clss's cache directory (clss/cachedir.py): the self-check verdicts and the tuning
database follow XDG_CACHE_HOME (platformdirs reads it at each call on Linux), and the
explicit overrides ($CLSS_CACHE_DIR, $CLSS_TUNING_DB) still win."""
import json
import sys

import pytest

from clss import selfcheck, tuning
from clss.cachedir import cache_dir

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="XDG_CACHE_HOME is the Linux convention")


@pytest.fixture
def env(tmp_path, monkeypatch):
    for name in ("CLSS_CACHE_DIR", "CLSS_TUNING_DB"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    return tmp_path


def test_xdg_cache_home_moves_both_caches(env):
    d = env / "xdg" / "clss"
    assert cache_dir() == d
    assert selfcheck.cache_path() == d / "selfcheck.json"
    assert tuning.db_path() == d / "tuning.json"
    # The writers create the directory there and write into it.
    selfcheck._store("k", selfcheck.Verdict("fp", "kernel", "fp32", "dev", True))
    tuning.store("dev | drv", "op", "key", {"X": 2})
    assert json.loads((d / "selfcheck.json").read_text())["k"]["ok"] is True
    assert json.loads((d / "tuning.json").read_text())["devices"]["dev | drv"]["op"]["key"][
        "params"] == {"X": 2}


def test_without_xdg_cache_home_the_default_is_home_cache(env, monkeypatch):
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(env / "home"))
    assert cache_dir() == env / "home" / ".cache" / "clss"


def test_the_overrides_win(env, monkeypatch):
    monkeypatch.setenv("CLSS_CACHE_DIR", str(env / "mine"))
    assert selfcheck.cache_path() == env / "mine" / "selfcheck.json"
    assert tuning.db_path() == env / "mine" / "tuning.json"
    monkeypatch.setenv("CLSS_TUNING_DB", str(env / "db.json"))
    assert tuning.db_path() == env / "db.json"
