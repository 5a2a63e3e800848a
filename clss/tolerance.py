"""How close an output must be to its reference: Tolerance (or EXACT), the defaults per
precision, and compare(). Used by the conformance cases (clss/verify), the fast-path
self-check at run time (clss/selfcheck.py) and the frame step's self-check."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
