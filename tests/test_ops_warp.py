import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from clss.ops import warp as W
from clss.verify.cases import warp as warp_cases
from helpers import PRECISIONS, assert_case

# Both spellings of every mode (opset 16 names, opset 20 names), every padding and
# align_corners, odd shapes including 1-pixel axes, grids reaching far off the image.
# The output size stays 3x4 (5x6 for warp): input sizes and channel counts vary freely,
# but PoCL compiles each variant again for every launch grid it meets.
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(mode=st.sampled_from(W.MODES), padding=st.sampled_from(W.PADDINGS), ac=st.booleans(),
       opset=st.sampled_from([16, 20]), n=st.integers(1, 2), c=st.sampled_from([1, 3, 5]),
       hi=st.integers(1, 9), wi=st.integers(1, 9), reach=st.sampled_from([0.5, 1.0, 1.5, 4.0]),
       precision=st.sampled_from(PRECISIONS))
def test_grid_sample_hypothesis(dev, mode, padding, ac, opset, n, c, hi, wi, reach, precision):
    case = warp_cases.grid_case(n, c, hi, wi, 3, 4, mode, padding, ac, opset=opset, reach=reach)
    assert_case(case, dev, precision)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(mode=st.sampled_from(W.MODES), padding=st.sampled_from(W.PADDINGS), c=st.sampled_from([1, 4, 16]),
       k=st.sampled_from([0, 3]), h=st.integers(1, 9), w=st.integers(1, 9),
       scale=st.sampled_from([1.0, 2.0]), precision=st.sampled_from(PRECISIONS))
def test_warp_hypothesis(dev, mode, padding, c, k, h, w, scale, precision):
    case = warp_cases.motion_case(1, c, h, w, 5, 6, mode, padding, scale=scale, cubic_channels=k)
    assert_case(case, dev, precision)


@pytest.mark.parametrize("mode", W.MODES)
def test_zero_motion_is_identity(dev, mode):
    # At integer positions the bilinear and Keys weights are exactly (0, 1, 0, 0): the
    # warp by zero motion must return the input bit for bit, in every mode.
    x = np.random.default_rng(0).standard_normal((2, 5, 7, 13)).astype(np.float32)
    for prec in PRECISIONS:
        xd = dev.to_device(x, prec)
        m = dev.to_device(np.zeros((2, 2, 7, 13), np.float32), prec)
        y = W.warp(dev, prec, xd, m, mode=mode)
        assert np.array_equal(y.get().view(np.uint8), xd.get().view(np.uint8)), prec


def test_integer_motion_is_a_shift(dev):
    x = np.random.default_rng(1).standard_normal((1, 3, 9, 11)).astype(np.float32)
    m = np.zeros((1, 2, 9, 11), np.float32)
    m[:, 0], m[:, 1] = 2, -1              # output (X, Y) reads input (X + 2, Y - 1)
    y = W.warp(dev, "fp32", dev.to_device(x), dev.to_device(m), mode="bilinear", padding="zeros").get()
    ref = np.zeros_like(x)
    ref[:, :, 1:, :-2] = x[:, :, :-1, 2:]
    assert np.array_equal(y, ref)


def test_nearest_copies_bits(dev):
    # Nearest is data movement: NaN payloads and -0.0 survive, in fp32 and fp16.
    x = np.arange(1 * 2 * 4 * 5, dtype=np.float32).reshape(1, 2, 4, 5)
    x.view(np.uint32)[0, 0, 1, 2] = 0x7FC01234
    x[0, 1, 2, 3] = -0.0
    grid = np.stack(np.meshgrid((2 * np.arange(5) + 1) / 5 - 1, (2 * np.arange(4) + 1) / 4 - 1), -1)
    grid = dev.to_device(grid[None].astype(np.float32))
    y = W.grid_sample(dev, "fp32", dev.to_device(x), grid, "nearest").get()
    assert np.array_equal(y.view(np.uint32), x.view(np.uint32))
    h = x.astype(np.float16)
    h.view(np.uint16)[0, 0, 1, 2] = 0x7E55
    yh = W.grid_sample(dev, "fp16", dev.to_device(h, "fp16"), grid, "nearest").get()
    assert np.array_equal(yh.view(np.uint16), h.view(np.uint16))


