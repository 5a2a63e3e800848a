"""Resize over H and W (kernels/resize.cl): ONNX Resize (opsets 10-19) and Upsample.

Semantics are the ONNX spec's, evaluated in float32 as onnxruntime (the twin) does:

* Output size from scales is ``int(float32(scale) * in)`` (onnxruntime); the ONNX Python
  reference floors the float64 product, which differs when the float32 scale sits just
  below an integer product (2.3 * 10 -> 23 here and in onnxruntime, 22 in the reference).
* The scale in the coordinate transform is the given scale, or float32(out) / float32(in)
  when sizes are given; keep_aspect_ratio_policy takes the min/max of those and rounds
  ``scale * in`` half up, as onnxruntime.
* align_corners and pytorch_half_pixel use ``length_resized``, the integer output length,
  as the spec writes and onnxruntime and PyTorch do. The ONNX reference uses the
  fractional ``scale * in`` instead; the two node cases where that matters are listed
  in NODE_DEVIATIONS. pytorch_half_pixel with an output length of 1 maps to 0 (spec,
  onnxruntime; the reference uses -0.5, which only changes cubic).
* Coordinates are float32 on the device, operation by operation as onnxruntime (the
  reference uses float64; nearest can then pick the other pixel on an exact tie that
  float32 rounding creates or removes). The kernel needs correctly rounded float32
  division for that, which PoCL and oclgrind give (see the README section).
* tf_crop_and_resize takes the output size from sizes, or from scales ignoring the roi
  (onnxruntime and the reference; the spec's text scales the roi length).
"""
from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np
import pyopencl.cltypes as clt

from .. import selfcheck
from ..device import Device
from ..tolerance import DEFAULT_TOL, EXACT
from .base import Unsupported, as_str, check_storage, onnx_op, rng
from .conv import builtin_free, load_defines

MODES = ("nearest", "linear", "cubic")
COORDS = ("half_pixel", "half_pixel_symmetric", "align_corners", "asymmetric", "pytorch_half_pixel",
          "tf_crop_and_resize")
# "legacy" is Resize-10 / Upsample nearest: ceil when the axis down-scales, else floor.
NEAREST_MODES = ("round_prefer_floor", "round_prefer_ceil", "floor", "ceil", "legacy")
POLICIES = ("stretch", "not_larger", "not_smaller")

_COORD_DEFINE = {"half_pixel": 0, "align_corners": 1, "asymmetric": 2, "pytorch_half_pixel": 3,
                 "tf_crop_and_resize": 4, "half_pixel_symmetric": 5}
# Channels per work-item: coordinates and weights are computed once per pixel for them.
CHANNELS_PER_ITEM = 4
# Linear/cubic (no antialias, not tf_crop_and_resize): kernel resize_x8, 8 outputs
# along x per work-item; 0 selects the reference kernel `resize` (one output each).
RESIZE_X8 = 1

_f32 = np.float32


def _pair(v, name):
    if np.ndim(v) == 0:
        return (v, v)
    v = tuple(np.asarray(v).ravel().tolist())
    if len(v) != 2:
        raise ValueError(f"{name} must be one value or (H, W), got {v}")
    return v


def output_size(in_hw, out_hw=None, scales=None, policy: str = "stretch"):
    """(out_hw, float32 scales) as onnxruntime derives them: from scales the size is
    int(scale * in) in float32; from sizes the scale is out / in, adjusted by the
    keep_aspect_ratio policy. Both given: taken as they are."""
    if policy not in POLICIES:
        raise ValueError(f"keep_aspect_ratio_policy must be one of {POLICIES}, got {policy!r}")
    if scales is None and out_hw is None:
        raise ValueError("resize: give out_hw or scales")
    if scales is not None:
        sc = tuple(_f32(s) for s in _pair(scales, "scales"))
        if not all(np.isfinite(s) and s > 0 for s in sc):
            raise ValueError(f"resize: scales must be finite and > 0, got {scales}")
        if out_hw is None:
            out_hw = tuple(int(s * _f32(n)) for s, n in zip(sc, in_hw))
        return tuple(int(o) for o in _pair(out_hw, "out_hw")), sc
    out_hw = tuple(int(o) for o in _pair(out_hw, "out_hw"))
    if any(o < 0 for o in out_hw):
        raise ValueError(f"resize: negative output size {out_hw}")
    sc = tuple(_f32(o) / _f32(n) if n else _f32(1) for o, n in zip(out_hw, in_hw))
    if policy != "stretch":
        s = min(sc) if policy == "not_larger" else max(sc)
        sc = (s, s)
        out_hw = tuple(int(math.floor(float(s * _f32(n)) + 0.5)) for n in in_hw)
    return out_hw, sc


