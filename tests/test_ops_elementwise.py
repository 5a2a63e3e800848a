import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from clss.ops import elementwise as ew
from clss.verify.cases import elementwise as ew_cases
from clss.tolerance import DEFAULT_TOL, compare
from helpers import ICD, PRECISIONS, assert_case, assert_fp16_native_builds

SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@st.composite
def broadcast_pair(draw, max_rank=4):
    """An output shape and two operand shapes that broadcast to it (each may drop
    leading dims and set any dim to 1)."""
    out = draw(st.lists(st.integers(1, 7), min_size=1, max_size=max_rank))

    def operand():
        keep = draw(st.integers(0, len(out)))
        return tuple(1 if draw(st.booleans()) else n for n in out[len(out) - keep:])
    a, b = operand(), operand()
    # Device.to_device uploads a 0-d array as shape (1,), so keep one operand ranked
    return (a or tuple(out), b) if not (a and b) else (a, b)


@SETTINGS
@given(shapes=broadcast_pair(), op=st.sampled_from(["add", "div", "max", "prelu", "less"]),
       precision=st.sampled_from(PRECISIONS))
def test_broadcast_shapes(shapes, op, precision, dev):
    sa, sb = shapes
    if op == "prelu":  # the slope broadcasts to x, not the other way round
        sa = tuple(np.broadcast_shapes(sa, sb))
    assert_case(ew_cases.binary_case(op, sa, sb), dev, precision)


@SETTINGS
@given(shapes=broadcast_pair(), cond_first=st.booleans())
def test_where_broadcast(shapes, cond_first, dev):
    sa, sb = shapes
    sc = sa if cond_first else sb
    assert_case(ew_cases.where_case(sc, sa, sb), dev, "fp32")


@st.composite
def slices(draw):
    shape = tuple(draw(st.lists(st.integers(1, 6), min_size=1, max_size=4)))
    rank = len(shape)
    axes = draw(st.permutations(range(rank)))[:draw(st.integers(1, rank))]
    bound = st.one_of(st.integers(-8, 8), st.sampled_from([2**63 - 1, -2**63, 2**31]))
    starts = [draw(bound) for _ in axes]
    ends = [draw(bound) for _ in axes]
    steps = [draw(st.sampled_from([-3, -2, -1, 1, 2, 3])) for _ in axes]
    # onnxruntime reads end = INT64_MAX with a negative step as "through index 0";
    # the ONNX spec (and its reference) clamps it to dim - 1, an empty slice. clss
    # follows the spec, so that one combination has no onnxruntime oracle.
    ends = [-2**63 if e == 2**63 - 1 and s < 0 else e for e, s in zip(ends, steps)]
    axes = [a - rank if draw(st.booleans()) else a for a in axes]
    return shape, starts, ends, axes, steps


@SETTINGS
@given(params=slices())
def test_slice_parameters(params, dev):
    shape, starts, ends, axes, steps = params
    assert_case(ew_cases.slice_case(shape, starts, ends, axes, steps), dev, "fp32")


@SETTINGS
@given(shape=st.lists(st.integers(1, 5), min_size=1, max_size=4),
       mode=st.sampled_from(list(ew.PAD_MODES)), data=st.data())
def test_pad_parameters(shape, mode, data, dev):
    lo = -1 if mode == "constant" else 0
    hi = 4 if mode in ("constant", "wrap", "edge") else 1  # onnxruntime's reflect wants pad < size
    pads = [data.draw(st.integers(lo, hi)) for _ in range(2 * len(shape))]
    if mode == "reflect":
        pads = [min(p, shape[i % len(shape)] - 1) for i, p in enumerate(pads)]
    if min(n + pads[i] + pads[i + len(shape)] for i, n in enumerate(shape)) < 0:
        return
    assert_case(ew_cases.pad_case(tuple(shape), pads, mode, 0.75), dev, "fp32")


