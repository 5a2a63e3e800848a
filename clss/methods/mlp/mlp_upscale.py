"""The shader MLP upscaler's two kernels (mlp_upscale.cl, beside this file): the fused gather +
DC removal + gamma ramp + 50-50-50-25 MLP per render pixel (`blocks`), and the overlap
average + PQ decode per output pixel (`fold`). The constants and geometry arrive as -D
options (`defines`, built by clss.methods.mlp.transform.kernel_defines, the one place
they are written); their ONNX twins are in clss/verify/cases/mlp_upscale.py."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ... import selfcheck
from ...device import Device
from ...ops.base import check_storage

KERNEL = Path(__file__).with_name("mlp_upscale.cl")

# Work-group shape: a fixed one, so PoCL compiles one work-group function per build, not
# one per frame size (the kernels guard their bounds).
LOCAL = (16, 4)
VLOCAL = (4, 4)       # the pixel-vector kernel: VEC pixels per work-item already
WEIGHT_COUNT = 50 * 50 + 50 + 50 * 50 + 50 + 25 * 50 + 25


def _round_up(n, m):
    return -(-int(n) // m) * m


def pack_weights(dev: Device, prec: str, flat: np.ndarray):
    """The packed weights (float32 [WEIGHT_COUNT]) on the device; in fp16 storage mode
    rounded to half first, as every fp16 weight of clss is."""
    flat = np.asarray(flat, np.float32).reshape(-1)
    if flat.size != WEIGHT_COUNT:
        raise ValueError(f"mlp_upscale: {flat.size} packed weights, expected {WEIGHT_COUNT}")
    if prec != "fp32":
        flat = flat.astype(np.float16).astype(np.float32)
    return dev.to_device(flat, "fp32")


FAST = "mlp_upscale.pixel_vectors"


def blocks(dev: Device, prec: str, color, feat, weights, defines: dict, *,
           inv_exposure=1.0, pq_scale=0.01, out=None, vec=None, events=None):
    """color [h, w, 3] linear, feat [H, W] (any [H, W] array when FEATURE=0), weights from
    pack_weights -> blocks [3, B*B, h, w] (PQ domain). vec: None (the fast path where its
    self-check passed on this device, else the reference), 1 (the reference kernel) or 8/16
    (the pixel-vector kernel, VEC pixels per work-item, after a PQ pass). events: a list
    that gets each launch's event (a profiled frame step's timings)."""
    ev = _recorder(events)
    check_storage("color", color, prec)
    check_storage("feat", feat, prec)
    if weights.dtype != np.float32 or weights.size != WEIGHT_COUNT:
        raise ValueError("mlp_upscale.blocks: weights must come from pack_weights")
    h, w, c = color.shape
    if c != 3:
        raise ValueError(f"color: expected [h, w, 3], got {color.shape}")
    s, b = int(defines["S"]), int(defines["B"])
    H, W = feat.shape[:2]
    if (H, W) != (s * h, s * w):
        raise ValueError(f"feat: expected [{s * h}, {s * w}] at scale {s}, got {feat.shape}")
    if out is None:
        out = dev.empty((3, b * b, h, w), prec)
    v = int(selfcheck.defines(dev, prec, FAST)["VEC"]) if vec is None else int(vec)
    if v > 1:
        opts = dict(defines, VEC=v)
        pq = dev.empty((3, h, w), "fp32")
        ev(dev.launch(dev.kernel(KERNEL, "mlp_upscale_pq", prec, **opts),
                      (_round_up(w, LOCAL[0]), _round_up(h, LOCAL[1])),
                      (color.data, pq.data, np.int32(h), np.int32(w), np.float32(inv_exposure),
                       np.float32(pq_scale)), local_size=LOCAL))
        ev(dev.launch(dev.kernel(KERNEL, "mlp_upscale_blocks_v", prec, **opts),
                      (_round_up(-(-w // v), VLOCAL[0]), _round_up(h, VLOCAL[1])),
                      (pq.data, feat.data, weights.data, out.data, np.int32(h), np.int32(w),
                       np.int32(H), np.int32(W)), local_size=VLOCAL))
        return out
    kern = dev.kernel(KERNEL, "mlp_upscale_blocks", prec, **defines)
    ev(dev.launch(kern, (_round_up(w, LOCAL[0]), _round_up(h, LOCAL[1])),
                  (color.data, feat.data, weights.data, out.data, np.int32(h), np.int32(w),
                   np.int32(H), np.int32(W), np.float32(inv_exposure), np.float32(pq_scale)),
                  local_size=LOCAL))
    return out


def _recorder(events):
    """A function that appends a launch's event to `events` (None: drops it)."""
    return (lambda e: None) if events is None else events.append


