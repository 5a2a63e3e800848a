"""What every op family shares: tolerances, conformance cases, and the
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


class Unsupported(Exception):
    """An ONNX node whose attributes/inputs the kernels do not cover."""


# --- tolerances ---------------------------------------------------------------

@dataclass(frozen=True)
class Tolerance:
    """Elementwise bound |out - ref| <= atol * max|ref| + rtol * |ref|.

    atol is relative to the output's scale, so one bound serves tensors of any
    magnitude; rtol covers the storage rounding of each element."""
    atol: float
    rtol: float

    def bound(self, ref: np.ndarray) -> np.ndarray:
        scale = float(np.max(np.abs(ref))) if ref.size else 0.0
        return self.atol * scale + self.rtol * np.abs(ref)

    def __str__(self) -> str:
        return f"{self.atol:g}*max|ref|+{self.rtol:g}*|ref|"


EXACT = "bit-exact"

# Defaults per precision. fp16 (half storage, float arithmetic) differs from an
# fp32 reference fed the same fp16-rounded inputs by the final rounding of the
# output (2^-11 relative) plus accumulation order; fp16-native accumulates in
# half, whose 11-bit mantissa loses ~1e-3 per add over long sums.
DEFAULT_TOL = {
    "fp32": Tolerance(1e-5, 1e-4),
    "fp16": Tolerance(1e-3, 1e-3),
    "fp16-native": Tolerance(1e-2, 1e-2),
}


@dataclass
class Comparison:
    max_abs: float
    max_rel: float      # max|d| / max|ref|
    ratio: float        # worst |d| / bound (<= 1 passes); for exact: mismatching elements
    tol: str
    passed: bool
    detail: str = ""


def compare(out: np.ndarray, ref: np.ndarray, tol: Tolerance | str) -> Comparison:
    out = np.asarray(out)
    ref = np.asarray(ref)
    if out.shape != ref.shape:
        return Comparison(np.inf, np.inf, np.inf, str(tol), False,
                          f"shape {out.shape} != reference {ref.shape}")
    if tol == EXACT:
        if out.dtype.kind == "f":
            same = (out == ref) | (np.isnan(out) & np.isnan(ref))
        else:
            same = out == ref
        bad = int(np.count_nonzero(~same))
        d = np.abs(out.astype(np.float64) - ref.astype(np.float64)) if out.size else np.zeros(1)
        mx = float(np.nanmax(d)) if d.size else 0.0
        scale = float(np.max(np.abs(ref.astype(np.float64)))) if ref.size else 0.0
        detail = "" if bad == 0 else f"{bad} of {out.size} elements differ; first at {_first(~same)}"
        return Comparison(mx, mx / scale if scale else mx, float(bad), EXACT, bad == 0, detail)
    o = out.astype(np.float64)
    r = ref.astype(np.float64)
    nan_mismatch = np.isnan(o) != np.isnan(r)
    finite = ~np.isnan(r) & ~np.isnan(o)
    d = np.where(finite, np.abs(o - r), 0.0)
    d = np.where(np.isinf(r) & (o == r), 0.0, d)
    bound = tol.bound(np.where(finite, r, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio_arr = np.where(bound > 0, d / bound, np.where(d > 0, np.inf, 0.0))
    max_abs = float(d.max()) if d.size else 0.0
    scale = float(np.max(np.abs(np.where(finite, r, 0.0)))) if r.size else 0.0
    ratio = float(ratio_arr.max()) if d.size else 0.0
    passed = ratio <= 1.0 and not nan_mismatch.any()
    detail = ""
    if nan_mismatch.any():
        detail = f"NaN mismatch at {_first(nan_mismatch)}"
    elif not passed:
        i = np.unravel_index(int(np.argmax(ratio_arr)), ratio_arr.shape)
        detail = f"worst at {tuple(int(k) for k in i)}: out {o[i]:.6g} ref {r[i]:.6g}"
    return Comparison(max_abs, max_abs / scale if scale else max_abs, ratio, str(tol), passed, detail)


def _first(mask: np.ndarray):
    idx = np.argwhere(mask)
    return tuple(int(k) for k in idx[0]) if len(idx) else None


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
