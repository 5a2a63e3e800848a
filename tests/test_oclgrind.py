"""Every kernel once, on tiny shapes, under the oclgrind simulator with its
out-of-bounds, uninitialised-read and data-race checks. Any diagnostic fails.

Skipped (with the reason shown) where oclgrind is not installed; .ci/run installs it."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from clss.ops import FAMILIES
from helpers import DIAGNOSTIC, ICD, oclgrind_env

@pytest.mark.oclgrind
@pytest.mark.skipif(not os.path.exists(ICD), reason="oclgrind not installed (apt-get install oclgrind)")
@pytest.mark.parametrize("family", FAMILIES)
def test_family_clean_under_oclgrind(family, tmp_path):
    p = subprocess.run([sys.executable, "-W", "ignore", "-m", "clss", "verify", "--level", "tiny",
                        "--precision", "all", "--family", family],
                       env=oclgrind_env(tmp_path), capture_output=True, text=True, timeout=900)
    diags = [line for line in p.stderr.splitlines() if DIAGNOSTIC.search(line)]
    assert not diags, "oclgrind reported:\n" + "\n".join(p.stderr.splitlines()[:60])
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    assert "passed" in p.stdout
