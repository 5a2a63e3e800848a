"""Conformance cases of the normalisations (clss/ops/norm.py, kernels/norm.cl):
LayerNormalization on any axis (with its Mean and InvStdDev outputs, scale broadcast),
InstanceNormalization, GroupNormalization (opset 21, per channel)."""
from __future__ import annotations

import numpy as np

from ...ops.base import rng
from ...ops.norm import group_norm, instance_norm, layer_norm
from ..case import Case, host_call
from ..twin import node_model


def layer_norm_case(shape, axis, scale_shape=None, bias=True, eps=1e-5):
    g = rng("layer norm", shape, axis, scale_shape, bias)
    x = (g.standard_normal(shape) * 3 + 1).astype(np.float32)
    ax = axis % len(shape)
    sshape = scale_shape or tuple(shape[ax:])
    ins = {"x": x, "scale": g.standard_normal(sshape).astype(np.float32)}
    if bias:
        ins["bias"] = g.standard_normal(sshape).astype(np.float32)
    twin = node_model("LayerNormalization", ins, n_outputs=3, opset=17, axis=axis, epsilon=eps)
    variant = f"{'x'.join(map(str, shape))} axis={axis}" + (f" scale {list(sshape)}" if scale_shape else "") + (
        "" if bias else " no bias")
    return Case("layer_norm", variant, ins, twin,
                host_call(lambda dev, p, x, scale, bias=None: list(
                    layer_norm(dev, p, x, scale, bias, axis, eps, stats=True))))


def instance_norm_case(shape, eps=1e-5):
    g = rng("instance norm", shape)
    c = shape[1]
    ins = {"x": (g.standard_normal(shape) * 2 - 1).astype(np.float32),
           "scale": g.standard_normal(c).astype(np.float32), "bias": g.standard_normal(c).astype(np.float32)}
    return Case("instance_norm", "x".join(map(str, shape)), ins,
                node_model("InstanceNormalization", ins, epsilon=eps),
                host_call(lambda dev, p, x, scale, bias: instance_norm(dev, p, x, scale, bias, eps)))


def group_norm_case(shape, groups, eps=1e-5):
    """Opset 21's scale per channel (opset 18's per group is deprecated: onnx's checker
    refuses it, so it has no twin here; clss.ops.norm.group_norm runs it)."""
    g = rng("group norm", shape, groups)
    n = shape[1]
    ins = {"x": (g.standard_normal(shape) * 2 + 0.5).astype(np.float32),
           "scale": g.standard_normal(n).astype(np.float32), "bias": g.standard_normal(n).astype(np.float32)}
    twin = node_model("GroupNormalization", ins, opset=21, num_groups=groups, epsilon=eps)
    return Case("group_norm", f"{'x'.join(map(str, shape))} groups={groups}",
                ins, twin, host_call(lambda dev, p, x, scale, bias: group_norm(dev, p, x, scale, bias, groups, eps)))


def cases(level: str = "quick") -> list[Case]:
    if level == "tiny":
        return [layer_norm_case((2, 5, 7), -1), layer_norm_case((2, 3, 21), -1), instance_norm_case((1, 3, 5, 7)),
                group_norm_case((1, 6, 5, 7), 3)]
    out = [layer_norm_case((2, 64, 24), -1), layer_norm_case((1, 96, 60), -1, bias=False),
           instance_norm_case((2, 8, 16, 20)), group_norm_case((2, 16, 16, 20), 4)]
    if level != "full":
        return out
    out += [
        layer_norm_case((1, 23, 7, 13), 1),
        layer_norm_case((2, 3, 7, 13), -2, scale_shape=(1, 13)),
        layer_norm_case((3, 1), -1),
        layer_norm_case((5, 1000), 1, eps=1e-3),
        instance_norm_case((1, 23, 31, 27)),
        instance_norm_case((2, 3, 67)),
        group_norm_case((1, 12, 31, 27), 4),
        group_norm_case((2, 6, 7, 13), 6),
        group_norm_case((2, 6, 7, 13), 1),
    ]
    return out
