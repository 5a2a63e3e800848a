"""GridSample and the motion-vector warp (kernels/warp.cl).

``grid_sample`` is ONNX GridSample (opset 16 and 20, 2-D) as onnxruntime's CPU kernel
computes it: padding applies to every tap (onnxruntime 1.32 and PyTorch; the ONNX
Python reference clamps the position first, which differs for bicubic + border),
nearest rounds half to even. ``warp`` is the motion-vector form of the CLSS frame
(clss-frame.md stage 5): GridSample, align_corners = 0, of the grid that a per-pixel
motion field describes, computed in pixels so precision does not depend on image size.
Grids and the derived coordinates stay float32 in every precision; data is in the
storage precision; nearest copies bits.
"""
from __future__ import annotations

import numpy as np

from .. import selfcheck
from ..device import Device
from ..tolerance import DEFAULT_TOL
from .base import Unsupported, as_str, check_storage, onnx_op, rng
from .conv import builtin_free, load_defines

MODES = ("nearest", "bilinear", "bicubic")
PADDINGS = ("zeros", "border", "reflection")
# ONNX opset 20 renamed the modes; both spellings are accepted everywhere.
_MODE_ALIASES = {"nearest": 0, "bilinear": 1, "linear": 1, "bicubic": 2, "cubic": 2}
_OPSET20_NAME = {"nearest": "nearest", "bilinear": "linear", "bicubic": "cubic"}
# Channels per work-item: the taps and weights are computed once per output pixel and
# reused for this many channels (the whole 16-channel CLSS history in one work-item).
CHANNELS_PER_ITEM = 16


def _mode(mode: str) -> int:
    try:
        return _MODE_ALIASES[mode]
    except KeyError:
        raise ValueError(f"mode must be one of {', '.join(_MODE_ALIASES)}, got {mode!r}") from None


def _padding(padding: str) -> int:
    if padding not in PADDINGS:
        raise ValueError(f"padding must be one of {', '.join(PADDINGS)}, got {padding!r}")
    return PADDINGS.index(padding)