def _nearest_rule(m) -> int:
    if m not in NEAREST_MODES:
        raise ValueError(f"nearest_mode must be one of {NEAREST_MODES}, got {m!r}")
    return NEAREST_MODES.index(m)


_TABLES_KEPT = 256  # per device; a few KiB each


def _axis_tables(dev: Device, prec: str, defines: dict, mode: str, sizes, scales, off, roi, cubic_a):
    """Per-axis coordinates, taps and weights (kernels/resize.cl axis_tables) for one
    resize geometry, computed once on the device and kept: they cost O(Ho + Wo), the
    pixels O(Ho * Wo * C). Kept on the real device (a model's planned device hands
    its allocations out per call), so a geometry's tables outlive every launch using them."""
    base = getattr(dev, "base", dev)
    cache = base.__dict__.setdefault("_resize_tables", OrderedDict())
    key = (prec, tuple(sorted(defines.items())), tuple(sizes), tuple(float(v) for v in (*scales, *off, *roi, cubic_a)))
    hit = cache.get(key)
    if hit is not None:
        cache.move_to_end(key)
        return hit
    ho, wo, h, w = sizes
    taps = 1 if mode == "nearest" else (2 if mode == "linear" else 4)
    na = ho + wo
    tabs = (base.empty((na,), "fp32"), base.empty((na * taps,), "fp32", np.int32), base.empty((na * taps,), "fp32"))
    kt = base.kernel("resize", "axis_tables", prec, **defines)
    base.launch(kt, (na,), (np.int32(ho), np.int32(wo), np.int32(h), np.int32(w), _f32(scales[0]),
                            _f32(scales[1]), _f32(off[0]), _f32(off[1]),
                            clt.make_float4(*(float(v) for v in roi)), _f32(cubic_a),
                            *(t.data for t in tabs)))
    cache[key] = tabs
    while len(cache) > _TABLES_KEPT:
        cache.popitem(last=False)
    return tabs


def cubic_tables(dev: Device, prec: str, in_hw, out_hw, cubic_a: float = -0.75):
    """(coord, idx, wt): the axis tables `resize` uses for a cubic, half_pixel resize of
    in_hw to out_hw (no antialias, clamped edges), for a fused kernel of a method's room
    that resamples as resize_x8 does (clss/methods/bicubic/bicubic.cl)."""
    (ho, wo), (sy, sx) = output_size(tuple(in_hw), tuple(out_hw))
    defines = dict(MODE=MODES.index("cubic"), COORD=_COORD_DEFINE["half_pixel"], CPT=CHANNELS_PER_ITEM,
                   ANTIALIAS=0, EXCLUDE=0)
    return _axis_tables(dev, prec, defines, "cubic", (ho, wo, *in_hw), (sy, sx), (_f32(0), _f32(0)),
                        np.asarray((0, 0, 1, 1), np.float32), cubic_a)


