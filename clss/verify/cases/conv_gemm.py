"""The implicit-GEMM conv rows (kernels/conv_gemm.cl, clss/ops/conv_gemm.py) against
onnxruntime's Conv: each row forced through conv2d's chooser (tuning={"VARIANT": row, tiles})
and, in fp16, the tensor-core data layout emulated (CONV_MMA=1) on any device. Shapes with
ragged tiles in every dimension: channels, pixels and the k = Cin * KH * KW walk. A row whose
self-check fails on a device falls back to the device's other rows, as the engine would.
The winograd_gemm row (clss/ops/conv_winograd_gemm.py) runs here too, on each GEMM of its step 2."""
from __future__ import annotations

import numpy as np

from ...ops import conv_gemm
from ...ops.conv import ConvCall, ConvLayer, _act, _flags, conv_output_size, layer_key
from ...tolerance import Tolerance
from .conv import make_case

ROWS = ("gemm", "gemm_global", "mma_emulated")
# winograd_gemm's cases, by the GEMM of its step 2 (the tuning parameter GEMM)
WINOGRAD = {"winograd_gemm": "gemm", "winograd_gemm_global": "gemm_global", "winograd_mma_emulated": "mma_emulated"}
# Winograd on the tensor cores' fp16 operands: V = B^T d B and U = G g G^T rounded to half lose
# about a bit in the transforms' sums (0.3-0.5x the fp16 tolerance against the direct row on most
# of tests/test_ops_conv_gemm.py's layers, 1.9x on one), so the probe and the tuner reject that GEMM
# where it misses; these cases check its data layout, where a wrong fragment map errs by O(1).
WINOGRAD_MMA_TOL = {"fp16": Tolerance(atol=5e-3, rtol=5e-3)}


def _case(row, tiles, *, n=1, cin, h, w, cout, k=(3, 3), strides=(1, 1), pads=(1, 1, 1, 1),
          dilations=(1, 1), group=1, bias=True, activation="none", alpha=0.01, residual=None):
    shape = dict(n=n, cin=cin, h=h, w=w, cout=cout, k=k, strides=strides, pads=pads, dilations=dilations,
                 group=group, bias=bias, activation=activation, alpha=alpha, residual=residual)
    if row in WINOGRAD:
        c = make_case(**shape, tuning={"VARIANT": "winograd_gemm", "GEMM": WINOGRAD[row], **tiles},
                      tol=WINOGRAD_MMA_TOL if row == "winograd_mma_emulated" else None)
    else:
        c = make_case(**shape, tuning={"VARIANT": "gemm" if row == "mma_emulated" else row, **tiles})
    if row == "winograd_mma_emulated":
        half, scalar = c.run, make_case(**shape, tuning={"VARIANT": "winograd_gemm", **tiles}).run
        # the tensor-core layout takes half storage only: fp32 runs the scalar GEMM
        c.run = lambda dev, prec, inputs: (half if prec == "fp16" else scalar)(dev, prec, inputs)
    if row == "mma_emulated":
        fallback = c.run

        def run(dev, prec, inputs):
            if prec != "fp16":      # the tensor-core layout takes half storage only
                return fallback(dev, prec, inputs)
            a = {name: dev.to_device(v, prec) for name, v in inputs.items()}
            ho = conv_output_size(h, k[0], strides[0], pads[0] + pads[2], dilations[0])
            wo = conv_output_size(w, k[1], strides[1], pads[1] + pads[3], dilations[1])
            out = dev.empty((n, cout, ho, wo), prec)
            layer = ConvLayer((n, cin, h, w), tuple(a["w"].shape), tuple(strides), tuple(pads), tuple(dilations),
                              group, residual=residual is not None)
            before = residual != "after"
            call = ConvCall(a["x"], a["w"], a.get("b"), None, activation, alpha, a.get("r"), before, out, ho, wo,
                            tiles)
            conv_gemm.launch(dev, prec, layer, call, _act(activation), _flags(a.get("b"), a.get("r"), before),
                             key=layer_key(layer, prec), variant="mma", mma=1)
            return [np.asarray(dev.to_host(out))]
        c.run = run
    c.variant = f"{c.variant} [{row}{''.join(f' {k}{v}' for k, v in tiles.items())}]"
    return c


# small tiles: a few work-groups, so that oclgrind checks the local memory and its barriers
SMALL = {"TM": 16, "TN": 16, "TK": 8, "RM": 2, "RN": 2}
MMA_SMALL = {"TM": 16, "TN": 16, "TK": 16}


def winograd_tiny() -> list:
    """winograd_gemm on each GEMM at small tiles: odd sizes (partial tiles in both directions),
    ragged GEMM tiles, pads 0 to 2 and asymmetric, a batch of 2, residuals before and after, no
    bias. In the quick level, not the tiny one: oclgrind runs them on their own
    (tests/test_oclgrind.py), as it reports a process's reused buffers as uninitialised."""
    return [_case("winograd_gemm", SMALL, cin=16, h=5, w=7, cout=17, activation="relu", residual="before"),
            _case("winograd_gemm_global", SMALL, n=2, cin=17, h=6, w=5, cout=16, pads=(0, 2, 1, 0),
                  activation="leaky_relu", alpha=0.2, residual="after"),
            _case("winograd_mma_emulated", MMA_SMALL, cin=16, h=5, w=9, cout=16, pads=(2, 0, 0, 2),
                  activation="sigmoid", bias=False)]


def cases(level: str = "quick") -> list:
    # tiny: every row with small tiles, ragged in channels, pixels and k, stride 2 with a
    # dilation, a 1x1 grouped layer, residuals before and after, a batch of 2.
    tiny = []
    for row, tiles in (("gemm", SMALL), ("gemm_global", SMALL), ("mma_emulated", MMA_SMALL)):
        tiny += [_case(row, tiles, cin=5, h=6, w=11, cout=19, activation="relu", residual="before"),
                 _case(row, tiles, n=2, cin=6, h=9, w=13, cout=9, strides=(2, 2), dilations=(2, 2),
                       pads=(2, 0, 1, 2), activation="leaky_relu", alpha=0.2, residual="after")]
    tiny.append(_case("gemm", SMALL, cin=8, h=5, w=7, cout=12, k=(1, 1), pads=(0, 0, 0, 0), group=2,
                      activation="sigmoid", bias=False))
    if level == "tiny":
        return tiny
    # quick: the default tiles, several work-groups along every axis; Winograd's small tiles, and
    # its default ones on prime sizes and channel counts
    quick = tiny + [_case(row, {}, cin=24, h=17, w=45, cout=70, activation="tanh") for row in ROWS]
    quick += winograd_tiny() + [_case(row, {}, cin=19, h=23, w=41, cout=29, activation="tanh", residual="before")
                                for row in ("winograd_gemm", "winograd_gemm_global")]
    if level == "quick":
        return quick
    return quick + [_case(row, {}, cin=37, h=23, w=61, cout=33, k=(5, 5), pads=(2, 2, 2, 2), residual="before")
                    for row in ROWS] + [
        _case(row, {}, cin=32, h=31, w=67, cout=48, activation="relu", residual="after")
        for row in ("winograd_gemm", "winograd_gemm_global", "winograd_mma_emulated")]
