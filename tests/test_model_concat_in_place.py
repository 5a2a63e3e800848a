"""A batch-1 channel Concat's inputs written in place by their producers (clss/model/execute.py
concat_in_place): the concat copies only what could not be placed, and every output is bit for
bit what the copying concat gives, and within tolerance of onnxruntime; placed inputs share the
concat's bytes, unaligned offsets, graph inputs, nested concats and inputs read after the concat
are left to the copy."""
import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

import clss
from clss.model import execute

IR = 9


def _graph(h, w):
    """x -> a = conv(x), b = relu(conv(a)) (a is read again by b's conv: a skip connection),
    c = concat(a, b, x) (x a graph input: copied), d = conv(c), e = concat(d, c) (d is read
    after it, c is itself a placed concat's output: both copied), y = conv(e);
    z = concat(relu(d), a2), a graph output (allocated per run: copied into)."""
    g = np.random.default_rng(5)

    def wt(name, co, ci):
        return numpy_helper.from_array((g.standard_normal((co, ci, 3, 3)) * 0.2).astype(np.float32), name)
    inits = [wt("wa", 8, 3), wt("wb", 8, 8), wt("wd", 8, 19), wt("wy", 4, 27), wt("wa2", 5, 3)]
    conv = (lambda i, o, wname: helper.make_node("Conv", [i, wname], [o], pads=[1, 1, 1, 1]))
    nodes = [conv("x", "a", "wa"), conv("a", "b0", "wb"), helper.make_node("Relu", ["b0"], ["b"]),
             helper.make_node("Concat", ["a", "b", "x"], ["c"], axis=1), conv("c", "d", "wd"),
             helper.make_node("Concat", ["d", "c"], ["e"], axis=1), conv("e", "y", "wy"),
             conv("x", "a2", "wa2"), helper.make_node("Relu", ["d"], ["dr"]),
             helper.make_node("Concat", ["dr", "a2"], ["z"], axis=1)]
    graph = helper.make_graph(nodes, "cat", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3, h, w])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, None),
                               helper.make_tensor_value_info("z", TensorProto.FLOAT, None),
                               helper.make_tensor_value_info("a2", TensorProto.FLOAT, None)], inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = IR
    return m


def _run(model, x, dev, prec, monkeypatch, on):
    monkeypatch.setattr(execute, "CONCAT_IN_PLACE", on)
    m = clss.Model(model, device=dev, precision=prec, fuse=False)
    out = m.run({"x": x})
    ex = m._current().executor
    placed = [a for a in ex.plan.allocs.values() if a.parent is not None]
    return out, placed, ex


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
@pytest.mark.parametrize("hw", [(16, 32), (7, 13)])
def test_placed_inputs_give_the_copying_concats_bits(dev, prec, hw, monkeypatch):
    model = _graph(*hw)
    x = np.random.default_rng(1).standard_normal((1, 3) + hw).astype(np.float32)
    ref, none, _ = _run(model, x, dev, prec, monkeypatch, False)
    got, placed, ex = _run(model, x, dev, prec, monkeypatch, True)
    assert not none
    for k in ref:
        np.testing.assert_array_equal(got[k], ref[k], err_msg=k)
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    want = dict(zip(["y", "z", "a2"], sess.run(None, {"x": x})))
    tol = 1e-4 if prec == "fp32" else 3e-2
    for k in want:
        assert np.max(np.abs(got[k] - want[k])) <= tol * max(1.0, np.max(np.abs(want[k]))), k
    cats = {n.outputs[0]: n.attrs.get("_in_place", []) for n in ex.g.nodes if n.op == "Concat"}
    align = ex._align()
    item = 4 if prec == "fp32" else 2
    plane = hw[0] * hw[1] * item
    if (8 * plane) % align == 0:
        # c = concat(a, b, x): a at 0 and b at 8 planes are placed (a's second reader, b's
        # conv, comes before the concat); x, a graph input, is copied
        assert cats["c"] == [0, 1]
        # e = concat(d, c): d is read after it (by dr's Relu), and c is a placed concat's own
        # output (no sub-buffer of a sub-buffer): both copied
        assert cats["e"] == []
        # z = concat(dr, a2) is a graph output, allocated per run: nothing placed in it
        assert cats["z"] == []
        assert len(placed) == 2
        for a in placed:
            parent = ex.plan.allocs[a.parent]
            assert a.offset % align == 0 and a.offset + a.nbytes <= parent.nbytes
            assert parent.start <= a.start
    else:       # a plane of 7 x 13 is no multiple of the alignment: only offset 0 is placed
        assert all(ks in ([], [0]) for ks in cats.values())
        assert all(a.offset == 0 for a in placed)


def test_an_input_read_after_the_concat_stays_a_copy(dev, monkeypatch):
    """a feeds the concat and a conv after it: its bytes must outlive the concat's, so a
    keeps its own buffer."""
    g = np.random.default_rng(2)
    w = numpy_helper.from_array((g.standard_normal((8, 3, 1, 1))).astype(np.float32), "w")
    w2 = numpy_helper.from_array((g.standard_normal((2, 8, 1, 1))).astype(np.float32), "w2")
    nodes = [helper.make_node("Conv", ["x", "w"], ["a"]), helper.make_node("Relu", ["a"], ["b"]),
             helper.make_node("Concat", ["a", "b"], ["c"], axis=1),
             helper.make_node("Conv", ["a", "w2"], ["d"]), helper.make_node("Concat", ["c", "d"], ["y"], axis=1)]
    graph = helper.make_graph(nodes, "late", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3, 16, 32])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)], [w, w2])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = IR
    x = g.standard_normal((1, 3, 16, 32)).astype(np.float32)
    ref, _, _ = _run(model, x, dev, "fp32", monkeypatch, False)
    got, placed, ex = _run(model, x, dev, "fp32", monkeypatch, True)
    np.testing.assert_array_equal(got["y"], ref["y"])
    cats = {n.outputs[0]: n.attrs.get("_in_place", []) for n in ex.g.nodes if n.op == "Concat"}
    assert cats["c"] == [1]          # b placed, a (read by d's conv later) copied


@pytest.mark.parametrize("method", ["nsrr", "nss"])
def test_shipped_networks_as_a_gpu_runs_them_place_their_skip_concats(dev, method, monkeypatch):
    """Without the CPU's channel-blocked layout (a GPU's configuration), NSRR's and NSS's
    U-Nets concatenate NCHW tensors: their skip inputs are placed, and the frames are bit for
    bit those of the copying concats."""
    from clss.model import layout
    monkeypatch.setattr(layout, "enabled", lambda dev, prec: False)
    placed = []
    real = execute.concat_in_place
    monkeypatch.setattr(execute, "concat_in_place", lambda *a: placed.append(real(*a)) or placed[-1])
    g = np.random.default_rng(3)
    h, w = 32, 48
    frames = [(g.random((h, w, 3), np.float32) * 2, np.full((h, w), 0.5, np.float32),
               np.full((h, w, 2), 0.5, np.float32)) for _ in range(3)]
    outs = {}
    for on in (False, True):
        monkeypatch.setattr(execute, "CONCAT_IN_PLACE", on)
        up = clss.Upscaler(method=method, scale=2, device=dev)
        outs[on] = [up.step(c, d, m, (0.25, -0.25), reset=i == 0) for i, (c, d, m) in enumerate(frames)]
    assert sum(placed) > 0
    for a, b in zip(outs[False], outs[True]):
        np.testing.assert_array_equal(a, b)
