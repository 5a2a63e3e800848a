"""Pooling (kernels/pool.cl): MaxPool, AveragePool, GlobalAveragePool, GlobalMaxPool.

NCHW with 1, 2 or 3 spatial dimensions (a 2-D tensor is pooled as depth 1).
Max pooling selects stored values and is bit-exact; average pooling sums in
float. Window geometry follows onnxruntime: output size
floor/ceil((in + pad_begin + pad_end - ((k - 1) * dilation + 1)) / stride) + 1,
in ceil mode a last window that would start in the end padding is dropped,
and auto_pad SAME_* pads ceil(in / stride) outputs' worth (kernel without dilation).
"""
from __future__ import annotations

import numpy as np

from .. import selfcheck
from ..device import Device
from ..tolerance import DEFAULT_TOL, EXACT
from .base import Unsupported, as_str, check_storage, onnx_op, rng
from .conv import builtin_free

AUTO_PADS = ("NOTSET", "VALID", "SAME_UPPER", "SAME_LOWER")
# Elements one work-item reduces in the first pass of global pooling.
GLOBAL_CHUNK = 2048
# Every -D combination the launches use, for build checks (fp16-native included,
# which PoCL cannot compile): (defines) of kernels/pool.cl.
BUILD_VARIANTS = ([dict(MODE=0), dict(MODE=0, INDICES=1), dict(MODE=1), dict(MODE=1, COUNT_PAD=1)]
                  + [dict(MODE=m, FINAL=f) for m in (0, 1) for f in (0, 1)])


def _per_dim(v, nd: int, default: int, name: str) -> list[int]:
    if v is None:
        return [default] * nd
    if isinstance(v, (int, np.integer)):
        return [int(v)] * nd
    v = [int(x) for x in v]
    if len(v) != nd:
        raise ValueError(f"{name} has {len(v)} values for {nd} spatial dimensions")
    return v