def _nan_payload(shape):
    x = np.random.default_rng(5).standard_normal(shape).astype(np.float32)
    x.view(np.uint32).flat[3] = 0x7FC0ABCD
    x.flat[5] = -0.0
    return x


def test_data_movement_is_bitwise(dev):
    # NaN payloads and signed zeros survive every layout op.
    x = _nan_payload((2, 3, 4, 5))
    xd = dev.to_device(x)
    bits = x.view(np.uint32)
    got = {
        "copy": ew.copy(dev, "fp32", xd),
        "concat": ew.concat(dev, "fp32", [xd, xd], 1),
        "slice": ew.slice(dev, "fp32", xd, [0, -1], [2, -100], [0, 3], [1, -1]),
        "pad": ew.pad(dev, "fp32", xd, [0, 0, 1, 2, 0, 0, 2, 1], "reflect"),
        "where": ew.where(dev, "fp32", dev.to_device(np.ones((1, 3, 1, 5), bool)), xd, xd),
    }
    want = {
        "copy": bits,
        "concat": np.concatenate([bits, bits], 1),
        "slice": bits[0:2, :, :, ::-1],
        "pad": np.pad(bits, [(0, 0), (0, 0), (1, 2), (2, 1)], mode="reflect"),
        "where": bits,
    }
    for name, y in got.items():
        assert np.array_equal(y.get().view(np.uint32), want[name]), name
    parts = ew.split(dev, "fp32", xd, [1, 4], -1)
    assert np.array_equal(parts[1].get().view(np.uint32), bits[..., 1:])


def test_pad_constant_value_bits_in_fp16(dev):
    x = dev.to_device(np.zeros((1, 2), np.float32), "fp16")
    y = ew.pad(dev, "fp16", x, [0, 1, 0, 1], value=1 / 3).get()
    assert y[0, 0] == np.float16(1 / 3) and y[0, 3] == np.float16(1 / 3)


@pytest.mark.parametrize("op,fn,lo,hi", [
    ("sigmoid", lambda x: 1 / (1 + np.exp(-x)), -30, 30),
    ("tanh", np.tanh, -12, 12),
    ("exp", np.exp, -80, 80),
    ("elu", lambda x: np.where(x < 0, np.expm1(x), x), -20, 5),
])
def test_transcendentals_hold_the_fp32_bound_against_float64(op, fn, lo, hi, dev):
    # PoCL's exp/tanh (not native_*) must stay inside the default fp32 bound on
    # their own, judged elementwise (rtol alone) against float64.
    x = np.linspace(lo, hi, 200003, dtype=np.float32)
    y = ew.unary(dev, "fp32", op, dev.to_device(x), 1.0).get()
    ref = fn(x.astype(np.float64))
    rel = np.abs(y - ref) / np.maximum(np.abs(ref), np.finfo(np.float32).tiny)
    assert rel.max() <= DEFAULT_TOL["fp32"].rtol, f"{op}: worst relative error {rel.max():.3g}"


def test_softmax_large_logits_are_stable(dev):
    x = np.array([[1000.0, 1001.0, 1002.0], [-1e4, 0.0, 1e4]], np.float32)
    y = ew.softmax(dev, "fp32", dev.to_device(x), -1).get()
    e = np.exp(x.astype(np.float64) - x.max(-1, keepdims=True))
    assert compare(y, e / e.sum(-1, keepdims=True), DEFAULT_TOL["fp32"]).passed


def test_min_max_propagate_nan_like_onnxruntime(dev):
    a = np.array([np.nan, 1, 2, -1, np.nan, 0, 0, 0, 5], np.float32)
    b = np.array([1, np.nan, 3, -2, np.nan, 0, 0, 0, 4], np.float32)
    for op, ref in (("min", np.minimum(a, b)), ("max", np.maximum(a, b))):
        y = ew.binary(dev, "fp32", op, dev.to_device(a), dev.to_device(b)).get()
        np.testing.assert_array_equal(y, ref)


