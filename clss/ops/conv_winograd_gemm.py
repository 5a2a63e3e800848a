"""The winograd_gemm row of the conv2d variant table: Winograd F(2x2, 3x3) on NCHW, for dense 3x3
convs with unit stride and dilation and at least 16 input and output channels (any padding, any
size: the last tiles are partial at odd sizes), in three launches:

  1. V = B^T d B of every 4x4 input tile, stride 2 (kernels/conv_winograd_gemm.cl winograd_input),
     as 16 matrices [16][Cin][P] per image, P tiles;
  2. M = U V, the 16 products as ONE grouped 1x1 conv (16 groups) through conv_gemm.launch, so
     that the local-memory, global-memory and tensor-core GEMMs of kernels/conv_gemm.cl serve it
     as they are, tiles and tuning included; U = G g G^T is transformed once on the host and kept
     with the layer's packed weights;
  3. Y = A^T M A with conv2d's epilogue (bias, residual before or after the activation), stored
     NCHW (winograd_output).

It is the GPU's Winograd, the shape MNN's and ComputeLibrary's OpenCL convs take: 2.25x fewer
multiplies than the direct conv, run by the tuned GEMM, for 16 (Cin + Cout) values per tile of
transform traffic. The CPU's `winograd` row (conv2d_wino on the channel-blocked layout) fuses the
three in one kernel instead. Like the GEMM rows it is probed on GPUs at a layer's first use and
measured by `clss tune --level`; a CPU runs it only when the caller forces it."""
from __future__ import annotations

import numpy as np

from .. import selfcheck
from . import conv_gemm, variants
from ..device import Device
from ..tolerance import DEFAULT_TOL
from .base import rng

MIN_CHANNELS = 16
NAME = "conv.winograd_gemm"
# The GEMM of step 2, the tuning parameter GEMM: conv_gemm.launch's (local, mma) and the fast
# path it needs. mma_emulated (the tensor-core fragments in scalar code, conv_gemm.cl
# CONV_MMA=1) is not searched: tests and `clss verify` force it to check that data path anywhere.
GEMMS = {"gemm": (1, 0, "conv.gemm"), "gemm_global": (0, 0, "conv.gemm_global"),
         "mma": (1, 2, "conv.mma"), "mma_emulated": (1, 1, None)}
TUNABLES = {"GEMM": ("gemm", "gemm_global", "mma"), "TM": conv_gemm.TUNABLES["TM"],
            "TN": conv_gemm.TUNABLES["TN"]}
# Work-items per group along the tiles of a row: one warp, so a transform's loads and stores
# run along P (PoCL, left to choose, makes groups whose private arrays overflow its stacks).
LX = 32
# F(2x2, 3x3)'s weight transform U = G g G^T
_G = np.array([[1, 0, 0], [.5, .5, .5], [.5, -.5, .5], [0, 0, 1]], np.float64)


def eligible(layer) -> bool:
    """Dense NCHW 3x3 convs, unit stride and dilation, >= MIN_CHANNELS in and out (conv.ConvLayer)."""
    cout, cin_g, kh, kw = layer.w
    return (layer.nchw and layer.group == 1 and (kh, kw) == (3, 3) and tuple(layer.strides) == (1, 1)
            and tuple(layer.dilations) == (1, 1) and cin_g >= MIN_CHANNELS and cout >= MIN_CHANNELS)


def _transform(g: np.ndarray) -> np.ndarray:
    """w [Cout, Cin, 3, 3] -> U as the grouped 1x1 conv's weight [16 * Cout, Cin, 1, 1]: group e
    (element (a, b) of the 4x4 tile, e = 4a + b) holds U[e] = (G g G^T)[a, b] over (Cout, Cin)."""
    cout, cin = g.shape[:2]
    return np.einsum("ak,oikl,bl->aboi", _G, g, _G).reshape(16 * cout, cin, 1, 1)


def _gemm(dev: Device, prec: str, key: str, tuning) -> tuple[int, int]:
    """(local, mma) of step 2: the GEMM parameter (default < shipped < tuned < the caller's).
    One whose self-check fails here (or that does not apply) is an error where the caller (the
    tuner's candidate) names it, and a table's choice falls back to the row's own GEMM."""
    name = variants.params(dev, "conv2d", key, "winograd_gemm", {"GEMM": "gemm"}, tuning)["GEMM"]
    if name not in GEMMS:
        raise ValueError(f"conv2d: winograd_gemm's GEMM must be one of {', '.join(GEMMS)}, got {name!r}")
    local, mma, fast = GEMMS[name]
    if mma and prec != "fp16":
        raise ValueError("conv2d: winograd_gemm on the tensor-core GEMM needs fp16 storage (precision 'fp16')")
    if fast is not None and not selfcheck.enabled(dev, prec, fast):
        if (tuning or {}).get("GEMM"):
            raise ValueError(f"conv2d: winograd_gemm's GEMM {name!r} is not used on this device (fast path {fast})")
        return GEMMS["gemm"][:2]
    return local, mma