def pool_geometry(in_sizes, kernel, stride=None, pads=None, dilation=None, ceil_mode=False,
                  auto_pad="NOTSET"):
    """Output sizes and (begin, end) pads per spatial dim, as onnxruntime computes them.

    pads: ONNX order [x1_begin, x2_begin, ..., x1_end, x2_end, ...], or one int for all."""
    nd = len(in_sizes)
    k = _per_dim(kernel, nd, 1, "kernel")
    s = _per_dim(stride, nd, 1, "stride")
    d = _per_dim(dilation, nd, 1, "dilation")
    if isinstance(pads, (int, np.integer)):
        p = [int(pads)] * (2 * nd)
    else:
        p = [0] * (2 * nd) if pads is None else [int(x) for x in pads]
    if len(p) != 2 * nd:
        raise ValueError(f"pads needs {2 * nd} values (begins then ends), got {len(p)}")
    if auto_pad not in AUTO_PADS:
        raise ValueError(f"auto_pad must be one of {AUTO_PADS}, got {auto_pad!r}")
    if min(k + s + d) < 1:
        raise ValueError(f"kernel, stride and dilation must be >= 1: {k}, {s}, {d}")
    outs, begins, ends = [], [], []
    for i, n in enumerate(in_sizes):
        if auto_pad == "VALID":
            pb = pe = 0
        elif auto_pad.startswith("SAME"):
            need = max(0, (-(-n // s[i]) - 1) * s[i] + k[i] - n)
            pb = need // 2 if auto_pad == "SAME_UPPER" else (need + 1) // 2
            pe = need - pb
        else:
            pb, pe = p[i], p[nd + i]
        span = n + pb + pe - ((k[i] - 1) * d[i] + 1)
        if span < 0:
            raise ValueError(f"pooling window {(k[i] - 1) * d[i] + 1} exceeds padded input "
                             f"{n + pb + pe} in spatial dim {i}")
        o = (-(-span // s[i]) if ceil_mode else span // s[i]) + 1
        if ceil_mode and (o - 1) * s[i] >= n + pb:
            o -= 1  # the last window would start in the end padding
        outs.append(o)
        begins.append(pb)
        ends.append(pe)
    return outs, begins, ends, k, s, d


def _as3(v, fill):
    return [fill] * (3 - len(v)) + list(v)


# 2-D max pooling 3 wide along x with unit stride and dilation there (3x3 / 1 /
# 1, the frame's neighbourhood max): kernel max_pool_row8, 8 outputs per
# work-item; 0 selects the reference kernel `pool` for every case.
POOL_ROW8 = 1
# Output rows per max_pool_row8 work-item when the window has unit stride and
# dilation along y (the 3x3 / 1 / 1 neighbourhood max): each input row is read and
# reduced once for all of them. 1 keeps one row per work-item.
POOL_ROWS = 4


def _pool(dev, prec, x, mode, kernel, stride, pads, dilation, ceil_mode, auto_pad,
          count_include_pad=False, indices=False, column_major=False, out=None):
    check_storage("x", x, prec)
    if x.ndim not in (3, 4, 5):
        raise ValueError(f"pooling needs [N, C, spatial...] with 1-3 spatial dims, got shape {x.shape}")
    sp = list(x.shape[2:])
    o, pb, pe, k, s, d = pool_geometry(sp, kernel, stride, pads, dilation, ceil_mode, auto_pad)
    if column_major and len(sp) != 2:
        raise ValueError("storage_order=1 (column-major indices) is defined for 2-D pooling only")
    n, c = x.shape[:2]
    out = out if out is not None else dev.empty((n, c, *o), prec)
    idx = dev.empty((n, c, *o), dtype=np.int64) if indices else None
    if out.size == 0:
        return (out, idx) if indices else out
    (ID, IH, IW), (OD, OH, OW) = _as3(sp, 1), _as3(o, 1)
    K, S, D, P = _as3(k, 1), _as3(s, 1), _as3(d, 1), _as3(pb, 0)
    E = [a + b for a, b in zip((ID, IH, IW), _as3(pe, 0))]
    defines = dict(MODE=mode)
    if mode == 1:
        defines["COUNT_PAD"] = int(bool(count_include_pad))
    if indices:
        defines["INDICES"] = 1
    if (POOL_ROW8 and mode == 0 and not indices and len(sp) == 2 and K[2] == 3 and S[2] == 1
            and D[2] == 1 and selfcheck.enabled(dev, prec, "pool.row8")):
        # fp16: vload_half8 measured faster here than the clang conversion (PoCL 3.0)
        rows = POOL_ROWS if S[1] == 1 and D[1] == 1 else 1
        kern = dev.kernel("pool", "max_pool_row8", prec, POOL_ROWS=rows,
                          CLSS_CLANG_VECTORS=builtin_free(dev) if prec != "fp16" else 0)
        dev.launch(kern, (-(-OW // 8), -(-OH // rows), n * c),
                   (x.data, out.data, *(np.int32(v) for v in (IH, IW, OH, OW, K[1], S[1], P[1], P[2],
                                                               D[1], n * c))))
        return out
    if (mode == 0 and not indices and len(sp) == 2 and K[1:] == [2, 2] and S[1:] == [2, 2]
            and D[1:] == [1, 1] and not any(pb) and (OH, OW) == (IH // 2, IW // 2)
            and selfcheck.enabled(dev, prec, "pool.max2x2")):
        kern = dev.kernel("pool", "max_pool_2x2", prec,
                          CLSS_CLANG_VECTORS=builtin_free(dev) if prec != "fp16" else 0)
        dev.launch(kern, (-(-OW // 8), OH, n * c),
                   (x.data, out.data, *(np.int32(v) for v in (IH, IW, OH, OW, n * c))))
        return out
    kern = dev.kernel("pool", "pool", prec, **defines)
    extra = (idx.data, np.int32(column_major)) if indices else ()
    ints = [ID, IH, IW, OD, OH, OW, *K, *S, *P, *D, *E, n * c * OD]
    dev.launch(kern, (OW, OH, n * c * OD), (x.data, out.data, *extra, *(np.int32(v) for v in ints)))
    return (out, idx) if indices else out


def max_pool(dev: Device, prec: str, x, kernel, stride=None, pads=None, dilation=None,
             ceil_mode: bool = False, auto_pad: str = "NOTSET", return_indices: bool = False,
             storage_order: int = 0, out=None, blocked: bool = False):
    """ONNX MaxPool. Padding never wins (it is -inf); ties keep the first maximum.
    With return_indices, also the flat index into x of each maximum (int64, as ONNX
    Indices; storage_order=1 numbers a 2-D plane column-major). blocked: x is
    channel-blocked [N, Cb, H, W, B] (clss/model/layout.py); the 2x2 / 2 window only."""
    if blocked:
        if x.ndim != 5 or not blocked_2x2(kernel, stride, pads, dilation, ceil_mode, auto_pad) or return_indices:
            raise ValueError("max_pool: a channel-blocked input takes the 2x2 / 2 window without padding")
        return max_pool_2x2_blocked(dev, prec, x, out)
    return _pool(dev, prec, x, 0, kernel, stride, pads, dilation, ceil_mode, auto_pad,
                 indices=return_indices, column_major=bool(storage_order), out=out)


def blocked_2x2(kernel, stride=None, pads=None, dilation=None, ceil_mode=False, auto_pad="NOTSET") -> bool:
    """The pool the channel-blocked layout covers: 2x2 windows at stride 2, no padding,
    dilation 1, floor output (the U-Nets' down-sampling)."""
    def ints(v, default):
        return default if v is None else [int(a) for a in v]
    return (ints(kernel, []) == [2, 2] and ints(stride, [1, 1]) == [2, 2] and not any(ints(pads, []))
            and ints(dilation, [1, 1]) == [1, 1] and not ceil_mode and auto_pad in ("NOTSET", "VALID"))


def max_pool_2x2_blocked(dev: Device, prec: str, x, out=None):
    """2x2 / 2 max pool of a channel-blocked [N, Cb, H, W, B] tensor, bit-identical to
    max_pool on the NCHW layout (kernels/pool.cl max_pool_2x2_blocked)."""
    check_storage("x", x, prec)
    n, cb, h, w, blk = x.shape
    oh, ow = h // 2, w // 2
    out = out if out is not None else dev.empty((n, cb, oh, ow, blk), prec)
    if out.size:
        dev.launch(dev.kernel("pool", "max_pool_2x2_blocked", prec, BLK=blk), (ow, oh, n * cb),
                   (x.data, out.data, *(np.int32(v) for v in (h, w, oh, ow, n * cb))))
    return out


def avg_pool(dev: Device, prec: str, x, kernel, stride=None, pads=None, dilation=None,
             ceil_mode: bool = False, count_include_pad: bool = False, auto_pad: str = "NOTSET", out=None):
    """ONNX AveragePool. count_include_pad divides by the taps inside the padded
    extent (never the ceil-mode overhang), otherwise by the taps inside x."""
    return _pool(dev, prec, x, 1, kernel, stride, pads, dilation, ceil_mode, auto_pad,
                 count_include_pad=count_include_pad, out=out)


def _global(dev, prec, x, mode, chunk, out):
    check_storage("x", x, prec)
    if x.ndim < 3:
        raise ValueError(f"global pooling needs [N, C, spatial...], got shape {x.shape}")
    n, c = x.shape[:2]
    hw = int(np.prod(x.shape[2:]))
    out = out if out is not None else dev.empty((n, c) + (1,) * (x.ndim - 2), prec)
    nc = n * c
    if nc == 0:
        return out
    if hw == 0:
        raise ValueError(f"global pooling over an empty spatial extent {x.shape}")
    chunk = int(chunk or GLOBAL_CHUNK)
    nchunks = -(-hw // chunk)
    count = np.float32(hw)
    lanes = dict(selfcheck.defines(dev, prec, "pool.global_vector_lanes"),
                 CLSS_CLANG_VECTORS=builtin_free(dev))
    if nchunks == 1:
        k = dev.kernel("pool", "global_pool_partial", prec, MODE=mode, CHUNK=chunk, FINAL=1, **lanes)
        dev.launch(k, (1, nc), (x.data, out.data, np.int32(hw), np.int32(1), np.int32(nc), count))
        return out
    part = dev.empty((nc, nchunks), dtype=np.float32)
    k1 = dev.kernel("pool", "global_pool_partial", prec, MODE=mode, CHUNK=chunk, **lanes)
    dev.launch(k1, (nchunks, nc), (x.data, part.data, np.int32(hw), np.int32(nchunks), np.int32(nc), count))
    k2 = dev.kernel("pool", "global_pool_final", prec, MODE=mode)
    dev.launch(k2, (nc,), (part.data, out.data, np.int32(nchunks), np.int32(nc), count))
    return out


def _selfcheck_run(dev: Device, prec: str) -> list[np.ndarray]:
    """Global max and average, in one pass and in two (chunks of 24), rows off multiples of 8."""
    x = dev.to_device(rng("global pool selfcheck").standard_normal((1, 3, 7, 13)).astype(np.float32), prec)
    return [dev.to_host(f(dev, prec, x, chunk)) for f in (global_max_pool, global_avg_pool)
            for chunk in (None, 24)]


# max selects a stored value (bit-exact); the average's lanes reorder the sum.
selfcheck.register(selfcheck.FastPath(
    "pool.global_vector_lanes", "pool", {"GLOBAL_LANES": 8}, {"GLOBAL_LANES": 1}, check=_selfcheck_run,
    tolerance=lambda prec: [EXACT, EXACT, DEFAULT_TOL[prec], DEFAULT_TOL[prec]],
    what="global pooling accumulates 8 vector lanes"))


def _selfcheck_row8(dev: Device, prec: str) -> list[np.ndarray]:
    """3x3 max pools (padded and not, row stride 1 and 2) of rows off multiples of 8."""
    x = dev.to_device(rng("max_pool_row8 selfcheck").standard_normal((1, 3, 9, 21)).astype(np.float32), prec)
    return [dev.to_host(max_pool(dev, prec, x, (3, 3), stride=s, pads=p))
            for s, p in (((1, 1), (1, 1, 1, 1)), ((2, 1), (0, 0, 0, 0)))]


selfcheck.register(selfcheck.FastPath(
    "pool.row8", "pool", {"POOL_ROW8": 1}, {"POOL_ROW8": 0}, check=_selfcheck_row8,
    tolerance=lambda prec: EXACT, what="3-wide max pool: 8 outputs per work-item (kernel max_pool_row8)"))


def _selfcheck_max2x2(dev: Device, prec: str) -> list[np.ndarray]:
    """2x2 / 2 max pools of odd-sized maps whose rows end in a partial vector, with ties
    (+-0) and a NaN."""
    x = rng("max_pool_2x2 selfcheck").standard_normal((1, 3, 9, 37)).astype(np.float32)
    x[0, 0, 0, :4] = [0.0, -0.0, -0.0, 0.0]
    x[0, 1, 2, 5] = np.nan
    return [dev.to_host(max_pool(dev, prec, dev.to_device(x, prec), (2, 2), stride=(2, 2)))]


selfcheck.register(selfcheck.FastPath(
    "pool.max2x2", "pool", {"POOL_MAX2X2": 1}, {"POOL_MAX2X2": 0}, check=_selfcheck_max2x2,
    tolerance=lambda prec: EXACT, what="2x2 / 2 max pool: 8 outputs per work-item (kernel max_pool_2x2)"))


def global_avg_pool(dev: Device, prec: str, x, chunk: int | None = None, out=None):
    """ONNX GlobalAveragePool: mean over all spatial dims, output [N, C, 1, ...].
    Two passes when H*W exceeds `chunk`: chunk sums (8 lanes each), then a sum of chunks."""
    return _global(dev, prec, x, 1, chunk, out)


def global_max_pool(dev: Device, prec: str, x, chunk: int | None = None, out=None):
    """ONNX GlobalMaxPool: max over all spatial dims (bit-exact)."""
    return _global(dev, prec, x, 0, chunk, out)


# --- ONNX -----------------------------------------------------------------------

def _pool_attrs(attrs, nd):
    if "kernel_shape" not in attrs:
        raise Unsupported("pooling without kernel_shape")
    auto_pad = as_str(attrs.get("auto_pad", "NOTSET"))
    if auto_pad not in AUTO_PADS:
        raise Unsupported(f"auto_pad {auto_pad!r}")
    return dict(kernel=list(attrs["kernel_shape"]), stride=attrs.get("strides"),
                pads=attrs.get("pads"), dilation=attrs.get("dilations"),
                ceil_mode=bool(attrs.get("ceil_mode", 0)), auto_pad=auto_pad)


def _spatial_ok(x):
    if x.ndim not in (3, 4, 5):
        raise Unsupported(f"pooling over {x.ndim - 2} spatial dims (1-3 supported)")


@onnx_op("MaxPool")
def _onnx_max_pool(dev, prec, attrs, inputs):
    x = inputs[0]
    _spatial_ok(x)
    order = int(attrs.get("storage_order", 0))
    if order and x.ndim != 4:
        raise Unsupported("MaxPool storage_order=1 outside 2-D")
    y, idx = max_pool(dev, prec, x, **_pool_attrs(attrs, x.ndim - 2), return_indices=True,
                      storage_order=order)
    return [y, idx]


@onnx_op("AveragePool")
def _onnx_avg_pool(dev, prec, attrs, inputs):
    x = inputs[0]
    _spatial_ok(x)
    return [avg_pool(dev, prec, x, **_pool_attrs(attrs, x.ndim - 2),
                     count_include_pad=bool(attrs.get("count_include_pad", 0)))]


@onnx_op("GlobalAveragePool")
def _onnx_gap(dev, prec, attrs, inputs):
    return [global_avg_pool(dev, prec, inputs[0])]


@onnx_op("GlobalMaxPool")
def _onnx_gmp(dev, prec, attrs, inputs):
    return [global_max_pool(dev, prec, inputs[0])]


NODE_DEVIATIONS = {
    "test_averagepool_2d_ceil_last_window_starts_on_pad":
        "expected output stored rounded to 4 decimals (0.1511); clss and onnxruntime give 0.151056",
}