def test_variadic_sum_in_place_fold(dev):
    xs = [np.full((2, 3), i + 1, np.float32) for i in range(4)]
    y = ew.variadic(dev, "fp32", "add", [dev.to_device(x) for x in xs]).get()
    assert np.array_equal(y, np.full((2, 3), 10, np.float32))


def test_reshape_is_a_view(dev):
    xd = dev.to_device(np.arange(24, dtype=np.float32))
    y = ew.reshape(xd, (2, 3, 4))
    assert y.base_data is xd.base_data and y.shape == (2, 3, 4)


def test_uncoalescable_rank_raises(dev):
    a = dev.to_device(np.zeros((2, 3, 4, 5, 6), np.float32))
    b = dev.to_device(np.zeros((3, 1, 5, 1), np.float32))
    with pytest.raises(ValueError, match="5 dimensions after coalescing"):
        ew.add(dev, "fp32", a, b)


def test_bad_arguments_raise(dev):
    x = dev.to_device(np.zeros((2, 3), np.float32))
    with pytest.raises(ValueError):
        ew.add(dev, "fp32", x, dev.to_device(np.zeros((4,), np.float32)))
    with pytest.raises(ValueError, match="do not add up"):
        ew.split(dev, "fp32", x, [1, 1], 1)
    with pytest.raises(ValueError, match="step 0"):
        ew.slice(dev, "fp32", x, [0], [1], [0], [0])
    with pytest.raises(ValueError, match="pad mode"):
        ew.pad(dev, "fp32", x, [0, 0, 0, 0], "symmetric")
    with pytest.raises(TypeError, match="condition"):
        ew.where(dev, "fp32", x, x, x)
    with pytest.raises(TypeError, match="float16 storage"):
        ew.relu(dev, "fp16", x)


@pytest.mark.skipif(not os.path.exists(ICD), reason="oclgrind not installed (apt-get install oclgrind)")
def test_fp16_native_variants_build(tmp_path):
    assert_fp16_native_builds(tmp_path, "elementwise", "elementwise")


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("vec", [0, 1], ids=["pad-reference", "pad8"])
def test_pad_fast_and_reference_kernels(vec, precision, dev, monkeypatch):
    # PAD_VEC=0 is the reference kernel the 8-wide pad8 is checked against.
    monkeypatch.setattr(ew, "PAD_VEC", vec)
    for c in (ew_cases.pad_case((1, 5, 11, 67), [0, 0, 0, 0, 0, 0, 5, 13], "edge"),
              ew_cases.pad_case((1, 3, 13, 41), [0, 0, 3, 5, 0, 0, 2, 0], "constant", -2.5),
              ew_cases.pad_case((2, 2, 5, 37), [0, 0, 1, 11, 0, 0, 1, 3], "reflect"),
              ew_cases.pad_case((3, 17), [1, 9, 2, 0], "wrap")):
        assert_case(c, dev, precision)


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("vec", [0, 1], ids=["bcast-reference", "binary_bcast8"])
def test_binary_bcast_fast_and_reference_kernels(vec, precision, dev, monkeypatch):
    # BCAST_VEC=0 is the reference kernel the 8-wide binary_bcast8 is checked against:
    # the blend's weight broadcast over channels, a last-axis broadcast, tails, a comparison.
    monkeypatch.setattr(ew, "BCAST_VEC", vec)
    for op, sa, sb in (("mul", (1, 1, 7, 37), (1, 3, 7, 37)), ("sub", (2, 3, 5, 1), (2, 3, 5, 29)),
                       ("add", (3, 1, 41), (3, 5, 41)), ("max", (1, 5, 1, 13), (1, 5, 3, 13)),
                       ("greater", (1, 1, 6, 23), (1, 4, 6, 23)), ("div", (2, 1, 9), (2, 7, 9))):
        assert_case(ew_cases.binary_case(op, sa, sb), dev, precision)
