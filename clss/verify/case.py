"""A conformance case: one op invocation with seeded inputs, its ONNX twin, and how to
run it on the device (tolerances: clss/tolerance.py)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import onnx

from ..device import Device
from ..tolerance import DEFAULT_TOL, EXACT, Tolerance


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


def host_call(fn: Callable, *, exact_ints: bool = True):
    """Wrap a device-level op as a Case.run: upload named inputs, call, download.

    fn(dev, prec, **device_arrays) -> Array or list of Arrays."""
    def run(dev: Device, prec: str, inputs: dict[str, np.ndarray]) -> list[np.ndarray]:
        arrays = {k: dev.to_device(v, prec) for k, v in inputs.items()}
        out = fn(dev, prec, **arrays)
        outs = out if isinstance(out, (list, tuple)) else [out]
        return [dev.to_host(o) for o in outs]
    return run
