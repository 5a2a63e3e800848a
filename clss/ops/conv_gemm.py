"""The implicit-GEMM rows of the conv2d variant table (kernels/conv_gemm.cl): tiles staged
in local memory (`gemm`), read from global memory (`gemm_global`), and tensor cores through
inline PTX mma.sync (`mma`, NVIDIA only), with the tensor-core data layout emulated in scalar
code for every other device (CONV_MMA=1: tests and oclgrind check it on the CPU).

conv.py's chooser (clss/ops/variants.py) decides when they run; this module launches them
and registers their self-checks, each against the conv2d the device would run otherwise."""
from __future__ import annotations

import numpy as np

from .. import selfcheck
from . import variants
from ..device import Device
from ..tolerance import DEFAULT_TOL
from .base import rng

# A work-group's tile (TM channels x TN pixels, k in steps of TK) and a work-item's register
# tile (RM x RN): 16 x 16 work-items, 16 accumulators each, 8 KB of local memory in fp32.
DEFAULTS = {"TM": 64, "TN": 64, "TK": 16, "RM": 4, "RN": 4}
TUNABLES = {"TM": (32, 64, 128), "TN": (32, 64, 128), "TK": (8, 16, 32), "RM": (2, 4, 8), "RN": (2, 4, 8)}
# Tensor cores: one warp per 16 channels (TM / 16 warps), TN / 8 m16n8k16 products per warp
# and k step of 16: 4 warps of 8 products, 32 accumulators a lane.
MMA_DEFAULTS = {"TM": 64, "TN": 64, "TK": 32}
MMA_TUNABLES = {"TM": (32, 64, 128), "TN": (32, 64, 128), "TK": (16, 32, 64)}


def has_mma(dev: Device) -> bool:
    """NVIDIA's OpenCL on a GPU with mma.sync m16n8k16 (compute capability 8.0 and up)."""
    if dev.is_cpu or "nvidia" not in dev.info.platform.lower():
        return False
    try:
        return int(dev.cl_device.compute_capability_major_nv) >= 8
    except Exception:           # no cl_nv_device_attribute_query: let the self-check decide
        return True


