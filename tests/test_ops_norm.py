"""The normalisations (clss/ops/norm.py, kernels/norm.cl) beyond their conformance cases
(tests/test_ops_conformance.py): GroupNormalization's per-group scale (opset 18, whose
twin onnx's checker refuses as deprecated) against numpy, argument checks, the build."""
import numpy as np
import pytest

from clss.ops import norm as N
from clss.tolerance import Tolerance, compare
from helpers import assert_fp16_native_builds


def _group_norm_ref(x, scale, bias, g, eps):
    n, c = x.shape[:2]
    xg = x.reshape(n, g, -1).astype(np.float64)
    y = (xg - xg.mean(-1, keepdims=True)) / np.sqrt(xg.var(-1, keepdims=True) + eps)
    y = y.reshape(x.shape)
    shp = (1, c) + (1,) * (x.ndim - 2)
    if scale.size == g:   # per group: repeat over the group's channels
        scale, bias = np.repeat(scale, c // g), np.repeat(bias, c // g)
    return (y * scale.reshape(shp) + bias.reshape(shp)).astype(np.float32)


@pytest.mark.parametrize("shape, groups, per_group", [((2, 6, 7, 13), 3, True), ((1, 8, 5, 11), 4, False),
                                                      ((1, 4, 9), 2, True)])
def test_group_norm_both_scale_forms(dev, shape, groups, per_group):
    g = np.random.default_rng(1)
    x = g.standard_normal(shape).astype(np.float32)
    k = groups if per_group else shape[1]
    s, b = g.standard_normal(k).astype(np.float32), g.standard_normal(k).astype(np.float32)
    out = N.group_norm(dev, "fp32", *(dev.to_device(a, "fp32") for a in (x, s, b)), groups, 1e-5)
    assert compare(dev.to_host(out), _group_norm_ref(x, s, b, groups, 1e-5), Tolerance(2e-5, 2e-4)).passed


def test_bad_arguments_are_named(dev):
    x = dev.to_device(np.zeros((1, 6, 3, 3), np.float32), "fp32")
    s4 = dev.to_device(np.ones(4, np.float32), "fp32")
    with pytest.raises(ValueError, match="do not split into 4 groups"):
        N.group_norm(dev, "fp32", x, s4, s4, 4)
    with pytest.raises(ValueError, match="6 channels"):
        N.instance_norm(dev, "fp32", x, s4, s4)
    with pytest.raises(ValueError, match="does not broadcast"):
        N.layer_norm(dev, "fp32", x, s4, None, -1)


def test_fp16_native_variants_build(tmp_path):
    assert_fp16_native_builds(tmp_path, "norm", "norm")


def test_group_norm_21_runs_through_the_model(dev):
    """onnx 1.22's shape inference leaves GroupNormalization-21's output shapeless (a function
    op): clss.Model takes its input's shape (graph.SAME_SHAPE_OPS) and infers on from there."""
    import clss
    from clss.verify.cases.norm import group_norm_case
    from clss.verify.twin import run_ort
    case = group_norm_case((1, 12, 7, 13), 4)
    m = case.twin
    out = clss.Model(m, device=dev).run(case.inputs)
    ref = run_ort(m, case.inputs)[0]
    assert compare(out["y0"], ref, Tolerance(2e-5, 2e-4)).passed
