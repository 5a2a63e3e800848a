"""The channel-blocked layout between layers (clss/model/layout.py): which tensors stay
blocked, the blocked ops against their NCHW forms, and whole graphs with the layout
against the per-layer transforms (the fast path's reference) and onnxruntime.

Tolerances: the blocked pool and nearest resize copy or compare values and are checked
bit for bit; a blocked conv chain sums a padded tensor's channels in blocks of the
vector width where the per-layer path sums them in blocks of ceil(C / ceil(C / 16)), so
graphs are compared within the conv tolerance (clss/tolerance.py DEFAULT_TOL)."""
from __future__ import annotations

import numpy as np
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

import clss
from clss import selfcheck
from clss.model import layout
from clss.model.graph import build
from clss.model.passes import run_passes
from clss.ops import conv, pool, resize
from clss.tolerance import DEFAULT_TOL, compare


def _needs_blocked(d, prec="fp32"):
    if not d.is_cpu or not selfcheck.enabled(d, prec, "conv.blocked"):
        pytest.skip(f"{d.info.name}: the channel-blocked conv does not apply here (a CPU layout)")


def _needs_layout(d, prec):
    """The blocked layout's own primitives are tested where its self-check lets clss use them:
    pip's PoCL 3.0 on a CPU newer than its LLVM 14 (an AVX-512 EPYC taken for a Zen 3)
    miscompiles them, and aborts in its compiler; the self-check, in a process of its own,
    turns the layout off there, and clss never launches them."""
    if not layout.enabled(d, prec):
        pytest.skip(f"{d.info.name}: the blocked layout is off on this device (its self-check failed)")


def _w(g, co, ci, k=3):
    return (g.standard_normal((co, ci, k, k)) * (0.6 / np.sqrt(ci * k * k))).astype(np.float32)


def _unet(cin=9, h=10, w=26, c1=16, c2=24, c3=32, tail=7):
    """conv -> conv -> pool -> conv -> resize -> concat(skip) -> conv -> conv (graph output):
    odd widths, a padded channel count (c2), a Sigmoid-fused conv, a residual-free chain."""
    g = np.random.default_rng(7)
    inits = [numpy_helper.from_array(a, n) for n, a in (
        ("w1", _w(g, c1, cin)), ("b1", g.standard_normal(c1).astype(np.float32) * 0.1),
        ("w2", _w(g, c2, c1)), ("b2", g.standard_normal(c2).astype(np.float32) * 0.1),
        ("w3", _w(g, c3, c2)), ("b3", g.standard_normal(c3).astype(np.float32) * 0.1),
        ("w4", _w(g, 16, c3 + c1)), ("b4", g.standard_normal(16).astype(np.float32) * 0.1),
        ("w5", _w(g, tail, 16)), ("sc", np.array([1, 1, 2, 2], np.float32)))]
    cv = dict(kernel_shape=[3, 3], pads=[1, 1, 1, 1])
    nodes = [helper.make_node("Conv", ["x", "w1", "b1"], ["c1"], **cv), helper.make_node("Relu", ["c1"], ["r1"]),
             helper.make_node("Conv", ["r1", "w2", "b2"], ["c2"], **cv), helper.make_node("Relu", ["c2"], ["r2"]),
             helper.make_node("MaxPool", ["r2"], ["p2"], kernel_shape=[2, 2], strides=[2, 2]),
             helper.make_node("Conv", ["p2", "w3", "b3"], ["c3"], **cv), helper.make_node("Sigmoid", ["c3"], ["r3"]),
             helper.make_node("Resize", ["r3", "", "sc"], ["u3"], mode="nearest",
                              coordinate_transformation_mode="asymmetric", nearest_mode="floor"),
             helper.make_node("Concat", ["u3", "r1"], ["cat"], axis=1),
             helper.make_node("Conv", ["cat", "w4", "b4"], ["c4"], **cv),
             helper.make_node("LeakyRelu", ["c4"], ["r4"], alpha=0.1),
             helper.make_node("Conv", ["r4", "w5"], ["y"], **cv)]
    graph = helper.make_graph(nodes, "unet", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, cin, h, w])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, tail, h, w])], inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    return m


def _graph(model):
    g, _, _ = build(model, None)
    run_passes(g)
    return g


