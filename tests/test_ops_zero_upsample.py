import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from clss.ops import zero_upsample as zu
from clss.verify.cases import zero_upsample as zu_cases
from clss.verify.conformance import check


@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(h=st.integers(1, 9), w=st.integers(1, 9),
       sy=st.sampled_from([1, 1.25, 1.5, 2, 2.5, 3, 4]), sx=st.sampled_from([1, 1.5, 2, 3, 3.3]),
       jy=st.floats(-0.5, 0.5), jx=st.floats(-0.5, 0.5))
def test_random_placements(dev, h, w, sy, sx, jy, jx):
    c = zu_cases.case(1, 3, h, w, (sy, sx), (jy, jx))
    row = check(c, dev, "fp32")
    assert row.passed, row


def test_every_sample_kept_once_inside_its_footprint():
    # The placement map is injective and each sample stays in its render pixel's footprint.
    for s in (1.0, 1.5, 2.0, 2.5, 3.0, 4.0):
        for jit in (-0.5, -0.2, 0.0, 0.37, 0.5):
            x = zu.placement(17, s, jit, int(17 * s))
            kept = x[x >= 0]
            assert len(set(kept.tolist())) == len(kept)
            j = np.nonzero(x >= 0)[0]
            assert np.all(kept >= np.floor(j * s) - 1e-9) and np.all(kept < np.ceil((j + 1) * s))


def test_nsrr_placement_is_top_left(dev):
    x = np.arange(6, dtype=np.float32).reshape(1, 1, 2, 3) + 1
    y = zu.zero_upsample(dev, "fp32", dev.to_device(x), 2).get()[0, 0]
    assert np.array_equal(y[::2, ::2], x[0, 0]) and y.sum() == x.sum()


def test_keeps_nan_payload_and_signed_zero(dev):
    x = np.ones((1, 2, 3, 3), np.float32)
    x.view(np.uint32)[0, 0, 1, 1] = 0x7FC01234
    x[0, 1, 2, 2] = -0.0
    y = zu.zero_upsample(dev, "fp32", dev.to_device(x), 2, (0.3, 0.3)).get()
    assert y.view(np.uint32)[0, 0, 3, 3] == 0x7FC01234
    assert y.view(np.uint32)[0, 1, 5, 5] == 0x80000000


def test_bad_arguments_raise(dev):
    x = dev.to_device(np.zeros((1, 2, 3, 3), np.float32))
    with pytest.raises(ValueError, match=">= 1"):
        zu.zero_upsample(dev, "fp32", x, 0.5)
    with pytest.raises(ValueError, match="jitter"):
        zu.zero_upsample(dev, "fp32", x, 2, (0.7, 0))
    with pytest.raises(ValueError, match=r"\[N, C, H, W\]"):
        zu.zero_upsample(dev, "fp32", dev.to_device(np.zeros((2, 3, 3), np.float32)), 2)
    with pytest.raises(TypeError, match="float16 storage"):
        zu.zero_upsample(dev, "fp16", x, 2)
