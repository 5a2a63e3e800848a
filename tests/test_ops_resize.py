import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from clss.ops import Unsupported, resize as rs
from clss.verify.cases import resize as rs_cases
from clss.verify.conformance import check
from helpers import PRECISIONS, assert_case

CASES = rs_cases.cases("full")


def test_case_names_unique():
    names = [c.name for c in CASES]
    assert len(names) == len(set(names))


# Hypothesis over shapes, scales and modes; the build variants stay those the sweep
# above compiled (per-process cache), so examples cost a launch, not a compile.
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(1, 2), c=st.integers(1, 9), h=st.integers(1, 12), w=st.integers(1, 12),
       sy=st.sampled_from([0.5, 0.6, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0]),
       sx=st.sampled_from([0.5, 0.6, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0]),
       mode=st.sampled_from(rs.MODES), coord=st.sampled_from(["half_pixel", "asymmetric", "align_corners"]),
       by_sizes=st.booleans(), precision=st.sampled_from(PRECISIONS))
def test_random_against_onnxruntime(dev, n, c, h, w, sy, sx, mode, coord, by_sizes, precision):
    if by_sizes:
        sizes = (max(1, int(round(h * sy))), max(1, int(round(w * sx))))
        case = rs_cases.case(n, c, h, w, mode=mode, coord=coord, sizes=sizes)
    else:
        if int(np.float32(sy) * h) < 1 or int(np.float32(sx) * w) < 1:
            return
        case = rs_cases.case(n, c, h, w, mode=mode, coord=coord, scales=(sy, sx))
    row = check(case, dev, precision)
    assert row.passed, f"{case.name} {precision}: {row.detail}"


def test_nearest_keeps_nan_payload_and_signed_zero(dev):
    x = np.arange(2 * 3 * 4 * 5, dtype=np.float32).reshape(2, 3, 4, 5)
    x.view(np.uint32)[1, 2, 3, 4] = 0x7FC01234
    x[0, 1, 2, 3] = -0.0
    y = rs.resize(dev, "fp32", dev.to_device(x), scales=(2, 2), mode="nearest").get()
    assert y.shape == (2, 3, 8, 10)
    assert y.view(np.uint32)[1, 2, 7, 9] == 0x7FC01234
    assert np.signbit(y[0, 1, 5, 7]) and y[0, 1, 5, 7] == 0


def test_output_size_follows_onnxruntime():
    # float32 product, truncated: 2.3f * 10 = 23.0 (the float64 product is 22.9999995)
    assert rs.output_size((10, 10), scales=2.3) == ((23, 23), (np.float32(2.3), np.float32(2.3)))
    (oh, ow), (sy, sx) = rs.output_size((7, 6), out_hw=(4, 3))
    assert (oh, ow) == (4, 3) and sy == np.float32(4) / np.float32(7) and sx == np.float32(0.5)
    assert rs.output_size((2, 4), out_hw=(1, 3), policy="not_smaller") == ((2, 3), (0.75, 0.75))
    assert rs.output_size((2, 4), out_hw=(1, 3), policy="not_larger") == ((1, 2), (0.5, 0.5))


def test_bad_arguments_raise(dev):
    x = dev.to_device(np.zeros((1, 1, 4, 4), np.float32))
    with pytest.raises(ValueError, match="give out_hw or scales"):
        rs.resize(dev, "fp32", x)
    with pytest.raises(ValueError, match="scales must be finite"):
        rs.resize(dev, "fp32", x, scales=(0, 2))
    with pytest.raises(ValueError, match="mode must be"):
        rs.resize(dev, "fp32", x, scales=2, mode="area")
    with pytest.raises(ValueError, match="antialias"):
        rs.resize(dev, "fp32", x, scales=0.5, mode="nearest", antialias=True)
    with pytest.raises(ValueError, match="out has shape"):
        rs.resize(dev, "fp32", x, scales=2, out=dev.empty((1, 1, 4, 4)))
    with pytest.raises(TypeError, match="float16 storage"):
        rs.resize(dev, "fp16", x, scales=2)


def test_onnx_handler_refuses_channel_and_batch_scales(dev):
    x = dev.to_device(np.zeros((1, 2, 4, 4), np.float32))
    handler = rs._onnx_resize
    with pytest.raises(Unsupported, match="axis 1"):
        handler(dev, "fp32", {"mode": b"linear"}, [x, None, np.array([1, 2, 2, 2], np.float32)])
    with pytest.raises(Unsupported, match="axis 0"):
        handler(dev, "fp32", {"mode": b"nearest"}, [x, None, None, np.array([2, 2, 8, 8], np.int64)])


def test_onnx_handler_rank3_and_axes(dev):
    # Leading axes fold into planes; axes picks the resized ones.
    from clss.verify.twin import node_model, run_ort
    g = np.random.default_rng(3)
    x = g.standard_normal((3, 5, 7)).astype(np.float32)
    sc = np.array([2.0, 1.5], np.float32)
    m = node_model("Resize", {"x": x, "roi": None, "scales": sc}, initializers={"scales": sc}, opset=19,
                   mode="linear", axes=[1, 2])
    ref = run_ort(m, {"x": x})[0]
    out = rs._onnx_resize(dev, "fp32", {"mode": b"linear", "axes": [1, 2]}, [dev.to_device(x), None, sc])[0]
    assert out.shape == ref.shape
    np.testing.assert_allclose(out.get(), ref, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("x8", [0, 1], ids=["resize-reference", "resize_x8"])
def test_resize_x8_fast_and_reference_kernels(x8, precision, dev, monkeypatch):
    # RESIZE_X8=0 is the reference kernel the 8-outputs-per-work-item resize_x8 is checked
    # against: tails (widths off multiples of 8), both filters, up and down, channels off CPT.
    monkeypatch.setattr(rs, "RESIZE_X8", x8)
    for c in (rs_cases.case(1, 5, 7, 13, mode="linear", scales=(2.0, 2.0)),
              rs_cases.case(2, 3, 11, 29, mode="cubic", scales=(1.5, 3.0)),
              rs_cases.case(1, 7, 17, 41, mode="linear", coord="align_corners", scales=(0.5, 0.75)),
              rs_cases.case(1, 2, 5, 9, mode="linear", coord="asymmetric", scales=(8.0, 8.0))):
        assert_case(c, dev, precision)
