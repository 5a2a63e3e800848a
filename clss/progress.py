"""Progress bars for long runs: tqdm on a terminal, silent otherwise (CI logs
stay readable)."""
from __future__ import annotations

import sys


def progress(iterable, desc: str = "", unit: str = "it", total=None, file=None):
    out = file or sys.stderr
    if not getattr(out, "isatty", lambda: False)():
        return iterable
    from tqdm import tqdm
    return tqdm(iterable, desc=desc, unit=unit, total=total, file=out, dynamic_ncols=True)