def test_which_tensors_stay_blocked():
    g = _graph(_unet())
    got = layout.blocked_tensors(g, 16)
    names = {n.outputs[0]: n.op for n in g.nodes}
    # every inner tensor of the chain; the graph output, and r4, read by a conv with
    # fewer than 8 outputs (the NCHW kernel), stay NCHW
    assert set(got) == set(names) - {"y", "r4"}, got
    assert got["r2"] == (1, 2, 10, 26, 16)          # 24 channels padded to two blocks of 16
    assert got["cat"] == (1, 3, 10, 26, 16)
    # in blocks of 8, 24 channels are whole blocks too
    assert layout.blocked_tensors(g, 8)["r2"] == (1, 3, 10, 26, 8)
    # with conv2d_thin (fast path conv.thin), the 7-output head reads r4 blocked
    assert set(layout.blocked_tensors(g, 16, thin=True)) == set(names) - {"y"}
    assert "r4" in layout.blocked_tensors(g, 8, thin=True)


def test_edges_stay_nchw():
    # a first conv with 5 outputs writes NCHW (a vector of output channels would be mostly
    # empty): its output r1, and so the concat it joins, the resize and the conv before it
    # stay NCHW; the conv after it reads r1's 5 channels in place and writes blocked
    g = _graph(_unet(c1=5))
    got = layout.blocked_tensors(g, 16)
    assert "r1" not in got and "cat" not in got and "u3" not in got and "r3" not in got
    assert "r2" in got and "p2" in got
    # a 5-channel input no longer stops the chain: the first conv reads it NCHW in place
    # (conv.FEW_IN) and writes blocked
    assert "r1" in layout.blocked_tensors(_graph(_unet(cin=5)), 16)
    # a concat input whose channels are not whole blocks: no blocked concat
    g = _graph(_unet(c1=24))
    got = layout.blocked_tensors(g, 16)
    assert "cat" not in got and "r1" not in got


@pytest.mark.parametrize("prec, shape", [("fp32", (9, 10, 26)), ("fp16", (17, 12, 38))])
def test_graph_against_reference_and_onnxruntime(any_dev, prec, shape):
    _needs_blocked(any_dev, prec)
    cin, h, w = shape
    model = _unet(cin, h, w)
    x = np.random.default_rng(3).standard_normal((1, cin, h, w)).astype(np.float32)
    outs = {}
    for fast in (True, False):
        with selfcheck.forcing("model.blocked_layout", fast):
            m = clss.Model(model, device=any_dev, precision=prec)
            assert bool(m.graph.blocked) == fast
            outs[fast] = m.run({"x": x})["y"]
    tol = DEFAULT_TOL[prec]
    c = compare(outs[True], outs[False], tol)
    assert c.passed, f"blocked layout against per-layer transforms: {c}"
    want = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"]).run(None, {"x": x})[0]
    c = compare(outs[True], want, tol)
    assert c.passed, f"blocked layout against onnxruntime: {c}"


