import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from clss.ops import scatter as S
from clss.verify.cases import scatter as scatter_cases
from helpers import PRECISIONS, assert_case


@st.composite
def scatter_args(draw):
    r = draw(st.integers(1, 4))
    dshape = tuple(draw(st.lists(st.integers(1, 6), min_size=r, max_size=r)))
    axis = draw(st.integers(-r, r - 1))
    reduction = draw(st.sampled_from(S.REDUCTIONS))
    a = axis % r
    ishape = tuple(draw(st.integers(1, d)) if k != a else
                   (draw(st.integers(1, d)) if reduction == "none" else draw(st.integers(1, 2 * d)))
                   for k, d in enumerate(dshape))
    return dshape, ishape, axis, reduction


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(args=scatter_args(), negative=st.booleans(), idx32=st.booleans(), precision=st.sampled_from(PRECISIONS))
def test_scatter_elements_hypothesis(dev, args, negative, idx32, precision):
    dshape, ishape, axis, reduction = args
    case = scatter_cases.elements_case(dshape, ishape, axis, reduction, negative=negative,
                                       idx_dtype=np.int32 if idx32 else np.int64)
    assert_case(case, dev, precision)


# Few image sizes: PoCL compiles each kernel again for every launch grid it meets.
@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(1, 2), h=st.sampled_from([1, 9]), w=st.sampled_from([1, 11]), mode=st.sampled_from(S.DEPTH_MODES),
       reach=st.sampled_from([0.5, 1.5, 4.0, 20.0]), snap=st.booleans(), precision=st.sampled_from(PRECISIONS))
def test_scatter_depth_hypothesis(dev, n, h, w, mode, reach, snap, precision):
    assert_case(scatter_cases.depth_case(n, h, w, mode, reach, snap=snap), dev, precision)


@pytest.mark.parametrize("reduction", ["max", "min"])
def test_keyed_max_min_orders_every_float(dev, reduction):
    # The order-preserving key must make atomic_max/min agree with float order across
    # signs, infinities and subnormals (plain float bits would put every negative above
    # every positive).
    vals = np.array([-np.inf, -3e38, -1.5, -1e-40, 0.0, 1e-40, 2.5, 3e38, np.inf], np.float32)
    g = np.random.default_rng(0)
    data = g.permutation(vals).astype(np.float32)
    upd = g.choice(vals, 40).astype(np.float32)
    idx = g.integers(0, len(vals), 40)
    ref = data.copy()
    (np.maximum if reduction == "max" else np.minimum).at(ref, idx, upd)
    got = S.scatter_elements(dev, "fp32", dev.to_device(data), dev.to_device(idx), dev.to_device(upd), 0,
                             reduction).get()
    assert np.array_equal(got, ref)


def test_none_with_duplicates_keeps_one_of_the_updates(dev):
    data = np.zeros(4, np.float32)
    idx = np.array([1, 1, 1, 3, 3], np.int64)
    upd = np.array([10, 20, 30, 40, 50], np.float32)
    got = S.scatter_elements(dev, "fp32", dev.to_device(data), dev.to_device(idx), dev.to_device(upd)).get()
    assert got[0] == 0 and got[2] == 0 and got[1] in (10, 20, 30) and got[3] in (40, 50)


def test_in_place_and_out_of_range_indices(dev):
    data = np.arange(6, dtype=np.float32)
    d = dev.to_device(data)
    idx = dev.to_device(np.array([0, 7, -1, -9], np.int64))    # 7 and -9 are out of range: dropped
    upd = dev.to_device(np.array([100, 200, 300, 400], np.float32))
    out = S.scatter_elements(dev, "fp32", d, idx, upd, 0, "add", out=d)
    assert out is d
    assert np.array_equal(d.get(), [100, 1, 2, 3, 4, 305])


def test_depth_threshold_clear_and_skips(dev):
    # 1 x 4 image; pixel 0 moves by +0.995: tap 0 weighs 0.005 (< 0.01, skipped),
    # tap 1 weighs 0.995. Pixel 2 has NaN depth and pixel 3 a negative one: not scattered.
    depth = np.array([[[[0.25, 0.5, np.nan, -0.5]]]], np.float32)
    motion = np.zeros((1, 2, 1, 4), np.float32)
    motion[0, 0, 0, 0] = 0.995
    for mode, far in (("max", 0.0), ("min", 1.0)):
        buf = S.scatter_depth(dev, "fp32", dev.to_device(depth), dev.to_device(motion), mode)
        assert buf.dtype == np.uint32
        got = S.bits_as_float(buf).get()[0, 0, 0]
        pick = max if mode == "max" else min
        assert np.array_equal(got, [far, pick(0.25, 0.5), far, far]), (mode, got)
    buf = S.scatter_depth(dev, "fp32", dev.to_device(depth), dev.to_device(motion), "min", clear=np.inf)
    assert np.array_equal(S.bits_as_float(buf).get()[0, 0, 0], [np.inf, 0.25, np.inf, np.inf])
    # -0.0 is stored as +0.0, so it never wins a max over positive depths through its sign bit
    buf = S.scatter_depth(dev, "fp32", dev.to_device(np.full((1, 1, 1, 2), -0.0, np.float32)),
                          dev.to_device(np.zeros((1, 2, 1, 2), np.float32)), "max")
    assert np.array_equal(buf.get().ravel(), [0, 0])


def test_depth_out_is_reused(dev):
    g = np.random.default_rng(5)
    depth = dev.to_device(g.uniform(0, 1, (2, 1, 6, 5)).astype(np.float32))
    motion = dev.to_device(g.uniform(-2, 2, (2, 2, 6, 5)).astype(np.float32))
    buf = dev.empty((2, 1, 6, 5), dtype=np.uint32)
    first = S.scatter_depth(dev, "fp32", depth, motion, out=buf).get()
    again = S.scatter_depth(dev, "fp32", depth, motion, out=buf)
    assert again is buf and np.array_equal(again.get(), first)   # cleared each call


def test_bad_arguments_raise(dev):
    d = dev.to_device(np.zeros((1, 1, 3, 3), np.float32))
    with pytest.raises(ValueError, match="motion"):
        S.scatter_depth(dev, "fp32", d, dev.to_device(np.zeros((1, 2, 3, 4), np.float32)))
    with pytest.raises(ValueError, match="mode must be"):
        S.scatter_depth(dev, "fp32", d, dev.to_device(np.zeros((1, 2, 3, 3), np.float32)), "mean")
    x = dev.to_device(np.zeros((3, 4), np.float32))
    with pytest.raises(ValueError, match="reduction must be"):
        S.scatter_elements(dev, "fp32", x, dev.to_device(np.zeros((3, 4), np.int64)), x, 0, "mean")
    with pytest.raises(TypeError, match="indices"):
        S.scatter_elements(dev, "fp32", x, dev.to_device(np.zeros((3, 4), np.float32)), x)
    with pytest.raises(ValueError, match="do not fit"):
        S.scatter_elements(dev, "fp32", x, dev.to_device(np.zeros((3, 5), np.int64)),
                           dev.to_device(np.zeros((3, 5), np.float32)), 0)
