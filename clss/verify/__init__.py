"""Verification, above the runtime (which never imports it): conformance cases (seeded
inputs, an ONNX twin, how to run them on the device), the twins' builders and onnxruntime,
each family's cases (cases/<stem>.py), and the `clss verify` table (conformance.py).
Tolerances and compare() are in clss/tolerance.py, below the ops: the runtime's fast-path
self-check uses them too."""
from __future__ import annotations

from .case import Case, host_call, round_inputs
from .cases import all_cases
from .conformance import Row, check, format_fast_paths, format_table

__all__ = ["Case", "host_call", "round_inputs", "all_cases", "Row", "check", "format_table",
           "format_fast_paths"]