def fold(dev: Device, prec: str, blk, defines: dict, *, exposure=1.0, inv_pq_scale=100.0,
         out=None, events=None):
    """blocks [3, B*B, h, w] -> [H, W, 3] linear: each output pixel the mean of the blocks
    covering it, PQ-decoded, times exposure."""
    check_storage("blocks", blk, prec)
    s, b = int(defines["S"]), int(defines["B"])
    _, bb, h, w = blk.shape
    if bb != b * b:
        raise ValueError(f"blocks: expected {b * b} block units at scale {s}, got {bb}")
    H, W = s * h, s * w
    if out is None:
        out = dev.empty((H, W, 3), prec)
    kern = dev.kernel(KERNEL, "mlp_upscale_fold", prec, **defines)
    _recorder(events)(dev.launch(kern, (_round_up(W, LOCAL[0]), _round_up(H, LOCAL[1])),
                                 (blk.data, out.data, np.int32(h), np.int32(w), np.int32(H),
                                  np.int32(W), np.float32(exposure), np.float32(inv_pq_scale)),
                                 local_size=LOCAL))
    return out


FUSED = "mlp_upscale.fused"
FUSED_VEC = 16       # render pixels (blocks) per vector: 15 owned, one for the neighbour
FUSED_ROWS = 32       # block rows a work-item of the fused kernel walks down


def frame(dev: Device, prec: str, color, feat, weights, defines: dict, *, exposure=1.0,
          pq_scale=0.01, inv_pq_scale=100.0, out=None, blk=None, pq=None, fused=None, rows=None, vec=None,
          events=None):
    """The whole frame step: color [h, w, 3] linear, feat [H, W] -> [H, W, 3] linear.
    fused: None (the fused fast path where its self-check passed on this device, else the
    reference pair blocks + fold, which writes its blocks to `blk` when given), False (the
    reference pair) or True (mlp_upscale_pq_v + mlp_upscale_fused, `vec` lanes, `rows` block
    rows per work-item; `pq` its [3, h, w] float32 scratch when given). events: a list that
    gets each launch's event."""
    check_storage("color", color, prec)
    check_storage("feat", feat, prec)
    h, w, _ = color.shape
    s = int(defines["S"])
    H, W = s * h, s * w
    if out is None:
        out = dev.empty((H, W, 3), prec)
    if fused is None:
        fused = selfcheck.enabled(dev, prec, FUSED)
    if not fused:
        blk = blocks(dev, prec, color, feat, weights, defines, inv_exposure=1.0 / exposure,
                     pq_scale=pq_scale, out=blk, events=events)
        return fold(dev, prec, blk, defines, exposure=exposure, inv_pq_scale=inv_pq_scale,
                    out=out, events=events)
    if weights.dtype != np.float32 or weights.size != WEIGHT_COUNT:
        raise ValueError("mlp_upscale.frame: weights must come from pack_weights")
    if feat.shape[:2] != (H, W):
        raise ValueError(f"feat: expected [{H}, {W}] at scale {s}, got {feat.shape}")
    v = int(vec or FUSED_VEC)
    opts = dict(defines, VEC=v, FUSED=1)
    rows = FUSED_ROWS if rows is None else int(rows)
    if pq is None:
        pq = dev.empty((3, h, w), "fp32")
    ev = _recorder(events)
    ev(dev.launch(dev.kernel(KERNEL, "mlp_upscale_pq_v", prec, **opts),
                  (_round_up(-(-w // v), VLOCAL[0]), _round_up(h, VLOCAL[1])),
                  (color.data, pq.data, np.int32(h), np.int32(w), np.float32(1.0 / exposure),
                   np.float32(pq_scale)), local_size=VLOCAL))
    ev(dev.launch(dev.kernel(KERNEL, "mlp_upscale_fused", prec, **opts),
                  (-(-(w + 1) // (v - 1)), -(-(h + 1) // rows)),
                  (pq.data, feat.data, weights.data, out.data, np.int32(h), np.int32(w),
                   np.int32(H), np.int32(W), np.int32(rows), np.float32(exposure),
                   np.float32(inv_pq_scale)), local_size=(1, 1)))
    return out


# The fast path (VEC pixel vectors) is registered with clss.selfcheck by fastpath.py,
# whose check runs the method's own geometry and weights.
