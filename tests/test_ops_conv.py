import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from clss.ops import conv
from clss.verify.cases import conv as conv_cases
from clss.verify.conformance import check
from helpers import PRECISIONS, assert_case

# Parameter combinations: kernel sizes, strides and activations come from small
# sets so the kernel builds are shared across examples (each distinct -D set
# compiles once per process); the shapes, pads, dilations and groups vary freely.
@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(op=st.sampled_from(["conv", "convT"]), n=st.integers(1, 2), cpg=st.integers(1, 5),
       opg=st.integers(1, 6), group=st.integers(1, 3), h=st.integers(1, 12), w=st.integers(1, 26),
       k=st.sampled_from([1, 3]), s=st.sampled_from([1, 2]), d=st.integers(1, 2),
       pads=st.tuples(*[st.integers(0, 2)] * 4), act=st.sampled_from(["none", "relu"]),
       residual=st.sampled_from([None, "before", "after"]), bias=st.booleans())
def test_parameter_combinations(dev, op, n, cpg, opg, group, h, w, k, s, d, pads, act, residual, bias):
    if op == "conv":
        pads = tuple(min(p, k - 1) for p in pads)   # keep every output window non-empty
        if h + pads[0] + pads[2] < (k - 1) * d + 1 or w + pads[1] + pads[3] < (k - 1) * d + 1:
            return
    else:
        pads = tuple(min(p, (k - 1) * d) for p in pads)
        if (s * (h - 1) + (k - 1) * d + 1 - pads[0] - pads[2] < 1
                or s * (w - 1) + (k - 1) * d + 1 - pads[1] - pads[3] < 1):
            return
    case = conv_cases.make_case(op, n=n, cin=cpg * group, h=h, w=w, cout=opg * group, k=(k, k), strides=(s, s),
                                pads=pads, dilations=(d, d), group=group, bias=bias, activation=act,
                                residual=residual)
    assert_case(case, dev, "fp32")


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(n=st.integers(1, 2), cin=st.integers(8, 40), cout=st.integers(8, 40), h=st.integers(1, 9),
       w=st.integers(1, 41), s=st.sampled_from([1, 2]), d=st.integers(1, 2),
       pads=st.tuples(*[st.integers(0, 2)] * 4), act=st.sampled_from(["none", "leaky_relu"]),
       residual=st.sampled_from([None, "before", "after"]), bias=st.booleans(),
       tile=st.sampled_from([(1, 14), (2, 6), (3, 4), (1, 5)]))
def test_blocked_parameter_combinations(dev, n, cin, cout, h, w, s, d, pads, act, residual, bias, tile):
    # conv2d_blocked (dense 3x3, >= 8 channels in and out) against onnxruntime: any channel
    # counts (partial input blocks and output vectors), edges, strides, dilations, tiles.
    pads = tuple(min(p, 2) for p in pads)
    if h + pads[0] + pads[2] < 2 * d + 1 or w + pads[1] + pads[3] < 2 * d + 1:
        return
    case = conv_cases.make_case(n=n, cin=cin, h=h, w=w, cout=cout, strides=(s, s), pads=pads,
                                dilations=(d, d), bias=bias, activation=act, alpha=0.1, residual=residual)
    fn = case.run
    tuning = {"NV": tile[0], "PX": tile[1]}
    case.run = lambda dv, p, i: _with_tuning(tuning, fn, dv, p, i)
    assert check(case, dev, "fp32").passed


@pytest.mark.parametrize("precision", PRECISIONS)
def test_blocked_and_reference_agree(dev, precision):
    # The fast path (conv.blocked) and its reference (the NCHW kernel) on the same layer.
    from clss import selfcheck
    dev.require(precision)
    if not selfcheck.enabled(dev, precision, "conv.blocked"):
        # (pip's PoCL 3.0 on an AVX-512 EPYC it takes for a Zen 3 aborts compiling it: the
        # self-check, in a process of its own, turns it off, and clss never launches it)
        pytest.skip(f"{dev.info.name}: conv.blocked is off on this device (its self-check failed)")
    g = np.random.default_rng(7)
    x = dev.to_device(g.standard_normal((1, 21, 9, 45)).astype(np.float32), precision)
    w = dev.to_device(g.standard_normal((19, 21, 3, 3)).astype(np.float32) * 0.2, precision)
    b = dev.to_device(g.standard_normal(19).astype(np.float32), precision)
    outs = []
    for fast in (True, False):
        with selfcheck.forcing("conv.blocked", fast):
            outs.append(dev.to_host(conv.conv2d(dev, precision, x, w, b, pads=(1, 1, 1, 1),
                                                activation="relu")).astype(np.float32))
    tol = 1e-5 if precision == "fp32" else 2e-2
    np.testing.assert_allclose(outs[0], outs[1], rtol=tol, atol=tol)


