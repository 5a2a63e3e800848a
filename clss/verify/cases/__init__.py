"""Every op family's conformance cases: clss/verify/cases/<stem>.py mirrors clss/ops/<stem>.py
and kernels/<stem>.cl, and provides ``cases(level) -> list[Case]`` (level "quick" is what
``clss verify`` runs, "tiny" its smallest shapes (oclgrind), "full" adds odd shapes and
parameter sweeps, as the tests run)."""
from __future__ import annotations

import importlib

from ... import ops
from ..case import Case


def family(name: str):
    """The cases module of one kernel family (a stem of ops.FAMILIES)."""
    return importlib.import_module(f"{__name__}.{name}")


def all_cases(level: str = "quick", families=None) -> list[Case]:
    """The cases of `families` (default: every family), in ops.FAMILIES order. A family
    whose kernel module is absent (a partial checkout) is left out, with ops.load_all's
    warning."""
    present = ops.load_all()
    out = []
    for name in families or ops.FAMILIES:
        if name in present:
            out.extend(family(name).cases(level))
    return out
