"""The MLP upscaler's fast path (mlp_upscale.cl: VEC = 8 render pixels per
work-item as vectors, the PQ encode hoisted into its own pass), registered with
clss.selfcheck and checked against the one-pixel reference kernel on a seeded frame, at 2x
and 3x, with and without the feature pass. It lives in the room (as CLSS's
frame_selfcheck.py does) because the check uses the method's geometry and weights;
clss.selfcheck_runner imports it so that a child process can run the check."""
from __future__ import annotations

import numpy as np

from ... import selfcheck
from ...device import Device
from ...ops.base import rng
from .mlp_upscale import FAST, FUSED, FUSED_VEC, KERNEL, blocks, frame, pack_weights
from . import transform as tf


def _selfcheck_run(dev: Device, prec: str) -> list:
    """The block pass on a seeded frame whose rows end in a partial vector and whose
    interior takes the vector loads, at 2x and 3x, with and without the feature."""
    g = rng("mlp_upscale selfcheck")
    outs = []
    for s, feature in ((2, True), (3, True), (2, False)):
        h, w = 7, 29
        color = dev.to_device(g.uniform(0, 4, (h, w, 3)).astype(np.float32), prec)
        feat = dev.to_device(g.uniform(0, 1, (s * h, s * w)).astype(np.float32), prec)
        t = tf.init_weights(int(g.integers(1 << 30)))
        t["fc3.weight"] = g.normal(0, 0.1, (25, 50)).astype(np.float32)
        wts = pack_weights(dev, prec, tf.packed(t))
        outs.append(dev.to_host(blocks(dev, prec, color, feat, wts, tf.kernel_defines(s, feature))))
    return outs


def _tolerance(prec):
    from ...tolerance import DEFAULT_TOL
    return DEFAULT_TOL[prec]


# The vector form computes the same formulas: the same FMAs per lane; pow's vector form may
# round differently from the scalar one, hence the op tolerance.
selfcheck.register(selfcheck.FastPath(
    FAST, KERNEL, {"VEC": 8}, {"VEC": 1}, check=_selfcheck_run, tolerance=_tolerance,
    what="8 render pixels per work-item as vectors, the PQ encode hoisted",
    applies=lambda dev: dev.is_cpu, measured=True))


def _fused_check_run(dev: Device, prec: str) -> list:
    """The whole frame step on seeded frames, compared in the PQ domain (as the method's
    tests compare it with its twin): widths with interior vectors and partial ones, a
    width under one vector, heights under and over one work-item's rows, at 2x and 3x,
    with and without the feature, an exposure."""
    from ...pipeline.contract import pq_encode
    g = rng("mlp_upscale fused selfcheck")
    outs = []
    for s, feature, (h, w) in ((2, True, (7, 37)), (3, True, (5, 31)), (2, False, (3, 9)),
                               (3, False, (2, 17))):
        color = dev.to_device(g.uniform(0, 4, (h, w, 3)).astype(np.float32), prec)
        feat = dev.to_device(g.uniform(0, 1, (s * h, s * w)).astype(np.float32), prec)
        t = tf.init_weights(int(g.integers(1 << 30)))
        t["fc3.weight"] = g.normal(0, 0.1, (25, 50)).astype(np.float32)
        wts = pack_weights(dev, prec, tf.packed(t))
        for rows in (None, 2):
            y = frame(dev, prec, color, feat, wts, tf.kernel_defines(s, feature),
                      exposure=1.5, rows=rows)
            outs.append(pq_encode(np.asarray(dev.to_host(y), np.float32)))
    return outs


def _fused_tolerance(prec):
    # PQ code values, absolute: the method's test tolerances against the ONNX twin
    from ...tolerance import Tolerance
    return Tolerance(1e-4, 0.0) if prec == "fp32" else Tolerance(2e-3, 0.0)


# The fused frame step computes the reference's formulas per block with the same FMAs
# per lane; the ramp as sqrt and square, the PQ transfer as exp2/log2 on vectors.
selfcheck.register(selfcheck.FastPath(
    FUSED, KERNEL, {"FUSED": 1, "VEC": FUSED_VEC}, {"FUSED": 0, "VEC": 1},
    check=_fused_check_run, tolerance=_fused_tolerance,
    what=f"the frame step as one GEMM kernel with the fold fused, {FUSED_VEC} render "
         "pixels per vector",
    applies=lambda dev: dev.is_cpu, measured=True))
