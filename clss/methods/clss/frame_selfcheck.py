"""The frame step's fast paths (frame.cl: VEC = 8 pixel vectors, builtin-free half
loads), registered with clss.selfcheck and checked by running two frames through the
Upscaler. upscaler.py calls register_fast_paths(Upscaler) once it has defined the class:
this module does not import upscaler.py, which imports frame.py, so nothing here closes
an import cycle."""
from __future__ import annotations

import numpy as np

from ... import selfcheck
from ...device import Device
from ...ops.base import rng
from ...ops.conv import builtin_free
from ...tolerance import DEFAULT_TOL
from .frame import KERNEL


def _selfcheck_run(mode: str, Upscaler):
    """Two frames (the second blends the warped history) at a render size whose output
    rows end in a partial vector, through the Upscaler in `mode`."""
    def run(dev: Device, prec: str) -> list[np.ndarray]:
        g = rng("frame selfcheck", mode)
        h, w = 6, 13
        up = Upscaler(2.0, "rules" if mode == "rule" else "net", device=dev, precision=prec)
        outs = []
        for jitter in ((0.25, -0.25), (-0.25, 0.25)):
            color = g.uniform(0, 4, (h, w, 3)).astype(np.float32)
            depth = g.uniform(0.1, 0.9, (h, w)).astype(np.float32)
            motion = g.uniform(-1.5, 1.5, (h, w, 2)).astype(np.float32)
            outs.append(up.step(color, depth, motion, jitter))
        return outs
    return run


def register_fast_paths(Upscaler) -> None:
    # The vector form and VEC = 1 compute the same formulas; per-lane builtins (pow, exp)
    # may round differently from their vector forms, hence the op tolerance, not bit-exact.
    for _mode in ("rule", "net"):
        selfcheck.register(selfcheck.FastPath(
            f"frame.pixel_vectors.{_mode}", KERNEL, {"VEC": 8, "NET": int(_mode == "net")},
            {"VEC": 1, "NET": int(_mode == "net")}, check=_selfcheck_run(_mode, Upscaler),
            tolerance=DEFAULT_TOL.__getitem__, what=f"8 output pixels per work-item as vectors ({_mode} mode)",
            applies=lambda dev: dev.is_cpu, measured=True))
        selfcheck.register(selfcheck.FastPath(
            f"frame.{_mode}.builtin_free_loads", KERNEL, {"CLSS_CLANG_VECTORS": 1, "NET": int(_mode == "net")},
            {"CLSS_CLANG_VECTORS": 0, "NET": int(_mode == "net")}, check=_selfcheck_run(_mode, Upscaler),
            tolerance=DEFAULT_TOL.__getitem__,
            what=f"half loads/stores as clang vector conversions ({_mode} mode)", applies=builtin_free))
        # the builtins inline (bit-exact) and the PQ transfer on powq8, the sigmoid on
        # pq_exp2q8 (rounded otherwise than the library's exp2, log2 and exp): tolerance
        selfcheck.register(selfcheck.FastPath(
            f"frame.inline_math.{_mode}", KERNEL, {"CLSS_INLINE_MATH": 1, "NET": int(_mode == "net")},
            {"CLSS_INLINE_MATH": 0, "NET": int(_mode == "net")}, check=_selfcheck_run(_mode, Upscaler),
            tolerance=DEFAULT_TOL.__getitem__,
            what=f"fmin, fmax, clamp, floor, select, ... as clang builtins and operators, the PQ transfer "
                 f"on powq8 ({_mode} mode)", applies=builtin_free))
