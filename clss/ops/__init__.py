"""Kernel families: kernel launchers and ONNX handlers. Each module shares its stem with
kernels/<stem>.cl, clss/verify/cases/<stem>.py (its conformance cases) and
tests/test_ops_<stem>.py; see base.py for what a family module provides."""
from __future__ import annotations

import importlib

from .base import ONNX_HANDLERS, Unsupported, onnx_op

FAMILIES = (
    "conv",
    "conv_gemm",
    "space_to_depth",
    "resize",
    "zero_upsample",
    "warp",
    "scatter",
    "mlp",
    "pool",
    "elementwise",
    "lstm",
    "reduce",
    "norm",
    "matmul",
)


def family(name: str):
    return importlib.import_module(f"{__name__}.{name}")


def load_all() -> dict:
    """Import every family so its ONNX handlers are registered. A family whose
    module is absent (a partial checkout) is left out with a warning; any
    other import error propagates."""
    import warnings
    mods = {}
    for name in FAMILIES:
        try:
            mods[name] = family(name)
        except ModuleNotFoundError as e:
            if e.name != f"{__name__}.{name}":
                raise
            warnings.warn(f"op family {name!r} is missing (clss/ops/{name}.py)")
    return mods


__all__ = ["Unsupported", "ONNX_HANDLERS", "onnx_op", "FAMILIES", "family", "load_all"]
