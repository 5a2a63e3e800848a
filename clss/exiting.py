"""Leaving a process that ran OpenCL kernels (a leaf: the clss command, python -m bench,
python -m weights_tools and the test session end through it)."""
from __future__ import annotations

import atexit
import os
import sys


def leave(status) -> None:
    """Exit with ``status`` after Python's own exit work (atexit handlers, flushed streams),
    but without the native library teardown that follows it: pip's PoCL 3.0 aborts there
    ("still have references to IRs - can't release LLVM context") once kernels were built,
    which turned a finished run (make demo's, every file written) into status 134."""
    status = 0 if status is None else status if isinstance(status, int) else 1
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(status)
