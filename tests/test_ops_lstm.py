"""The fused ConvLSTM cell (clss/ops/lstm.py, kernels/lstm.cl, passes.fuse_lstm_cell):
which graphs fuse, that the fused cell matches the ten ONNX nodes it replaces bit for bit
(and onnxruntime within the stated tolerance), NCHW and blocked gates alike. The per-case
conformance against onnxruntime is in tests/test_ops_conformance.py."""
import numpy as np
import onnx
import pytest

import clss
from clss import selfcheck
from clss.device import storage_dtype
from clss.model.graph import build
from clss.model.passes import fuse_lstm_cell, run_passes
from clss.ops import lstm
from clss.verify.cases.lstm import cell_model
from clss.verify.twin import session
from helpers import PRECISIONS
from clss.tolerance import DEFAULT_TOL, compare


def _graph(model):
    g = build(model, None, max_alloc=2**40, storage_itemsize=4)[0]
    run_passes(g)
    return g


@pytest.mark.parametrize("order", [(0, 1, 2, 3), (2, 0, 3, 1), (3, 2, 1, 0)])
def test_the_ten_nodes_fuse_whatever_the_gate_order(order):
    x = np.zeros((1, 20, 3, 5), np.float32)
    g = _graph(cell_model(x, 5, order=order))
    assert fuse_lstm_cell(g) == 1
    (cell,) = g.nodes
    assert cell.op == "clss.LSTMCell" and cell.inputs == ["x", "c"] and cell.outputs == ["h", "c_out"]
    assert tuple(cell.attrs["order"]) == order and len(cell.unfused) == 10


def _cell_with_reader(tensor):
    """The cell's graph, with one more reader of `tensor` (a Neg, a graph output)."""
    m = cell_model(np.zeros((1, 8, 3, 5), np.float32), 2)
    m.graph.node.append(onnx.helper.make_node("Neg", [tensor], ["extra"]))
    m.graph.output.append(onnx.helper.make_tensor_value_info("extra", onnx.TensorProto.FLOAT, None))
    return _graph(m)


def test_a_gate_read_twice_does_not_fuse():
    # another reader of sigmoid(f): the gates are not the cell's alone
    g = _cell_with_reader("sf")
    assert fuse_lstm_cell(g) == 0 and "clss.LSTMCell" not in [n.op for n in g.nodes]


def test_c_out_may_have_other_readers():
    g = _cell_with_reader("c_out")
    assert fuse_lstm_cell(g) == 1
    assert [n.op for n in g.nodes] == ["clss.LSTMCell", "Neg"]


@pytest.mark.parametrize("prec", PRECISIONS)
@pytest.mark.parametrize("shape, order", [((1, 16, 5, 13), (0, 1, 2, 3)), ((2, 3, 7, 9), (1, 3, 0, 2))])
def test_fused_model_matches_the_unfused_nodes_bit_for_bit(any_dev, prec, shape, order):
    # a conv makes the gates: on a CPU they stay channel-blocked into the cell
    n, ch, h, w = shape
    g = np.random.default_rng(ch)
    feeds = {"x": g.standard_normal((n, 6, h, w)).astype(np.float32),
             "c": g.standard_normal(shape).astype(np.float32)}
    model = cell_model(feeds["x"], ch, conv=True, order=order)
    fused = clss.Model(model, device=any_dev, precision=prec)
    if not selfcheck.enabled(any_dev, prec, "model.lstm_cell"):
        pytest.skip("the fused cell's fast path is off on this device")
    assert "clss.LSTMCell" in [nd.op for nd in fused.graph.nodes]
    plain = clss.Model(model, device=any_dev, precision=prec, fuse=False)
    a, b = fused.run(feeds), plain.run(feeds)
    for k in ("h", "c_out"):
        assert np.array_equal(a[k].view(np.uint8), b[k].view(np.uint8)), k
    if prec == "fp32":      # fp16 against onnxruntime: the conformance cases (rounded inputs)
        ref = dict(zip(("h", "c_out"), session(model).run(None, feeds)))
        for k in ref:
            r = compare(a[k], ref[k], DEFAULT_TOL[prec])
            assert r.passed, (k, r)


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
def test_blocked_and_nchw_gates_agree(any_dev, prec):
    n, ch, h, w = 1, 6, 4, 11          # 24 gate channels: two blocks of 16, the last half padding
    g = np.random.default_rng(7)
    gates = g.standard_normal((n, 4 * ch, h, w)).astype(np.float32)
    c = g.standard_normal((n, ch, h, w)).astype(np.float32)
    blocked = np.zeros((n, 2, h, w, 16), np.float32)
    for k in range(4 * ch):
        blocked[:, k // 16, :, :, k % 16] = gates[:, k]
    d = lambda a: any_dev.to_device(a, prec)
    h1, c1 = (t.get() for t in lstm.lstm_cell(any_dev, prec, d(gates), d(c), (3, 1, 0, 2)))
    h2, c2 = (t.get() for t in lstm.lstm_cell(any_dev, prec, d(blocked), d(c), (3, 1, 0, 2)))
    assert h1.dtype == storage_dtype(prec)
    assert np.array_equal(h1, h2) and np.array_equal(c1, c2)


def test_bad_arguments_raise(dev):
    d = lambda *s: dev.to_device(np.zeros(s, np.float32))
    with pytest.raises(ValueError, match="do not hold 4 x 3 channels"):
        lstm.lstm_cell(dev, "fp32", d(1, 11, 2, 2), d(1, 3, 2, 2))
    with pytest.raises(ValueError, match="do not hold"):
        lstm.lstm_cell(dev, "fp32", d(1, 12, 2, 3), d(1, 3, 2, 2))
    with pytest.raises(ValueError, match="permutation"):
        lstm.lstm_cell(dev, "fp32", d(1, 12, 2, 2), d(1, 3, 2, 2), (0, 1, 1, 2))
    with pytest.raises(TypeError, match="float16 storage"):
        lstm.lstm_cell(dev, "fp16", d(1, 12, 2, 2), d(1, 3, 2, 2))