def _blocked(d, prec, a, blk):
    x = d.to_device(a, prec)
    return conv.to_blocked(d, prec, x, blk, -(-a.shape[1] // blk))


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
@pytest.mark.parametrize("blk", [8, 16])
def test_pool_and_resize_blocked_bit_exact(any_dev, prec, blk):
    _needs_layout(any_dev, prec)
    g = np.random.default_rng(11)
    a = g.standard_normal((2, 19, 9, 23)).astype(np.float32)
    a[0, 3, 1, :4] = [0.0, -0.0, np.nan, 1.0]
    xb = _blocked(any_dev, prec, a, blk)
    x = any_dev.to_device(a, prec)
    got = pool.max_pool(any_dev, prec, xb, (2, 2), stride=(2, 2), blocked=True)
    want = _blocked(any_dev, prec, any_dev.to_host(pool.max_pool(any_dev, prec, x, (2, 2), stride=(2, 2))), blk)
    np.testing.assert_array_equal(any_dev.to_host(got).view(np.uint8), any_dev.to_host(want).view(np.uint8))
    for coord, nearest, out_hw in (("asymmetric", "floor", (18, 46)), ("half_pixel", "round_prefer_floor", (20, 37))):
        got = resize.resize(any_dev, prec, xb, out_hw=out_hw, mode="nearest", coord=coord, nearest_mode=nearest,
                            blocked=True)
        ref = resize.resize(any_dev, prec, x, out_hw=out_hw, mode="nearest", coord=coord, nearest_mode=nearest)
        want = _blocked(any_dev, prec, any_dev.to_host(ref), blk)
        np.testing.assert_array_equal(any_dev.to_host(got).view(np.uint8), any_dev.to_host(want).view(np.uint8))


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_conv_blocked_in_and_out(any_dev, prec):
    """conv2d reading a blocked input and writing a blocked output equals the NCHW conv
    on every real channel (a padded 24-channel output, a stride-2 layer)."""
    _needs_blocked(any_dev, prec)
    v = conv.vector_width(any_dev)
    g = np.random.default_rng(5)
    a = g.standard_normal((1, 20, 11, 29)).astype(np.float32)
    w = any_dev.to_device(_w(g, 24, 20), prec)
    b = any_dev.to_device(g.standard_normal(24).astype(np.float32), prec)
    x = any_dev.to_device(a, prec)
    for strides in ((1, 1), (2, 2)):
        ref = any_dev.to_host(conv.conv2d(any_dev, prec, x, w, b, strides=strides, pads=(1, 1, 1, 1),
                                          activation="relu"))
        yb = conv.conv2d(any_dev, prec, _blocked(any_dev, prec, a, v), w, b, strides=strides, pads=(1, 1, 1, 1),
                         activation="relu", out_blocked=True)
        assert yb.shape == (1, -(-24 // v), *ref.shape[2:], v)
        got = any_dev.to_host(yb).transpose(0, 1, 4, 2, 3).reshape(1, -1, *ref.shape[2:])[:, :24]
        c = compare(got, ref, DEFAULT_TOL[prec])
        assert c.passed, c


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
@pytest.mark.parametrize("cin, cout, k, blk, act, res", [
    (16, 4, 3, 16, "tanh", None), (16, 3, 3, 16, "none", "before"), (20, 7, 3, 16, "relu", "after"),
    (24, 5, 3, 8, "sigmoid", None), (8, 1, 1, 8, "leaky_relu", "before"), (37, 2, 3, 16, "none", None)])
def test_thin_conv_reads_blocked_input(any_dev, prec, cin, cout, k, blk, act, res):
    """conv2d_thin (a conv with < 8 outputs on a blocked input, fast path conv.thin)
    equals the NCHW conv within the conv tolerance: its lanes sum a block's channels as a
    tree. Odd widths and heights (edge and inside work-items, a ragged last tile), a
    padded last block, 1 to 7 outputs (a partial second group of 4), every epilogue."""
    _needs_blocked(any_dev, prec)
    if not selfcheck.enabled(any_dev, prec, "conv.thin"):
        pytest.skip("conv.thin does not pass its self-check here")
    g = np.random.default_rng(cin * 31 + cout)
    h, wd = 7, 41
    a = g.standard_normal((2, cin, h, wd)).astype(np.float32)
    w = any_dev.to_device(_w(g, cout, cin, k), prec)
    b = any_dev.to_device(g.standard_normal(cout).astype(np.float32), prec)
    r = any_dev.to_device(g.standard_normal((2, cout, h, wd)).astype(np.float32), prec) if res else None
    kw = dict(pads=(k // 2,) * 4, activation=act, alpha=0.1, residual=r, residual_before_act=res == "before")
    ref = any_dev.to_host(conv.conv2d(any_dev, prec, any_dev.to_device(a, prec), w, b, **kw))
    packed = {}
    for _ in range(2):      # packed once, reused
        got = any_dev.to_host(conv.conv2d(any_dev, prec, _blocked(any_dev, prec, a, blk), w, b, packed=packed, **kw))
        c = compare(got, ref, DEFAULT_TOL[prec])
        assert c.passed, c
    assert packed[prec].key[0] == "thin"


def test_blocked_conv_refuses_what_it_cannot_do(dev):
    _needs_blocked(dev)
    g = np.random.default_rng(1)
    x = dev.to_device(g.standard_normal((1, 16, 5, 9)).astype(np.float32))
    w = dev.to_device(_w(g, 16, 16))
    with pytest.raises(ValueError, match="blocked"):
        conv.conv2d(dev, "fp32", x, w, residual=dev.to_device(np.zeros((1, 16, 5, 9), np.float32)),
                    pads=(1, 1, 1, 1), out_blocked=True)
    with pytest.raises(ValueError, match="blocked"):
        conv.conv2d(dev, "fp32", x, dev.to_device(_w(g, 16, 16, 1)), out_blocked=True)
    # a thin conv reads blocks of 8 or 16 only
    xb = conv.to_blocked(dev, "fp32", x, 12, 2)
    with pytest.raises(ValueError, match="blocks of 8 or 16"):
        conv.conv2d(dev, "fp32", xb, dev.to_device(_w(g, 3, 16)), pads=(1, 1, 1, 1))


def _gather_net(h=9, w=23):
    """Slices of one input's channels and a second input, concatenated, read by two
    blocked convs (NSRD's and NSRR's input stacks): the concat writes the blocked layout
    (clss.ConcatBlocked) and reads the slices' channel ranges in place."""
    g = np.random.default_rng(9)
    inits = [numpy_helper.from_array(a, n) for n, a in (
        ("wa", _w(g, 16, 19)), ("wb", _w(g, 12, 19)),
        ("s0", np.array([2], np.int64)), ("e0", np.array([14], np.int64)), ("ax", np.array([1], np.int64)),
        ("s1", np.array([20], np.int64)), ("e1", np.array([22], np.int64)))]
    cv = dict(kernel_shape=[3, 3], pads=[1, 1, 1, 1])
    nodes = [helper.make_node("Slice", ["x", "s0", "e0", "ax"], ["xs0"]),
             helper.make_node("Slice", ["x", "s1", "e1", "ax"], ["xs1"]),
             helper.make_node("Concat", ["xs0", "z", "xs1"], ["cat"], axis=1),
             helper.make_node("Conv", ["cat", "wa"], ["ya"], **cv),
             helper.make_node("Conv", ["cat", "wb"], ["yb"], **cv)]
    ins = [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 30, h, w]),
           helper.make_tensor_value_info("z", TensorProto.FLOAT, [1, 5, h, w])]
    outs = [helper.make_tensor_value_info("ya", TensorProto.FLOAT, [1, 16, h, w]),
            helper.make_tensor_value_info("yb", TensorProto.FLOAT, [1, 12, h, w])]
    return _model(nodes, "gather", ins, outs, inits)


def _model(nodes, name, ins, outs, inits):
    m = helper.make_model(helper.make_graph(nodes, name, ins, outs, inits),
                          opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    return m


def test_concat_into_blocked_reads_slices_in_place():
    g = _graph(_gather_net())
    layout.apply(g, 16)
    ops = [n.op for n in g.nodes]
    assert ops.count("Slice") == 0 and ops.count("clss.ConcatBlocked") == 1, ops
    cat = next(n for n in g.nodes if n.op == "clss.ConcatBlocked")
    assert cat.inputs == ["x", "z", "x"] and cat.attrs["ranges"] == [(2, 12), (0, 5), (20, 2)]
    # 19 channels in the blocks a conv's NCHW input gets (conv.input_block): 2 x 10, not 2 x 16
    assert g.blocked["cat"] == (1, 2, 9, 23, 10) and cat.attrs["block"] == 10


@pytest.mark.parametrize("cin, block", [(60, 15), (18, 9), (19, 10), (64, 16), (16, 16), (10, 10), (33, 11),
                                        (8, 8)])
def test_input_block_splits_channels_evenly(cin, block):
    from clss.ops import conv
    assert conv.input_block(cin) == block


@pytest.mark.parametrize("net", ["gather", "scaled"])
@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_concat_into_blocked_against_onnxruntime(any_dev, prec, net):
    _needs_blocked(any_dev, prec)
    model = {"gather": _gather_net, "scaled": _scaled_gather_net}[net]()
    g = np.random.default_rng(2)
    shape = lambda i: [d.dim_value for d in i.type.tensor_type.shape.dim]
    # x and z signed; the scale maps r and m positive, as NSRR's reweighting
    feeds = {i.name: (g.uniform(0, 10, shape(i)) if i.name in ("r", "m") else g.standard_normal(shape(i)))
             .astype(np.float32) for i in model.graph.input}
    m = clss.Model(model, device=any_dev, precision=prec)
    assert "cat" in m.graph.blocked and any(n.op == "clss.ConcatBlocked" for n in m.graph.nodes)
    got = m.run(feeds)
    want = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"]).run(None, feeds)
    for o, ref in zip(model.graph.output, want):
        c = compare(got[o.name], ref, DEFAULT_TOL[prec])
        assert c.passed, f"{o.name}: {c}"


def _scaled_gather_net(h=9, w=23):
    """NSRR's reweighted input stack in small: slices of x, each times a one-channel map
    (a Slice of r, or a whole [1,1,H,W] input, on either side of the Mul), concatenated
    and read by a blocked conv. One Mul's output is also a graph output: it stays a node."""
    g = np.random.default_rng(11)
    c = lambda *v: np.array(v, np.int64)
    inits = [numpy_helper.from_array(a, n) for n, a in (
        ("wa", _w(g, 16, 25)), ("ax", c(1)), ("s0", c(0)), ("e0", c(4)), ("s1", c(4)), ("e1", c(16)),
        ("s2", c(16)), ("e2", c(21)), ("r0", c(1)), ("r1", c(2)))]
    cv = dict(kernel_shape=[3, 3], pads=[1, 1, 1, 1])
    nodes = [helper.make_node("Slice", ["x", "s0", "e0", "ax"], ["x0"]),
             helper.make_node("Slice", ["x", "s1", "e1", "ax"], ["x1"]),
             helper.make_node("Slice", ["x", "s2", "e2", "ax"], ["x2"]),
             helper.make_node("Slice", ["r", "r0", "r1", "ax"], ["rs"]),
             helper.make_node("Mul", ["x1", "rs"], ["m1"]),
             helper.make_node("Mul", ["m", "x2"], ["m2"]),
             helper.make_node("Mul", ["x0", "m"], ["m0"]),
             helper.make_node("Concat", ["x0", "m1", "m2", "m0"], ["cat"], axis=1),
             helper.make_node("Conv", ["cat", "wa"], ["ya"], **cv)]
    vi = lambda n, ch: helper.make_tensor_value_info(n, TensorProto.FLOAT, [1, ch, h, w])
    return _model(nodes, "scaled", [vi("x", 30), vi("r", 3), vi("m", 1)], [vi("ya", 16), vi("m0", 4)], inits)


def test_concat_into_blocked_computes_channel_broadcast_muls():
    g = _graph(_scaled_gather_net())
    layout.apply(g, 16)
    ops = [n.op for n in g.nodes]
    # x0 is read twice (the concat and m0's Mul): its Slice stays; m0 is a graph output
    assert ops.count("Mul") == 1 and ops.count("Slice") == 1 and ops.count("clss.ConcatBlocked") == 1, ops
    cat = next(n for n in g.nodes if n.op == "clss.ConcatBlocked")
    assert cat.inputs == ["x0", "x", "x", "m0", "r", "m"]
    assert cat.attrs["ranges"] == [(0, 4), (4, 12), (16, 5), (0, 4)]
    assert cat.attrs["scales"] == [None, (0, 1), (1, 0), None]


@pytest.mark.parametrize("one_source", [True, False])
@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_scaled_concat_is_the_mul_bit_for_bit(any_dev, prec, one_source):
    """concat_to_blocked with a scaled input against Mul then the blocked layout in numpy:
    the product rounded once to the storage type, odd width (a partial 16-pixel run), a
    block (7) that splits the inputs, N = 2, and the last block's padding channels zero.
    Inputs from one tensor take one to_blocked_table launch; from two, a launch per input
    (to_blocked_table for the scaled one, to_blocked_at)."""
    _needs_layout(any_dev, prec)
    g = np.random.default_rng(3)
    n, h, w = 2, 5, 19
    x = g.standard_normal((n, 9, h, w)).astype(np.float32)
    s = g.uniform(0, 10, (n, 3, h, w)).astype(np.float32)
    st = np.float16 if prec == "fp16" else np.float32
    xs, ss = x.astype(st), s.astype(st)
    xd, sd = any_dev.to_device(x, prec), any_dev.to_device(s, prec)
    second = xd if one_source else any_dev.to_device(x, prec)
    got = any_dev.to_host(conv.concat_to_blocked(any_dev, prec, [xd, second], 7, [(1, 5), (6, 3)],
                                                 [(sd, 2), None]))
    cat = np.concatenate([(xs[:, 1:6].astype(np.float32) * ss[:, 2:3].astype(np.float32)).astype(st),
                          xs[:, 6:9]], axis=1)
    want = np.zeros((n, 2 * 7, h, w), st)
    want[:, :8] = cat
    want = np.ascontiguousarray(want.reshape(n, 2, 7, h, w).transpose(0, 1, 3, 4, 2))
    assert got.shape == want.shape
    assert np.array_equal(got.astype(st).view(np.uint8), want.view(np.uint8))