def _blocks(c: int, cpb: int | None) -> tuple[int, int]:
    cpb = max(1, min(int(cpb or CHANNELS_PER_ITEM), max(c, 1)))
    return cpb, -(-c // cpb)


def grid_sample(dev: Device, prec: str, x, grid, mode: str = "bilinear", padding: str = "zeros",
                align_corners: bool = False, *, cubic_channels: int = 0, out=None,
                channels_per_item: int | None = None):
    """x [N,C,Hi,Wi] (storage precision), grid [N,Ho,Wo,2] float32 (x, y in [-1, 1]) ->
    [N,C,Ho,Wo]. ``cubic_channels=k`` samples channels [0, k) bicubic, the rest with ``mode``."""
    check_storage("x", x, prec)
    if grid.dtype != np.float32:
        raise TypeError(f"grid: expected float32 (coordinates stay fp32 in every precision), got {grid.dtype}")
    n, c, hi, wi = x.shape
    if grid.ndim != 4 or grid.shape[0] != n or grid.shape[3] != 2:
        raise ValueError(f"grid_sample: grid {grid.shape} does not match input {x.shape}; expected [N,Ho,Wo,2]")
    ho, wo = grid.shape[1:3]
    out = out if out is not None else dev.empty((n, c, ho, wo), prec)
    if out.size == 0 or hi * wi == 0:
        return _zero_fill(dev, out)
    cpb, nblk = _blocks(c, channels_per_item)
    k = dev.kernel("warp", "grid_sample", prec, **_options(mode, padding, cubic_channels),
                   **load_defines(dev, prec, "warp"))
    dev.launch(k, (wo, ho, n * nblk), (x.data, grid.data, out.data,
                                       *map(np.int32, (c, hi, wi, ho, wo, cpb, nblk, n, bool(align_corners)))))
    return out


def warp(dev: Device, prec: str, x, motion, *, motion_scale=(1.0, 1.0), scale: float = 1.0,
         mode: str = "bicubic", padding: str = "zeros", cubic_channels: int = 0, out=None,
         channels_per_item: int | None = None):
    """Backward warp of x [N,C,Hi,Wi] by a motion field [N,2,Ho,Wo] (storage precision) -> [N,C,Ho,Wo].

    Output pixel (X, Y) reads x at pixel-index position (pixel i has its centre at i)
        xs = (X + 0.5) * Wi / Wo - 0.5 + motion[n, 0, Y, X] * motion_scale[0] * scale
        ys = (Y + 0.5) * Hi / Ho - 0.5 + motion[n, 1, Y, X] * motion_scale[1] * scale
    i.e. xs = X + mx when the sizes agree and both scales are 1 (``prev = p + motion``).
    ``motion_scale`` converts the renderer's units to its pixels (clss-frame.md), ``scale``
    those pixels to x's (e.g. 2 for render-resolution motion applied to a 2x history).
    Equals GridSample(x, grid, align_corners=0) with
        grid[n, Y, X] = ((2X + 1) / Wo - 1 + 2 mx kx / Wi,  (2Y + 1) / Ho - 1 + 2 my ky / Hi),
    (kx, ky) = motion_scale * scale (see ``twin_warp``). ``cubic_channels=k``: channels
    [0, k) bicubic, the rest ``mode`` (the CLSS history: k = 3, mode bilinear)."""
    check_storage("x", x, prec)
    check_storage("motion", motion, prec)
    n, c, hi, wi = x.shape
    if motion.ndim != 4 or motion.shape[0] != n or motion.shape[1] != 2:
        raise ValueError(f"warp: motion {motion.shape} does not match input {x.shape}; expected [N,2,Ho,Wo]")
    ho, wo = motion.shape[2:]
    out = out if out is not None else dev.empty((n, c, ho, wo), prec)
    if out.size == 0 or hi * wi == 0:
        return _zero_fill(dev, out)
    cpb, nblk = _blocks(c, channels_per_item)
    kx, ky = (float(s) * float(scale) for s in motion_scale)
    k = dev.kernel("warp", "warp_motion", prec, **_options(mode, padding, cubic_channels),
                   **load_defines(dev, prec, "warp"))
    dev.launch(k, (wo, ho, n * nblk),
               (x.data, motion.data, out.data, *map(np.int32, (c, hi, wi, ho, wo, cpb, nblk, n)),
                np.float32(wi / wo), np.float32(hi / ho), np.float32(kx), np.float32(ky)))
    return out


def _options(mode, padding, cubic_channels=0) -> dict:
    """Build options; align_corners is a run-time argument (see kernels/warp.cl)."""
    return dict(MODE=_mode(mode), PAD=_padding(padding), CUBIC_CHANNELS=int(cubic_channels))


def _zero_fill(dev, out):
    dev.fill(out, 0)        # through the device: a model's recorded launch plan keeps it
    return out


# --- ONNX -----------------------------------------------------------------------

NODE_DEVIATIONS = {
    f"test_gridsample_volumetric_{m}_align_corners_{a}":
        "5-D (volumetric) GridSample: the kernels are 2-D NCHW only"
    for m in ("bilinear", "nearest") for a in (0, 1)
}


@onnx_op("GridSample")
def _onnx_grid_sample(dev, prec, attrs, inputs):
    x, grid = inputs[:2]
    if x.ndim != 4:
        raise Unsupported(f"{x.ndim - 2}-D GridSample (only 2-D)")
    mode = as_str(attrs.get("mode", "linear"))
    padding = as_str(attrs.get("padding_mode", "zeros"))
    if mode not in _MODE_ALIASES:
        raise Unsupported(f"GridSample mode {mode!r}")
    if padding not in PADDINGS:
        raise Unsupported(f"GridSample padding_mode {padding!r}")
    ac = bool(attrs.get("align_corners", 0))
    if grid.dtype == np.float16:
        # An fp16 model stores its grid as half: widen it with the sampler's own build
        # (pyopencl's astype cannot touch half without cl_khr_fp16).
        wide = dev.empty(grid.shape, dtype=np.float32)
        if grid.size:
            dev.launch(dev.kernel("warp", "widen_half", prec, **_options(mode, padding)), (grid.size,),
                       (grid.data, wide.data, np.int32(grid.size)))
        grid = wide
    return [grid_sample(dev, prec, x, grid, mode, padding, ac)]


def _selfcheck_warp(dev: Device, prec: str) -> list[np.ndarray]:
    """GridSample bilinear and bicubic and the motion warp (3 bicubic + 2 bilinear
    channels), off-screen taps included."""
    g = rng("warp selfcheck")
    x = dev.to_device(g.standard_normal((1, 5, 7, 13)).astype(np.float32), prec)
    grid = dev.to_device(g.uniform(-1.2, 1.2, (1, 9, 11, 2)).astype(np.float32), "fp32")
    motion = dev.to_device(g.uniform(-3, 3, (1, 2, 7, 13)).astype(np.float32), prec)
    outs = [grid_sample(dev, prec, x, grid, m) for m in ("bilinear", "bicubic")]
    outs.append(warp(dev, prec, x, motion, cubic_channels=3, mode="bilinear"))
    return [dev.to_host(o) for o in outs]


selfcheck.register(selfcheck.FastPath(
    "warp.builtin_free_loads", "warp", {"CLSS_CLANG_VECTORS": 1}, {"CLSS_CLANG_VECTORS": 0},
    check=_selfcheck_warp, tolerance=DEFAULT_TOL.__getitem__,
    what="half loads/stores as clang vector conversions (PoCL)", applies=builtin_free))
