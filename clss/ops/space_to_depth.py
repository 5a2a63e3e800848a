"""SpaceToDepth / DepthToSpace (kernels/space_to_depth.cl): bit-exact data movement."""
from __future__ import annotations

import numpy as np

from .. import selfcheck
from .conv import builtin_free
from ..device import Device
from ..tolerance import EXACT
from .base import Unsupported, as_str, check_storage, onnx_op, rng

MODES = ("DCR", "CRD")


def _mode(mode: str) -> int:
    if mode not in MODES:
        raise ValueError(f"mode must be DCR or CRD, got {mode!r}")
    return int(mode == "CRD")


def space_to_depth(dev: Device, prec: str, x, block: int, mode: str = "DCR", out=None):
    """[N,C,H*b,W*b] -> [N,C*b*b,H,W]. DCR is ONNX SpaceToDepth; CRD is pixel_unshuffle."""
    check_storage("x", x, prec)
    n, c, hh, ww = x.shape
    if block < 1 or hh % block or ww % block:
        raise ValueError(f"space_to_depth: input {x.shape} height/width not divisible by block {block}")
    h, w = hh // block, ww // block
    out = out if out is not None else dev.empty((n, c * block * block, h, w), prec)
    k = dev.kernel("space_to_depth", "space_to_depth", prec, CRD=_mode(mode),
                   CLSS_CLANG_VECTORS=builtin_free(dev),
                   **selfcheck.defines(dev, prec, "space_to_depth.b2_vector_loads"))
    dev.launch(k, (-(-w // 8), h, n * c * block),
               (x.data, out.data, np.int32(c), np.int32(h), np.int32(w), np.int32(block),
                np.int32(n * c * block)))
    return out


def depth_to_space(dev: Device, prec: str, x, block: int, mode: str = "DCR", out=None):
    """[N,C*b*b,H,W] -> [N,C,H*b,W*b]. DCR and CRD as ONNX DepthToSpace."""
    check_storage("x", x, prec)
    n, cbb, h, w = x.shape
    if block < 1 or cbb % (block * block):
        raise ValueError(f"depth_to_space: {cbb} channels not divisible by block^2 = {block * block}")
    c = cbb // (block * block)
    out = out if out is not None else dev.empty((n, c, h * block, w * block), prec)
    k = dev.kernel("space_to_depth", "depth_to_space", prec, CRD=_mode(mode),
                   CLSS_CLANG_VECTORS=builtin_free(dev),
                   **selfcheck.defines(dev, prec, "space_to_depth.b2_vector_loads"))
    dev.launch(k, (-(-w // 8), h, n * c * block),
               (x.data, out.data, np.int32(c), np.int32(h), np.int32(w), np.int32(block),
                np.int32(n * c * block)))
    return out


def _selfcheck_run(dev: Device, prec: str) -> list[np.ndarray]:
    """Both B = 2 paths (whole 8-column runs and the scalar tail) in both channel orders,
    both directions."""
    x = rng("s2d selfcheck").standard_normal((1, 3, 4, 2 * 11)).astype(np.float32)
    xd = dev.to_device(x, prec)
    y = rng("d2s selfcheck").standard_normal((1, 3 * 4, 3, 11)).astype(np.float32)
    yd = dev.to_device(y, prec)
    return ([dev.to_host(space_to_depth(dev, prec, xd, 2, m)) for m in MODES]
            + [dev.to_host(depth_to_space(dev, prec, yd, 2, m)) for m in MODES])


selfcheck.register(selfcheck.FastPath(
    "space_to_depth.b2_vector_loads", "space_to_depth", fast={"S2D_VEC": 1}, reference={"S2D_VEC": 0},
    check=_selfcheck_run, tolerance=lambda prec: EXACT,
    what="B = 2 de-interleave through two vload8 and .even/.odd (SpaceToDepth), interleave through two "
         "vstore8 (DepthToSpace)"))


# --- ONNX -----------------------------------------------------------------------

@onnx_op("SpaceToDepth")
def _onnx_s2d(dev, prec, attrs, inputs):
    return [space_to_depth(dev, prec, inputs[0], int(attrs["blocksize"]))]


@onnx_op("DepthToSpace")
def _onnx_d2s(dev, prec, attrs, inputs):
    mode = as_str(attrs.get("mode", "DCR"))
    if mode not in MODES:
        raise Unsupported(f"DepthToSpace mode {mode!r}")
    return [depth_to_space(dev, prec, inputs[0], int(attrs["blocksize"]), mode)]
