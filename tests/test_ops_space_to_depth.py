import numpy as np
import pytest

from clss.ops import space_to_depth as s2d


def test_round_trip_keeps_nan_payload_and_signed_zero(dev):
    # Data movement copies bits: a NaN payload and -0.0 must survive both ways.
    x = np.arange(2 * 3 * 4 * 6, dtype=np.float32).reshape(2, 3, 4, 6)
    bits = x.view(np.uint32)
    bits[0, 0, 0, 0] = 0x7FC01234
    x[1, 2, 3, 5] = -0.0
    for mode in s2d.MODES:
        y = s2d.space_to_depth(dev, "fp32", dev.to_device(x), 2, mode)
        z = s2d.depth_to_space(dev, "fp32", y, 2, mode).get()
        assert np.array_equal(z.view(np.uint32), x.view(np.uint32))


def test_bad_shapes_raise(dev):
    x = dev.to_device(np.zeros((1, 3, 5, 4), np.float32))
    with pytest.raises(ValueError, match="not divisible by block"):
        s2d.space_to_depth(dev, "fp32", x, 2)
    with pytest.raises(ValueError, match="channels not divisible"):
        s2d.depth_to_space(dev, "fp32", x, 2)
    with pytest.raises(TypeError, match="float16 storage"):
        s2d.space_to_depth(dev, "fp16", dev.to_device(np.zeros((1, 1, 2, 2), np.float32)), 2)