def launch(dev: Device, prec: str, layer, call, act: int, flags: int, *, key: str, variant: str,
           local: int = 1, mma: int = 0):
    """conv2d_gemm on an NCHW layer (conv.ConvLayer, conv.ConvCall); mma: 0, 1 (emulated, fp16
    storage) or 2 (PTX). Tiles: the defaults < shipped table < tuned entry < `call.tuning`."""
    n, cin, h, wd = layer.x
    cout, cin_g, kh, kw = layer.w
    group = layer.group
    cout_g = cout // group
    (sy, sx), (dy, dx), (pt, pl) = layer.strides, layer.dilations, layer.pads[:2]
    if mma and prec != "fp16":
        raise ValueError("conv2d: the tensor-core variant needs fp16 storage (precision 'fp16')")
    t = variants.params(dev, "conv2d", key, variant, MMA_DEFAULTS if mma else DEFAULTS, call.tuning)
    tiles = {k: t[k] for k in ("TM", "TN", "TK")} if mma else {k: t[k] for k in ("TM", "TN", "TK", "RM", "RN")}
    if mma:
        if t["TM"] % 16 or t["TN"] % 8 or t["TK"] % 16:
            raise ValueError(f"conv2d: tensor-core tile TM={t['TM']} TN={t['TN']} TK={t['TK']} is not a "
                             f"multiple of 16 x 8 x 16")
        ls = (32, t["TM"] // 16, 1)
    else:
        if t["TM"] % t["RM"] or t["TN"] % t["RN"]:
            raise ValueError(f"conv2d: tile TM={t['TM']} TN={t['TN']} is not a multiple of RM={t['RM']} "
                             f"RN={t['RN']}")
        # a device whose work-groups are smaller than the tile's (some take 128 or 256
        # work-items): each work-item takes more of the tile, the tile stays
        limit = int(dev.cl_device.max_work_group_size)
        while (t["TN"] // t["RN"]) * (t["TM"] // t["RM"]) > limit:
            if t["RN"] < t["TN"] and (t["RN"] <= t["RM"] or t["RM"] == t["TM"]):
                t["RN"] *= 2
            else:
                t["RM"] *= 2
        ls = (t["TN"] // t["RN"], t["TM"] // t["RM"], 1)
        tiles.update(RM=t["RM"], RN=t["RN"])
    k = dev.kernel("conv_gemm", "conv2d_gemm", prec, KH=kh, KW=kw, ACT=act, CONV_LOCAL=int(local),
                   CONV_MMA=int(mma), **tiles, **d2s_defines(getattr(call, "d2s", None)))
    gs = (-(-ho_wo(call) // t["TN"]) * ls[0], -(-cout_g // t["TM"]) * ls[1], n * group)
    dev.launch(k, gs,
               (call.x.data, call.w.data, None if call.b is None else call.b.data,
                None if call.residual is None else call.residual.data, call.out.data,
                *(np.int32(v) for v in (cin, h, wd, cout, call.ho, call.wo, cin_g, cout_g, group,
                                        sy, sx, pt, pl, dy, dx, flags)),
                np.float32(call.alpha)),
               local_size=ls)
    return call.out


def d2s_defines(d2s) -> dict:
    """-DD2S, -DD2S_CRD of a DepthToSpace fused into a conv's store (kernels/d2s_index.h), from
    ConvCall.d2s = (r, crd); none without one, so the program is the same as before."""
    return {} if not d2s else {"D2S": int(d2s[0]), "D2S_CRD": int(d2s[1])}


def ho_wo(call) -> int:
    return int(call.ho) * int(call.wo)


def _selfcheck(variant: str, conv2d):
    def check(dev: Device, prec: str) -> list[np.ndarray]:
        """The variant against the conv2d the device runs otherwise: a 3x3 layer with ragged
        tiles (37 channels, 9 x 23 pixels, 75 taps), stride 2 with a dilation and asymmetric
        pads, a grouped 1x1 layer with a residual after the activation, a batch of 2. Small:
        it runs under oclgrind too."""
        g = rng("conv gemm selfcheck")
        outs = []
        for n, cin, cout, hw, k, s, d, pads, grp, act, res in (
                (1, 5, 37, (9, 23), 3, 1, 1, (1, 1, 1, 1), 1, "relu", None),
                (2, 6, 9, (11, 13), 3, 2, 2, (2, 0, 1, 2), 1, "leaky_relu", "before"),
                (1, 8, 12, (5, 7), 1, 1, 1, (0, 0, 0, 0), 2, "sigmoid", "after")):
            x = dev.to_device(g.standard_normal((n, cin) + hw).astype(np.float32), prec)
            w = dev.to_device(g.standard_normal((cout, cin // grp, k, k)).astype(np.float32) * 0.3, prec)
            b = dev.to_device(g.standard_normal(cout).astype(np.float32), prec)
            ho = (hw[0] + pads[0] + pads[2] - d * (k - 1) - 1) // s + 1
            wo = (hw[1] + pads[1] + pads[3] - d * (k - 1) - 1) // s + 1
            r = (dev.to_device(g.standard_normal((n, cout, ho, wo)).astype(np.float32), prec) if res else None)
            outs.append(dev.to_host(conv2d(dev, prec, x, w, b, strides=(s, s), pads=pads, dilations=(d, d),
                                           group=grp, activation=act, residual=r,
                                           residual_before_act=res == "before",
                                           tuning={"VARIANT": variant})))
        return outs
    return check


def register_selfchecks(conv2d) -> None:
    """The rows' fast paths, each checked through conv2d's chooser (clss/ops/conv.py calls this
    with its conv2d, which imports this module)."""
    for name, variant, what, applies in (
            ("conv.gemm", "gemm", "implicit-GEMM conv, tiles staged in local memory (conv2d_gemm, CONV_LOCAL=1) / "
             "the conv2d variant the device runs otherwise", lambda dev: True),
            ("conv.gemm_global", "gemm_global", "implicit-GEMM conv, operands read from global memory "
             "(conv2d_gemm, CONV_LOCAL=0) / the conv2d variant the device runs otherwise", lambda dev: True),
            ("conv.mma", "mma", "implicit-GEMM conv on tensor cores, mma.sync through inline PTX (conv2d_gemm, "
             "CONV_MMA=2; fp16 storage) / the conv2d variant the device runs otherwise", has_mma)):
        selfcheck.register(selfcheck.FastPath(
            name, "conv_gemm", {"VARIANT": variant}, {"VARIANT": "other"}, check=_selfcheck(variant, conv2d),
            tolerance=DEFAULT_TOL.__getitem__, what=what, applies=applies))
