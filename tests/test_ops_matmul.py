"""The run-time matrix products (clss/ops/matmul.py, kernels/matmul.cl) beyond their
conformance cases (tests/test_ops_conformance.py): hypothesis-drawn broadcasting batches
against numpy, argument checks, the build."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from clss.ops import matmul as MM
from clss.tolerance import Tolerance, compare
from helpers import SETTINGS, assert_fp16_native_builds

dims = st.integers(1, 9)


@settings(max_examples=30, **SETTINGS)
@given(m=dims, k=st.integers(0, 17), n=dims, ba=st.lists(st.sampled_from([1, 2, 3]), max_size=3),
       bb=st.lists(st.sampled_from([1, 2, 3]), max_size=3))
def test_broadcasting_batches_against_numpy(dev, m, k, n, ba, bb):
    try:
        np.broadcast_shapes(tuple(ba), tuple(bb))
    except ValueError:
        return
    g = np.random.default_rng(m * 100 + n)
    a = g.standard_normal(tuple(ba) + (m, k)).astype(np.float32)
    b = g.standard_normal(tuple(bb) + (k, n)).astype(np.float32)
    ref = np.matmul(a.astype(np.float64), b).astype(np.float32)
    out = dev.to_host(MM.matmul(dev, "fp32", dev.to_device(a, "fp32"), dev.to_device(b, "fp32")))
    assert out.shape == ref.shape
    assert compare(out, ref, Tolerance(2e-5, 2e-4)).passed


def test_bad_shapes_are_named(dev):
    a = dev.to_device(np.zeros((2, 3), np.float32), "fp32")
    with pytest.raises(ValueError, match="inner sizes differ"):
        MM.matmul(dev, "fp32", a, a)
    with pytest.raises(ValueError, match="does not broadcast"):
        MM.gemm(dev, "fp32", a, dev.to_device(np.zeros((3, 4), np.float32), "fp32"),
                dev.to_device(np.zeros(3, np.float32), "fp32"))


def test_fp16_native_variants_build(tmp_path):
    assert_fp16_native_builds(tmp_path, "matmul", "matmul")
