"""Every fast path at once. clss/selfcheck.py is the registry the ops register their
fast paths in (it sits below them); this module sits above them and imports every
module that registers one (the op families and the frame step), so `clss verify` can
check them all and a variant's check can run in a child process:

    python -m clss.selfcheck_runner DEVICE_INDEX PRECISION NAME
"""
from __future__ import annotations

from . import selfcheck


def load_registrations() -> None:
    """Import every module that registers fast paths."""
    import warnings as w
    from .ops import load_all
    with w.catch_warnings():
        w.simplefilter("ignore")
        load_all()
    from .methods.clss import upscaler  # noqa: F401 (registers the frame step's, frame_selfcheck.py)
    from .methods.mlp import fastpath  # noqa: F401 (the MLP upscaler's pixel-vector kernel)


def check_all(dev, precisions, kernels=None) -> list:
    """selfcheck.check_all over every fast path clss has."""
    load_registrations()
    return selfcheck.check_all(dev, precisions, kernels)


if __name__ == "__main__":
    import sys
    load_registrations()
    sys.exit(selfcheck._child_main(sys.argv[1:]))
