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


def _d2s_reference(x, b, mode):
    """numpy DepthToSpace as the ONNX spec writes it (DCR and CRD)."""
    n, cbb, h, w = x.shape
    c = cbb // (b * b)
    if mode == "DCR":
        t = x.reshape(n, b, b, c, h, w).transpose(0, 3, 4, 1, 5, 2)
    else:
        t = x.reshape(n, c, b, b, h, w).transpose(0, 1, 4, 2, 5, 3)
    return t.reshape(n, c, h * b, w * b)


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
@pytest.mark.parametrize("b, shape", [(2, (1, 12, 5, 19)), (2, (2, 4, 3, 16)), (3, (1, 18, 4, 11)),
                                      (4, (1, 16, 2, 9))])
def test_depth_to_space_moves_bits_as_onnx_says(any_dev, prec, b, shape):
    # whole 8-column runs (the B = 2 vector interleave) and the scalar tails, odd widths,
    # N > 1; bit-exact against the spec's reshape / transpose in both precisions
    from clss.device import storage_dtype
    x = np.random.default_rng(b).standard_normal(shape).astype(storage_dtype(prec))
    x.reshape(-1)[3] = -0.0
    for mode in s2d.MODES:
        y = s2d.depth_to_space(any_dev, prec, any_dev.to_device(x, prec), b, mode).get()
        want = _d2s_reference(x, b, mode)
        assert y.dtype == want.dtype and np.array_equal(y.view(np.uint8), want.view(np.uint8)), mode
