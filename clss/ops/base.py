"""What every op family shares: the registry that maps ONNX op types onto kernels, and
small helpers (argument checks, seeded generators for the fast-path self-checks).

Each module in clss/ops/ holds one kernel family (same stem as kernels/<stem>.cl,
clss/verify/cases/<stem>.py and tests/test_ops_<stem>.py) and provides:

* device-level functions, ``fn(dev, prec, x: cl.array.Array, ..., out=None) -> Array``
  working on NCHW tensors in the precision's storage type;
* ONNX handlers registered with ``@onnx_op(...)``, used by clss.Model and by the
  node-case conformance tests;
* its fast paths' self-checks (clss/selfcheck.py).

Its conformance cases (seeded inputs, ONNX twins) are in clss/verify/cases/<stem>.py.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np
import onnx

from ..device import storage_dtype


class Unsupported(Exception):
    """An ONNX node whose attributes/inputs the kernels do not cover."""


def rng(*key) -> np.random.Generator:
    """A generator seeded from a readable key, so each case is reproducible alone."""
    import zlib
    return np.random.default_rng(zlib.crc32(repr(key).encode()))


# --- ONNX handlers --------------------------------------------------------------

@dataclass
class OnnxHandler:
    """fn(dev, prec, attrs, inputs) -> list of device arrays.

    inputs[i] is a device array, or a numpy array for the indices listed in
    ``const_inputs`` (shape-like inputs such as Resize scales, Pad pads, which
    must be known when the launch is set up), or None for an omitted optional
    input. Handlers raise Unsupported for attribute values they do not cover."""
    op_type: str
    fn: Callable
    const_inputs: frozenset = frozenset()
    domain: str = ""


ONNX_HANDLERS: dict[str, OnnxHandler] = {}


def onnx_op(*op_types: str, const_inputs: Iterable[int] = ()):
    def deco(fn):
        for t in op_types:
            ONNX_HANDLERS[t] = OnnxHandler(t, fn, frozenset(const_inputs))
        return fn
    return deco


def unsupported_on_value_error(fn, *args, **kw):
    """fn(*args, **kw), its ValueError (an argument the kernels do not cover) raised as
    Unsupported: what an ONNX handler reports for a node it cannot run."""
    try:
        return fn(*args, **kw)
    except ValueError as e:
        raise Unsupported(str(e)) from None


def node_attrs(node: onnx.NodeProto) -> dict:
    return {a.name: onnx.helper.get_attribute_value(a) for a in node.attribute}


def as_str(v) -> str:
    return v.decode() if isinstance(v, bytes) else str(v)


def check_storage(name: str, a, prec: str) -> None:
    """Device tensors must already be in the precision's storage type."""
    want = storage_dtype(prec)
    if a.dtype != want:
        raise TypeError(f"{name}: expected {want} storage for precision {prec!r}, got {a.dtype}")