@pytest.mark.parametrize("tuning", [{"XV": 1, "CB": 8}, {"XV": 2, "CB": 3}, {"XV": 1, "CB": 1}],
                         ids=lambda t: f"XV{t['XV']}-CB{t['CB']}")
def test_other_register_blocks(dev, tuning):
    # The -D tunables change the work-item's block; every block must give the same result.
    for c in (conv_cases.make_case(cin=6, h=9, w=29, cout=7, activation="relu", residual="before"),
              conv_cases.make_case("convT", cin=5, h=5, w=11, cout=6, strides=(2, 2), pads=(1, 1, 1, 1),
                                   output_padding=(1, 1))):
        fn = c.run
        c.run = lambda d, p, i, fn=fn: _with_tuning(tuning, fn, d, p, i)
        row = check(c, dev, "fp32")
        assert row.passed, row


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("tuning", [{"S2K3": 0}, {"S2K3": 1, "XV": 1, "CB": 8}, {"S2K3": 1, "XV": 2, "CB": 8}],
                         ids=lambda t: "-".join(f"{k}{v}" for k, v in t.items()))
def test_stride2_reference_and_fast_variants(dev, tuning, precision):
    # -DCONV_S2K3=0 is the reference the fast de-interleaved path is checked against.
    for c in (conv_cases.make_case(cin=5, h=13, w=71, cout=11, strides=(2, 2), activation="relu"),
              conv_cases.make_case(cin=3, h=7, w=37, cout=13, strides=(2, 2), pads=(0, 1, 2, 0),
                                   residual="after")):
        fn = c.run
        c.run = lambda d, p, i, fn=fn: _with_tuning(tuning, fn, d, p, i)
        row = check(c, dev, precision)
        assert row.passed, row


def _with_tuning(tuning, fn, dev, prec, inputs):
    saved = dict(conv.TUNING)
    conv.TUNING.update(tuning)
    try:
        return fn(dev, prec, inputs)
    finally:
        conv.TUNING.clear()
        conv.TUNING.update(saved)


def test_nan_and_inf_propagate_through_padding_edges(dev):
    # Edge loads select zero for padding; a NaN inside the image must still reach the outputs
    # whose windows contain it, and no other output.
    x = np.zeros((1, 1, 5, 20), np.float32)
    x[0, 0, 0, 0] = np.nan
    x[0, 0, 4, 19] = np.inf
    w = np.ones((1, 1, 3, 3), np.float32)
    y = conv.conv2d(dev, "fp32", dev.to_device(x), dev.to_device(w), pads=(1, 1, 1, 1)).get()[0, 0]
    assert np.isnan(y[:2, :2]).all() and np.isinf(y[3:, 18:]).all()
    assert np.count_nonzero(~np.isfinite(y)) == 8


def test_bad_arguments_raise(dev):
    x = dev.to_device(np.zeros((1, 4, 5, 5), np.float32))
    w = dev.to_device(np.zeros((2, 3, 3, 3), np.float32))
    with pytest.raises(ValueError, match="disagree"):
        conv.conv2d(dev, "fp32", x, w)
    w = dev.to_device(np.zeros((2, 2, 3, 3), np.float32))
    with pytest.raises(ValueError, match="residual shape"):
        conv.conv2d(dev, "fp32", x, w, group=2, residual=x)
    with pytest.raises(ValueError, match="activation"):
        conv.conv2d(dev, "fp32", x, w, group=2, activation="gelu")
    with pytest.raises(ValueError, match="output would be"):
        conv.conv2d(dev, "fp32", x, dev.to_device(np.zeros((2, 4, 7, 7), np.float32)))
    with pytest.raises(TypeError, match="float16 storage"):
        conv.conv2d(dev, "fp16", x, w, group=2)


def test_onnx_auto_pad_same_and_valid(dev):
    from clss.ops import ONNX_HANDLERS
    from clss.verify.twin import node_model, run_ort
    g = np.random.default_rng(5)
    x = g.standard_normal((1, 2, 7, 10)).astype(np.float32)
    w = g.standard_normal((3, 2, 4, 3)).astype(np.float32)
    for op, wt in (("Conv", w), ("ConvTranspose", w.transpose(1, 0, 2, 3).copy())):
        for auto_pad in ("SAME_UPPER", "SAME_LOWER", "VALID"):
            ref = run_ort(node_model(op, {"x": x, "w": wt}, auto_pad=auto_pad, strides=[2, 3]),
                          {"x": x, "w": wt})[0]
            out = ONNX_HANDLERS[op].fn(dev, "fp32", {"auto_pad": auto_pad, "strides": [2, 3]},
                                       [dev.to_device(x), dev.to_device(wt)])[0].get()
            assert out.shape == ref.shape, (op, auto_pad)
            np.testing.assert_allclose(out, ref, rtol=1e-4, atol=1e-5 * np.abs(ref).max(),
                                       err_msg=f"{op} {auto_pad}")