def test_warp_equals_device_grid_sample(dev):
    # The motion form against the grid form on the device itself, beyond onnxruntime.
    g = np.random.default_rng(2)
    x = g.standard_normal((2, 16, 12, 10)).astype(np.float32)
    m = g.uniform(-3, 3, (2, 2, 24, 20)).astype(np.float32)
    base_x = (2 * np.arange(20) + 1) / 20 - 1
    base_y = (2 * np.arange(24) + 1) / 24 - 1
    grid = np.stack([base_x[None, None, :] + 2 * 0.5 * 2 * m[:, 0] / 10,
                     base_y[None, :, None] + 2 * 0.5 * 2 * m[:, 1] / 12], -1).astype(np.float32)
    a = W.warp(dev, "fp32", dev.to_device(x), dev.to_device(m), motion_scale=(0.5, 0.5), scale=2.0,
               mode="bilinear", padding="border", cubic_channels=3).get()
    b = W.grid_sample(dev, "fp32", dev.to_device(x), dev.to_device(grid), "bilinear", "border",
                      cubic_channels=3).get()
    assert np.allclose(a, b, atol=2e-5 * np.abs(b).max(), rtol=1e-4)


@pytest.mark.parametrize("cpb", [1, 5, 16, 64])
def test_channel_blocking_does_not_change_results(dev, cpb):
    g = np.random.default_rng(3)
    x = dev.to_device(g.standard_normal((2, 23, 6, 7)).astype(np.float32))
    m = dev.to_device(g.uniform(-2, 2, (2, 2, 6, 7)).astype(np.float32))
    ref = W.warp(dev, "fp32", x, m, mode="bilinear", cubic_channels=3).get()
    got = W.warp(dev, "fp32", x, m, mode="bilinear", cubic_channels=3, channels_per_item=cpb).get()
    assert np.array_equal(got, ref)


def test_bad_arguments_raise(dev):
    x = dev.to_device(np.zeros((1, 3, 4, 4), np.float32))
    grid = dev.to_device(np.zeros((1, 2, 2, 2), np.float32))
    with pytest.raises(TypeError, match="grid: expected float32"):
        W.grid_sample(dev, "fp16", dev.to_device(np.zeros((1, 3, 4, 4)), "fp16"),
                      dev.to_device(np.zeros((1, 2, 2, 2)), "fp16"))
    with pytest.raises(ValueError, match="mode must be"):
        W.grid_sample(dev, "fp32", x, grid, "area")
    with pytest.raises(ValueError, match="padding must be"):
        W.grid_sample(dev, "fp32", x, grid, padding="wrap")
    with pytest.raises(ValueError, match="expected \\[N,Ho,Wo,2\\]"):
        W.grid_sample(dev, "fp32", x, dev.to_device(np.zeros((1, 2, 2, 3), np.float32)))
    with pytest.raises(ValueError, match="expected \\[N,2,Ho,Wo\\]"):
        W.warp(dev, "fp32", x, dev.to_device(np.zeros((1, 3, 4, 4), np.float32)))


@pytest.mark.parametrize("spelling", [("bilinear", "linear"), ("bicubic", "cubic"), ("nearest", "nearest")])
def test_onnx_handler_both_spellings_and_half_grid(dev, spelling):
    # opset 16 and opset 20 names give the same result; an fp16 model's half grid is widened.
    from clss.ops import ONNX_HANDLERS
    fn = ONNX_HANDLERS["GridSample"].fn
    g = np.random.default_rng(4)
    x = g.standard_normal((2, 3, 5, 6)).astype(np.float32)
    grid = g.uniform(-1.2, 1.2, (2, 4, 3, 2)).astype(np.float16).astype(np.float32)
    attrs = {"padding_mode": b"border", "align_corners": 1}
    a, b = (fn(dev, "fp32", {**attrs, "mode": m.encode()}, [dev.to_device(x), dev.to_device(grid)])[0].get()
            for m in spelling)
    assert np.array_equal(a, b)
    h = fn(dev, "fp16", {**attrs, "mode": spelling[1].encode()},
           [dev.to_device(x, "fp16"), dev.to_device(grid, "fp16")])[0]
    assert h.dtype == np.float16
    ref = fn(dev, "fp32", {**attrs, "mode": spelling[1].encode()},
             [dev.to_device(x.astype(np.float16).astype(np.float32)), dev.to_device(grid)])[0].get()
    assert np.allclose(dev.to_host(h), ref, atol=2e-3 * np.abs(ref).max(), rtol=1e-3)
