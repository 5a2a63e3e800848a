"""Normalisations (kernels/norm.cl): ONNX LayerNormalization, InstanceNormalization and
GroupNormalization, each a [rows, L] view of the input normalised row by row.

LayerNormalization: any axis; Scale and B broadcast to the normalised shape (expanded on
the device when smaller); the optional Mean and InvStdDev outputs. InstanceNormalization:
any rank >= 3. GroupNormalization: opset 18's scale per group and opset 21's per channel
(told apart by their length when they differ)."""
from __future__ import annotations

import numpy as np

from .. import selfcheck
from ..device import Device
from ..tolerance import DEFAULT_TOL
from .base import Unsupported, unsupported_on_value_error, check_storage, onnx_op, rng
from .conv import builtin_free
from .elementwise import expand

FAST = "norm.builtin_free_loads"

BUILD_VARIANTS = [dict(HAS_BIAS=b, STATS=s, SCALE_MODE=m) for b in (0, 1) for s in (0, 1) for m in (0, 1, 2)]


def _launch(dev, prec, x, scale, bias, rows, L, sidx, eps, stats: bool, mode: int):
    out = dev.empty(x.shape, prec)
    mean = dev.empty((rows,), prec) if stats else None
    istd = dev.empty((rows,), prec) if stats else None
    if out.size:
        clang = builtin_free(dev) and selfcheck.enabled(dev, prec, FAST)
        k = dev.kernel("norm", "norm_rows", prec, HAS_BIAS=int(bias is not None), STATS=int(stats),
                       SCALE_MODE=mode, CLSS_CLANG_VECTORS=int(clang))
        dummy = mean if stats else out
        i32 = np.int32
        dev.launch(k, (rows,), (x.data, scale.data, (bias if bias is not None else scale).data, out.data,
                                dummy.data, (istd if stats else out).data, i32(L), i32(rows),
                                *map(i32, sidx), np.float32(eps)))
    return out, mean, istd


def layer_norm(dev: Device, prec: str, x, scale, bias=None, axis: int = -1, eps: float = 1e-5,
               stats: bool = False):
    """ONNX LayerNormalization. Returns y, or (y, mean, inv_std_dev) with stats=True,
    the statistics shaped x.shape[:axis] + (1,) * (rank - axis)."""
    check_storage("x", x, prec)
    rank = x.ndim
    if not -rank <= axis < rank:
        raise ValueError(f"LayerNormalization axis {axis} out of range for rank {rank}")
    axis %= rank
    norm_shape = tuple(x.shape[axis:])
    rows = int(np.prod(x.shape[:axis], dtype=np.int64))
    L = int(np.prod(norm_shape, dtype=np.int64))

    def full(t, what):
        if t is None:
            return None
        check_storage(what, t, prec)
        if tuple(t.shape) == norm_shape:
            return t
        shape = tuple(t.shape)
        if len(shape) > len(norm_shape) and all(d == 1 for d in shape[:len(shape) - len(norm_shape)]):
            t = t.reshape(shape[len(shape) - len(norm_shape):])
        try:
            ok = np.broadcast_shapes(tuple(t.shape), norm_shape) == norm_shape
        except ValueError:
            ok = False
        if not ok:
            raise ValueError(f"LayerNormalization {what} of shape {shape} does not broadcast "
                             f"to the normalised shape {norm_shape}")
        return expand(dev, prec, t, norm_shape)
    scale, bias = full(scale, "scale"), full(bias, "bias")
    y, mean, istd = _launch(dev, prec, x, scale, bias, rows, L, (1, 0, 1, max(L, 1)), eps, stats, 1)
    if not stats:
        return y
    st_shape = tuple(x.shape[:axis]) + (1,) * (rank - axis)
    return y, mean.reshape(st_shape), istd.reshape(st_shape)


def norm_block(dev: Device, prec: str, x, scale, bias, outer: int, length: int, inner: int,
               eps: float = 1e-5):
    """x viewed [outer, length, inner] normalised along `length` for each (outer, inner)
    pair, scale and bias [length]: a LayerNorm over a block of axes that is not the last
    (a channel LayerNorm of NCHW). clss.Model's layer-norm pattern pass makes these."""
    check_storage("x", x, prec)
    if outer * length * inner != x.size or scale.size != length or (bias is not None and bias.size != length):
        raise ValueError(f"norm over [{outer}, {length}, {inner}] of {tuple(x.shape)} with scale "
                         f"{tuple(scale.shape)}")
    if inner == 1:
        return _launch(dev, prec, x, scale, bias, outer, length, (1, 0, 1, max(length, 1)), eps, False, 1)[0]
    out = dev.empty(x.shape, prec)
    if out.size:
        clang = builtin_free(dev) and selfcheck.enabled(dev, prec, FAST)
        k = dev.kernel("norm", "norm_strided", prec, HAS_BIAS=int(bias is not None), CLSS_CLANG_VECTORS=int(clang))
        dev.launch(k, (inner, outer), (x.data, scale.data, (bias if bias is not None else scale).data, out.data,
                                       np.int32(length), np.int32(inner), np.int32(outer), np.float32(eps)))
    return out