def run(dev: Device, prec: str, L, c, conv):
    """The row's run function (conv.VARIANTS): layer L (conv.ConvLayer), call c (conv.ConvCall);
    conv: the clss.ops.conv module, which hands itself in (it imports this module for its
    table, so importing it back here would close a cycle)."""
    n, cin, h, w = L.x
    cout = L.w[0]
    th, tw = -(-c.ho // 2), -(-c.wo // 2)
    key = conv.layer_key(L, prec)
    local, mma = _gemm(dev, prec, key, c.tuning)
    mid = "fp16" if mma else "fp32"     # V, M and U: what the GEMM multiplies (kernel's MID_HALF)
    pw = conv._host_packed(dev, prec, c.w, None, c.packed, ("winograd_gemm", mid), cout, _transform, store=mid)
    v = dev.empty((n, 16 * cin, th, tw), mid)
    m = dev.empty((n, 16 * cout, th, tw), mid)
    gx = -(-tw // LX) * LX
    dev.launch(dev.kernel("conv_winograd_gemm", "winograd_input", prec, MID_HALF=int(bool(mma))),
               (gx, th, n * cin),
               (c.x.data, v.data, *(np.int32(a) for a in (cin, h, w, th, tw, L.pads[0], L.pads[1]))),
               local_size=(LX, 1, 1))
    gemm = conv.ConvLayer((n, 16 * cin, th, tw), (16 * cout, cin, 1, 1), (1, 1), (0, 0, 0, 0), (1, 1), 16)
    conv_gemm.launch(dev, mid, gemm, conv.ConvCall(v, pw.wp, None, None, "none", 0.0, None, True, m, th, tw,
                                                   c.tuning),
                     0, 0, key=key, variant="winograd_gemm", local=local, mma=mma)
    dev.launch(dev.kernel("conv_winograd_gemm", "winograd_output", prec, ACT=conv._act(c.activation),
                          MID_HALF=int(bool(mma))),
               (gx, th, n * cout),
               (m.data, None if c.b is None else c.b.data, None if c.residual is None else c.residual.data,
                c.out.data, *(np.int32(a) for a in (cout, c.ho, c.wo, th, tw,
                                                    conv._flags(c.b, c.residual, c.residual_before_act))),
                np.float32(c.alpha)),
               local_size=(LX, 1, 1))
    return c.out


def register_selfcheck(conv2d) -> None:
    """conv.winograd_gemm: the row against the direct row (conv.py calls this with its conv2d)."""
    def check(dev: Device, prec: str) -> list[np.ndarray]:
        """16 and 17 input channels, 19, 16 and 24 outputs (ragged GEMM tiles); odd and prime
        sizes (partial tiles in both directions), pads 0 to 2 and asymmetric, a batch of 2,
        residuals before and after the activation, no bias (tests/test_oclgrind.py runs the verify
        cases' tiny shapes instead)."""
        g = rng("conv winograd_gemm selfcheck")
        row = "winograd_gemm" if selfcheck.enabled(dev, prec, NAME) else "direct"
        outs = []
        for n, cin, cout, hw, pads, act, res, bias in (
                (1, 16, 19, (9, 13), (1, 1, 1, 1), "relu", "before", True),
                (2, 17, 16, (7, 5), (0, 2, 2, 0), "leaky_relu", "after", True),
                (1, 16, 24, (5, 11), (2, 2, 2, 2), "tanh", None, False)):
            x = dev.to_device(g.standard_normal((n, cin) + hw).astype(np.float32), prec)
            w = dev.to_device(g.standard_normal((cout, cin, 3, 3)).astype(np.float32) * 0.1, prec)
            b = dev.to_device(g.standard_normal(cout).astype(np.float32), prec) if bias else None
            ho, wo = hw[0] + pads[0] + pads[2] - 2, hw[1] + pads[1] + pads[3] - 2
            r = dev.to_device(g.standard_normal((n, cout, ho, wo)).astype(np.float32), prec) if res else None
            outs.append(dev.to_host(conv2d(dev, prec, x, w, b, pads=pads, activation=act, alpha=0.2, residual=r,
                                           residual_before_act=res == "before", tuning={"VARIANT": row})))
        return outs

    selfcheck.register(selfcheck.FastPath(
        NAME, "conv_gemm", {"VARIANT": "winograd_gemm"}, {"VARIANT": "direct"}, check=check,
        tolerance=DEFAULT_TOL.__getitem__, sources=("conv_winograd_gemm",),
        what="3x3 stride-1 convs with >= 16 inputs and outputs by Winograd F(2x2, 3x3): transforms around one "
             "grouped 1x1 conv_gemm (winograd_input, conv2d_gemm, winograd_output) / the direct row (conv2d)"))