def resize(dev: Device, prec: str, x, out_hw=None, scales=None, mode: str = "linear",
           coord: str = "half_pixel", nearest_mode="round_prefer_floor", cubic_a: float = -0.75,
           exclude_outside: bool = False, out=None, *, antialias: bool = False, roi=None,
           extrapolation_value: float = 0.0, keep_aspect_ratio_policy: str = "stretch",
           blocked: bool = False):
    """Resize [N,C,H,W] over H and W.

    out_hw / scales: (H, W) pairs or one value for both; see output_size(). mode: nearest,
    linear, cubic; coord: an ONNX coordinate_transformation_mode; nearest_mode: one mode or
    a (H, W) pair ("legacy": Resize-10/Upsample rounding). antialias: linear/cubic filter
    widened by 1/scale when down-scaling. roi: (h_start, w_start, h_end, w_end), used by
    tf_crop_and_resize, whose out-of-range samples are extrapolation_value. blocked: x is
    channel-blocked [N, Cb, H, W, B] (clss/model/layout.py): nearest modes, output blocked."""
    check_storage("x", x, prec)
    if blocked and (len(x.shape) != 5 or mode != "nearest" or coord == "tf_crop_and_resize"):
        raise ValueError("resize: blocked=True takes a channel-blocked [N, Cb, H, W, B] input and nearest "
                         "resizes only (not tf_crop_and_resize)")
    if len(x.shape) != 4 and not blocked:
        raise ValueError(f"resize: expected an NCHW tensor, got shape {x.shape}")
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if coord not in COORDS:
        raise ValueError(f"coord must be one of {COORDS}, got {coord!r}")
    if antialias and mode == "nearest":
        raise ValueError("resize: antialias applies to linear and cubic only")
    if antialias and coord == "tf_crop_and_resize":
        raise ValueError("resize: antialias with tf_crop_and_resize is not supported")
    n, c, h, w = x.shape[:4]
    if blocked:
        n, cb, h, w, blk = x.shape
    (ho, wo), (sy, sx) = output_size((h, w), out_hw, scales, keep_aspect_ratio_policy)
    want = (n, cb, ho, wo, blk) if blocked else (n, c, ho, wo)
    if out is None:
        out = dev.empty(want, prec)
    else:
        check_storage("out", out, prec)
        if tuple(out.shape) != want:
            raise ValueError(f"resize: out has shape {out.shape}, expected {want}")
    if out.size == 0:
        return out
    if h == 0 or w == 0:
        raise ValueError(f"resize: empty input {x.shape} cannot fill output {out.shape}")

    off = (_f32(0), _f32(0))
    if coord == "half_pixel_symmetric":
        # onnxruntime's float32 steps; the rest of its formula runs in double there.
        def offset(s, n_in, n_out):
            adjustment = _f32(n_out) / (s * _f32(n_in))
            return _f32(n_in) / _f32(2) * (_f32(1) - adjustment)
        off = (offset(sy, h, ho), offset(sx, w, wo))
    r = np.asarray((0, 0, 1, 1) if roi is None else roi, np.float32).ravel()
    if r.size != 4:
        raise ValueError(f"resize: roi must be (h_start, w_start, h_end, w_end), got {roi}")

    defines = dict(MODE=MODES.index(mode), COORD=_COORD_DEFINE[coord], CPT=CHANNELS_PER_ITEM)
    if mode == "nearest":
        ny, nx = (nearest_mode, nearest_mode) if isinstance(nearest_mode, str) else tuple(nearest_mode)
        defines.update(NEAREST_Y=_nearest_rule(ny), NEAREST_X=_nearest_rule(nx))
    else:
        defines["ANTIALIAS"] = int(bool(antialias))
        # Linear without antialias: excluding an outside tap and renormalising leaves the
        # edge pixel, which clamping gives too, so one build serves both.
        defines["EXCLUDE"] = int(bool(exclude_outside) and (mode == "cubic" or antialias))
    coord, idx, wt = _axis_tables(dev, prec, defines, mode, (ho, wo, h, w), (sy, sx), off, r, cubic_a)
    if blocked:
        # the pixels axis_tables chose, copied as whole channel blocks (clss/model/layout.py)
        dev.launch(dev.kernel("resize", "resize_nearest_blocked", prec, **defines, BLK=blk), (wo, ho, n * cb),
                   (x.data, out.data, *(np.int32(v) for v in (h, w, ho, wo, n * cb)), idx.data))
        return out
    x8 = (bool(RESIZE_X8) and mode != "nearest" and not antialias and defines["COORD"] != 4
          and selfcheck.enabled(dev, prec, "resize.x8"))
    near8 = (bool(RESIZE_X8) and mode == "nearest" and defines["COORD"] != 4
             and selfcheck.enabled(dev, prec, "resize.nearest_x8"))
    k = dev.kernel("resize", "resize_x8" if x8 or near8 else "resize", prec, **defines,
                   **load_defines(dev, prec, "resize"))
    cb = -(-c // CHANNELS_PER_ITEM)
    dev.launch(k, (-(-wo // 8) if x8 or near8 else wo, ho, n * cb),
               (x.data, out.data, np.int32(c), np.int32(h), np.int32(w), np.int32(ho), np.int32(wo),
                np.int32(n * cb), _f32(sy), _f32(sx), _f32(extrapolation_value), _f32(cubic_a),
                coord.data, idx.data, wt.data))
    return out


# --- ONNX -----------------------------------------------------------------------

def _full_rank(values, axes, rank, fill):
    full = [fill(i) for i in range(rank)]
    for v, a in zip(values, axes):
        full[a] = v
    return full


def _onnx_plan(shape, scales, sizes, axes, policy):
    """Full-rank (out_shape, float32 scales), as onnxruntime computes them."""
    rank = len(shape)
    if sizes is not None:
        out = _full_rank([int(s) for s in sizes], axes, rank, lambda i: shape[i])
        sc = [_f32(o) / _f32(n) if n else _f32(1) for o, n in zip(out, shape)]
        if policy != "stretch":
            s = (min if policy == "not_larger" else max)(sc[a] for a in axes)
            sc = [s if i in axes else _f32(1) for i in range(rank)]
            out = [int(math.floor(float(s * _f32(n)) + 0.5)) if i in axes else n
                   for i, n in enumerate(shape)]
        return out, sc
    sc = _full_rank([_f32(s) for s in scales], axes, rank, lambda i: _f32(1))
    return [int(s * _f32(n)) for s, n in zip(sc, shape)], sc


def _resize_onnx(dev, prec, x, scales, sizes, roi, axes, *, mode, coord, nearest_mode, cubic_a=-0.75,
                 exclude_outside=False, antialias=False, extrapolation_value=0.0, policy="stretch",
                 blocked=False):
    # a channel-blocked tensor (clss/model/layout.py) resizes as its NCHW shape says
    shape = (x.shape[0], x.shape[1] * x.shape[4], *x.shape[2:4]) if blocked else tuple(x.shape)
    rank = len(shape)
    if rank < 2:
        raise Unsupported(f"Resize of a rank-{rank} tensor (clss resizes the last two axes)")
    axes = [a + rank if a < 0 else a for a in (range(rank) if axes is None else axes)]
    if scales is None and sizes is None:
        raise Unsupported("Resize without scales or sizes")
    out_shape, sc = _onnx_plan(shape, scales, sizes, axes, policy)
    if roi is not None and roi.size:
        r = np.asarray(roi, np.float32).ravel()
        if r.size == 2 * len(axes) and len(axes) != rank:
            r = np.array(_full_rank(r[:len(axes)], axes, rank, lambda i: 0.0)
                         + _full_rank(r[len(axes):], axes, rank, lambda i: 1.0), np.float32)
        if r.size != 2 * rank:
            raise Unsupported(f"Resize roi of {r.size} values for rank {rank}")
    else:
        r = np.array([0.0] * rank + [1.0] * rank, np.float32)
    for i in range(rank - 2):
        crop = coord == "tf_crop_and_resize" and (r[i] != 0 or r[rank + i] != 1)
        if out_shape[i] != shape[i] or sc[i] != 1 or crop:
            raise Unsupported(f"Resize over axis {i} of rank {rank} (clss resizes the last two axes)")
    if blocked:
        return resize(dev, prec, x, out_hw=tuple(out_shape[-2:]), scales=(sc[-2], sc[-1]), mode=mode,
                      coord=coord, nearest_mode=nearest_mode, blocked=True)
    lead = int(np.prod(shape[:-2], dtype=np.int64))
    x4 = x.reshape(1, lead, shape[-2], shape[-1])
    y = resize(dev, prec, x4, out_hw=tuple(out_shape[-2:]), scales=(sc[-2], sc[-1]), mode=mode,
               coord=coord, nearest_mode=nearest_mode, cubic_a=cubic_a, exclude_outside=exclude_outside,
               antialias=antialias, roi=(r[rank - 2], r[rank - 1], r[2 * rank - 2], r[2 * rank - 1]),
               extrapolation_value=extrapolation_value)
    return y.reshape(*shape[:-2], *out_shape[-2:])


def _legacy(dev, prec, attrs, x, scales):
    """Resize-10 and Upsample: asymmetric coordinates, nearest or (bi)linear."""
    mode = as_str(attrs.get("mode", "nearest"))
    mode = {"bilinear": "linear"}.get(mode, mode)
    if mode not in ("nearest", "linear"):
        raise Unsupported(f"Resize-10/Upsample mode {mode!r}")
    return _resize_onnx(dev, prec, x, np.asarray(scales, np.float32).ravel(), None, None, None,
                        mode=mode, coord="asymmetric", nearest_mode="legacy")


@onnx_op("Resize", const_inputs=(1, 2, 3))
def _onnx_resize(dev, prec, attrs, inputs):
    x = inputs[0]
    if len(inputs) == 2:  # Resize-10: (X, scales); from opset 11 a second input alone is invalid
        return [_legacy(dev, prec, attrs, x, inputs[1])]
    roi = inputs[1]
    scales = inputs[2] if len(inputs) > 2 and inputs[2] is not None and inputs[2].size else None
    sizes = inputs[3] if len(inputs) > 3 and inputs[3] is not None and inputs[3].size else None
    mode = as_str(attrs.get("mode", "nearest"))
    coord = as_str(attrs.get("coordinate_transformation_mode", "half_pixel"))
    nearest = as_str(attrs.get("nearest_mode", "round_prefer_floor"))
    policy = as_str(attrs.get("keep_aspect_ratio_policy", "stretch"))
    antialias = bool(attrs.get("antialias", 0))
    if mode not in MODES:
        raise Unsupported(f"Resize mode {mode!r}")
    if coord not in COORDS:
        raise Unsupported(f"Resize coordinate_transformation_mode {coord!r}")
    if nearest not in NEAREST_MODES[:4]:
        raise Unsupported(f"Resize nearest_mode {nearest!r}")
    if policy not in POLICIES:
        raise Unsupported(f"Resize keep_aspect_ratio_policy {policy!r}")
    if antialias and (mode == "nearest" or coord == "tf_crop_and_resize"):
        raise Unsupported(f"Resize antialias with mode {mode!r} / {coord!r}")
    axes = attrs.get("axes")
    return [_resize_onnx(dev, prec, x, scales, sizes, roi, None if axes is None else list(axes),
                         mode=mode, coord=coord, nearest_mode=nearest,
                         cubic_a=float(attrs.get("cubic_coeff_a", -0.75)),
                         exclude_outside=bool(attrs.get("exclude_outside", 0)), antialias=antialias,
                         extrapolation_value=float(attrs.get("extrapolation_value", 0.0)), policy=policy,
                         blocked=bool(attrs.get("blocked")))]


@onnx_op("Upsample", const_inputs=(1,))
def _onnx_upsample(dev, prec, attrs, inputs):
    scales = attrs.get("scales") if len(inputs) < 2 or inputs[1] is None else inputs[1]
    if scales is None:
        raise Unsupported("Upsample without scales")
    return [_legacy(dev, prec, attrs, inputs[0], scales)]


NODE_DEVIATIONS = {
    name: "the ONNX reference takes align_corners' length_resized as the fractional scale*in "
          "(2.4 here); the spec's formula, onnxruntime (our twin) and PyTorch use the integer "
          "output length, as clss does"
    for name in ("test_resize_downsample_scales_linear_align_corners",
                 "test_resize_downsample_scales_cubic_align_corners")
}


# --- fast paths (clss/selfcheck.py) ----------------------------------------------

def _selfcheck_resize(dev: Device, prec: str) -> list[np.ndarray]:
    """Linear and cubic up- and down-sampling of rows off multiples of 8."""
    x = dev.to_device(rng("resize selfcheck").standard_normal((1, 3, 7, 13)).astype(np.float32), prec)
    return [dev.to_host(resize(dev, prec, x, hw, mode=m)) for m in ("linear", "cubic")
            for hw in ((14, 27), (5, 9))]


def _selfcheck_nearest(dev: Device, prec: str) -> list[np.ndarray]:
    """Nearest up- and down-sampling (the U-Nets' 2x, a fractional one) of rows off
    multiples of 8."""
    x = dev.to_device(rng("resize nearest selfcheck").standard_normal((1, 5, 7, 13)).astype(np.float32), prec)
    return [dev.to_host(resize(dev, prec, x, hw, mode="nearest", coord="asymmetric",
                               nearest_mode="floor")) for hw in ((14, 26), (5, 9), (11, 19))]


selfcheck.register(selfcheck.FastPath(
    "resize.nearest_x8", "resize", {"RESIZE_NEAREST_X8": 1}, {"RESIZE_NEAREST_X8": 0},
    check=_selfcheck_nearest, tolerance=lambda prec: EXACT,
    what="nearest resize: 8 outputs along x per work-item, copied as one vector (kernel "
         "resize_x8, MODE 0)"))

for _name, _fast, _ref, _what, _applies in (
        ("resize.x8", {"RESIZE_X8": 1}, {"RESIZE_X8": 0},
         "linear/cubic resize: 8 outputs along x per work-item (kernel resize_x8)", lambda dev: True),
        ("resize.builtin_free_loads", {"CLSS_CLANG_VECTORS": 1}, {"CLSS_CLANG_VECTORS": 0},
         "half loads/stores as clang vector conversions (PoCL)", builtin_free)):
    selfcheck.register(selfcheck.FastPath(_name, "resize", _fast, _ref, check=_selfcheck_resize,
                                          tolerance=DEFAULT_TOL.__getitem__, what=_what, applies=_applies))