def instance_norm(dev: Device, prec: str, x, scale, bias, eps: float = 1e-5):
    """ONNX InstanceNormalization: x [N, C, D1, ...], scale and bias [C]."""
    check_storage("x", x, prec)
    if x.ndim < 3:
        raise ValueError(f"InstanceNormalization needs rank >= 3, got {tuple(x.shape)}")
    n, c = int(x.shape[0]), int(x.shape[1])
    if scale.size != c or bias.size != c:
        raise ValueError(f"InstanceNormalization: scale {scale.shape} and bias {bias.shape} must have "
                         f"the {c} channels")
    L = int(np.prod(x.shape[2:], dtype=np.int64))
    return _launch(dev, prec, x, scale, bias, n * c, L, (c, 1, max(L, 1), 1), eps, False, 2)[0]


def group_norm(dev: Device, prec: str, x, scale, bias, num_groups: int, eps: float = 1e-5):
    """ONNX GroupNormalization: x [N, C, D1, ...]; scale and bias [C] (opset 21) or
    [num_groups] (opset 18)."""
    check_storage("x", x, prec)
    if x.ndim < 2:
        raise ValueError(f"GroupNormalization needs rank >= 2, got {tuple(x.shape)}")
    n, c, g = int(x.shape[0]), int(x.shape[1]), int(num_groups)
    if g < 1 or c % g:
        raise ValueError(f"GroupNormalization: {c} channels do not split into {g} groups")
    hw = int(np.prod(x.shape[2:], dtype=np.int64))
    L = c // g * hw
    if scale.size == c and bias.size == c:
        return _launch(dev, prec, x, scale, bias, n * g, L, (g, c // g, max(hw, 1), c // g), eps, False,
                       2 if c == g else 0)[0]
    if scale.size == g and bias.size == g:
        return _launch(dev, prec, x, scale, bias, n * g, L, (g, 1, max(L, 1), 1), eps, False, 2)[0]
    raise ValueError(f"GroupNormalization: scale {scale.shape} and bias {bias.shape} must have {c} "
                     f"(channels) or {g} (groups) elements")


# --- ONNX -----------------------------------------------------------------------------

_unsupported = unsupported_on_value_error


@onnx_op("LayerNormalization")
def _onnx_layer_norm(dev, prec, attrs, inputs):
    if int(attrs.get("stash_type", 1)) != 1:
        raise Unsupported("LayerNormalization stash_type other than 1 (float32)")
    x, scale = inputs[0], inputs[1]
    bias = inputs[2] if len(inputs) > 2 else None
    # clss_stats=0: a LayerNorm whose Mean and InvStdDev nobody reads (clss.Model's layer-norm
    # pattern, clss/model/patterns.py) writes only Y
    stats = bool(attrs.get("clss_stats", 1))
    y = _unsupported(layer_norm, dev, prec, x, scale, bias, int(attrs.get("axis", -1)),
                     float(attrs.get("epsilon", 1e-5)), stats=stats)
    return list(y) if stats else [y]


@onnx_op("InstanceNormalization")
def _onnx_instance_norm(dev, prec, attrs, inputs):
    return [_unsupported(instance_norm, dev, prec, inputs[0], inputs[1], inputs[2],
                         float(attrs.get("epsilon", 1e-5)))]


@onnx_op("GroupNormalization")
def _onnx_group_norm(dev, prec, attrs, inputs):
    if int(attrs.get("stash_type", 1)) != 1:
        raise Unsupported("GroupNormalization stash_type other than 1 (float32)")
    return [_unsupported(group_norm, dev, prec, inputs[0], inputs[1], inputs[2], int(attrs["num_groups"]),
                         float(attrs.get("epsilon", 1e-5)))]


# --- fast path (clss/selfcheck.py): clang vector loads against the builtins --------------

def _selfcheck(dev: Device, prec: str) -> list[np.ndarray]:
    """Rows of 21 (a ragged tail) in each scale mode: LayerNorm, InstanceNorm, GroupNorm."""
    g = rng("norm selfcheck")
    up = lambda a: dev.to_device(np.asarray(a, np.float32), prec)   # noqa: E731
    x = up(g.standard_normal((2, 4, 3, 7)) * 2 + 1)
    s4, b4 = up(g.standard_normal(4)), up(g.standard_normal(4))
    s7, b7 = up(g.standard_normal(7)), up(g.standard_normal(7))
    return [dev.to_host(layer_norm(dev, prec, x, s7, b7, -1)), dev.to_host(instance_norm(dev, prec, x, s4, b4)),
            dev.to_host(group_norm(dev, prec, x, s4, b4, 2)),
            dev.to_host(norm_block(dev, prec, x, s4, b4, 2, 4, 21))]


selfcheck.register(selfcheck.FastPath(
    FAST, "norm", {"CLSS_CLANG_VECTORS": 1}, {"CLSS_CLANG_VECTORS": 0}, check=_selfcheck,
    tolerance=DEFAULT_TOL.__getitem__, applies=lambda dev: bool(builtin_free(dev)),
    what="normalisations: loads and stores as clang vector accesses (PoCL) / the builtins"))
