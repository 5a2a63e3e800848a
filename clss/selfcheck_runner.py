"""Every fast path at once. clss/selfcheck.py is the registry the ops register their
fast paths in (it sits below them); this module sits above them and imports every
module that registers one (the op families, and each method's as its MethodSpec names
it: `fast_paths`), so `clss verify` can check them all and a variant's check can run in
a child process:

    python -m clss.selfcheck_runner DEVICE_INDEX PRECISION NAME
    python -m clss.selfcheck_runner --deferred INDEX:PRECISION:NAME ...   (selfcheck.deferring)
"""
from __future__ import annotations

from . import selfcheck


def load_registrations() -> None:
    """Import every module that registers fast paths."""
    import importlib
    import warnings as w
    from . import methods
    from . import model  # noqa: F401 - registers model.blocked_layout
    from .ops import load_all
    with w.catch_warnings():
        w.simplefilter("ignore")
        load_all()
    for module in dict.fromkeys(s.fast_paths for s in methods.specs() if s.fast_paths):
        importlib.import_module(module)
    # precision="auto"'s fp16 check of a method, when a run deferred it (pipeline/precision.py)
    from .pipeline import precision
    selfcheck.DEFERRED_CHECKS[precision.PREFIX] = (
        lambda dev, prec, name: precision.check_deferred(dev, prec, name, methods.spec))


def check_all(dev, precisions, kernels=None) -> list:
    """selfcheck.check_all over every fast path clss has."""
    load_registrations()
    return selfcheck.check_all(dev, precisions, kernels)


if __name__ == "__main__":
    import os
    import sys
    load_registrations()
    if sys.argv[1:2] == ["--deferred"]:
        os.nice(19)         # after the run that deferred them, beside whatever runs next
        status = selfcheck.deferred_main(sys.argv[2:])
    else:
        status = selfcheck._child_main(sys.argv[1:])
    # The verdict is printed: leave without the interpreter's teardown, where pip's PoCL 3.0
    # aborts ("still have references to IRs - can't release LLVM context") once programs
    # have been built, which would read as a crashed check and cost a fast path that passed.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)
