"""What every op family shares: conformance cases (tolerances: clss/tolerance.py), and the
registry that maps ONNX op types onto kernels.

Each module in clss/ops/ holds one kernel family (same stem as kernels/<stem>.cl
and tests/test_ops_<stem>.py) and provides:

* device-level functions, ``fn(dev, prec, x: cl.array.Array, ..., out=None) -> Array``
  working on NCHW tensors in the precision's storage type;
* ``cases(level) -> list[Case]``: seeded conformance cases (level "quick" is what
  ``clss verify`` runs, "full" adds odd shapes and parameter sweeps);
* ONNX handlers registered with ``@onnx_op(...)``, used by the node-case
  conformance tests and by clss.Model.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterable

import numpy as np
import onnx

from ..device import Device, storage_dtype
# Tolerances live below the ops: the runtime's fast-path self-check compares with them too.
from ..tolerance import DEFAULT_TOL, EXACT, Comparison, Tolerance, compare  # noqa: F401


class Unsupported(Exception):
    """An ONNX node whose attributes/inputs the kernels do not cover."""


# --- conformance cases ----------------------------------------------------------

@dataclass
class Case:
    """One op invocation with seeded inputs, its ONNX twin, and how to run it here.

    ``run(dev, prec, inputs) -> list of host arrays`` gets the same (fp16-rounded
    in half modes) inputs that onnxruntime gets, in the twin's output order."""
    op: str
    variant: str
    inputs: dict[str, np.ndarray]
    twin: onnx.ModelProto
    run: Callable[[Device, str, dict[str, np.ndarray]], list[np.ndarray]]
    exact: bool = False
    tol: dict[str, Tolerance] = field(default_factory=dict)
    no_round: tuple[str, ...] = ()   # float inputs that stay fp32 in half modes (e.g. grids)

    def tolerance(self, precision: str):
        if self.exact:
            return EXACT
        return self.tol.get(precision, DEFAULT_TOL[precision])

    @property
    def name(self) -> str:
        return f"{self.op}[{self.variant}]"


def round_inputs(case: Case, precision: str) -> dict[str, np.ndarray]:
    """Inputs as the engine stores them: fp16-rounded floats in half modes."""
    if precision == "fp32":
        return dict(case.inputs)
    return {k: (v.astype(np.float16).astype(np.float32)
                if v.dtype.kind == "f" and k not in case.no_round else v)
            for k, v in case.inputs.items()}


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


def node_attrs(node: onnx.NodeProto) -> dict:
    return {a.name: onnx.helper.get_attribute_value(a) for a in node.attribute}


def as_str(v) -> str:
    return v.decode() if isinstance(v, bytes) else str(v)


def host_call(fn: Callable, *, exact_ints: bool = True):
    """Wrap a device-level op as a Case.run: upload named inputs, call, download.

    fn(dev, prec, **device_arrays) -> Array or list of Arrays."""
    def run(dev: Device, prec: str, inputs: dict[str, np.ndarray]) -> list[np.ndarray]:
        arrays = {k: dev.to_device(v, prec) for k, v in inputs.items()}
        out = fn(dev, prec, **arrays)
        outs = out if isinstance(out, (list, tuple)) else [out]
        return [dev.to_host(o) for o in outs]
    return run


def check_storage(name: str, a, prec: str) -> None:
    """Device tensors must already be in the precision's storage type."""
    want = storage_dtype(prec)
    if a.dtype != want:
        raise TypeError(f"{name}: expected {want} storage for precision {prec!r}, got {a.dtype}")
