"""The Reduce* family (clss/ops/reduce.py, kernels/reduce.cl) beyond its conformance cases
(tests/test_ops_conformance.py): hypothesis-drawn axes and shapes against numpy, argument
checks, the ONNX handler's axes forms, and the half-arithmetic build."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from clss.ops import reduce as R
from clss.ops.base import Unsupported
from clss.tolerance import Tolerance, compare
from helpers import SETTINGS, assert_fp16_native_builds

NUMPY = {"sum": np.sum, "mean": np.mean, "max": np.max, "min": np.min, "prod": np.prod,
         "l1": lambda x, axis, keepdims: np.sum(np.abs(x), axis=axis, keepdims=keepdims),
         "l2": lambda x, axis, keepdims: np.sqrt(np.sum(x * x, axis=axis, keepdims=keepdims)),
         "sumsq": lambda x, axis, keepdims: np.sum(x * x, axis=axis, keepdims=keepdims),
         "logsum": lambda x, axis, keepdims: np.log(np.sum(x, axis=axis, keepdims=keepdims)),
         "logsumexp": lambda x, axis, keepdims: np.log(np.sum(np.exp(x), axis=axis, keepdims=keepdims))}


@settings(max_examples=40, **SETTINGS)
@given(op=st.sampled_from(sorted(R.OPS)), shape=st.lists(st.integers(1, 9), min_size=1, max_size=6),
       data=st.data(), keepdims=st.booleans())
def test_any_axes_against_numpy(dev, op, shape, data, keepdims):
    axes = data.draw(st.lists(st.integers(-len(shape), len(shape) - 1), unique_by=lambda a: a % len(shape),
                              max_size=len(shape)))
    g = np.random.default_rng(len(shape))
    x = (g.uniform(0.5, 1.5, shape) if op in ("prod", "logsum") else g.standard_normal(shape)).astype(np.float32)
    ref = NUMPY[op](x.astype(np.float64), axis=tuple(axes) if axes else None, keepdims=keepdims)
    out = dev.to_host(R.reduce(dev, "fp32", op, dev.to_device(x, "fp32"), axes or None, keepdims))
    assert out.shape == np.asarray(ref).shape
    assert compare(out, np.asarray(ref, np.float32), Tolerance(2e-5, 2e-4)).passed


def test_axis_out_of_range_is_named(dev):
    x = dev.to_device(np.zeros((2, 3), np.float32), "fp32")
    with pytest.raises(ValueError, match="axis 2 out of range"):
        R.reduce(dev, "fp32", "sum", x, [2])
    with pytest.raises(ValueError, match="repeat"):
        R.reduce(dev, "fp32", "sum", x, [1, -1])


def test_handler_axes_attribute_input_and_noop(dev):
    h = R._onnx_reduce("sum")
    x = np.arange(24, dtype=np.float32).reshape(2, 3, 4)
    dx = dev.to_device(x, "fp32")
    assert np.allclose(dev.to_host(h(dev, "fp32", {"axes": [1], "keepdims": 0}, [dx])[0]), x.sum(1))
    assert np.allclose(dev.to_host(h(dev, "fp32", {}, [dx, np.array([0, 2])])[0]), x.sum((0, 2), keepdims=True))
    assert np.array_equal(dev.to_host(h(dev, "fp32", {"noop_with_empty_axes": 1}, [dx, np.array([], np.int64)])[0]), x)
    with pytest.raises(Unsupported, match="out of range"):
        h(dev, "fp32", {}, [dx, np.array([5])])


def test_fp16_native_variants_build(tmp_path):
    assert_fp16_native_builds(tmp_path, "reduce", "reduce")
