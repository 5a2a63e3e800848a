"""`clss model info FILE`: a model's ops against clss's op table, from the file alone
(no device, no shapes resolved, nothing built, external data not read). Exit status 0
when every op type is supported, 1 when something is not, 2 for a bad file or flag."""
from __future__ import annotations

import glob
import json
import os

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from clss.cli import main
from clss.model import graph, optable


def _model(nodes, inputs, outputs, inits=(), opset=17, domains=(), producer=("", "")):
    g = helper.make_graph(nodes, "g", inputs, outputs, list(inits))
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", opset)]
                          + [helper.make_opsetid(d, 1) for d in domains],
                          producer_name=producer[0], producer_version=producer[1])
    return m


def _vi(name, shape, t=TensorProto.FLOAT):
    return helper.make_tensor_value_info(name, t, shape)


def _w(name, shape, seed=0):
    return numpy_helper.from_array(np.random.default_rng(seed).standard_normal(shape).astype(np.float32), name)


def _conv_relu(shape=(1, 3, 8, 8)):
    nodes = [helper.make_node("Conv", ["x", "w"], ["c"], pads=[1, 1, 1, 1], name="conv"),
             helper.make_node("Relu", ["c"], ["y"], name="relu")]
    return _model(nodes, [_vi("x", list(shape))], [_vi("y", None)], [_w("w", (4, 3, 3, 3))])


def _info(tmp_path, m, *flags, name="m.onnx", **save):
    p = tmp_path / name
    onnx.save(m, str(p), **save)
    return p, main(["model", "info", str(p), *map(str, flags)])


def _run(capsys, argv):
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    assert "Traceback" not in cap.out + cap.err
    return rc, cap


def test_supported_model(tmp_path, capsys):
    p, rc = _info(tmp_path, _conv_relu())
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "verdict: all 2 op types supported" in out
    assert optable.OPS["Conv"] in out and optable.OPS["Relu"] in out   # the limits, from the table
    assert "opset: 17" in out and "input  x: float [1, 3, 8, 8]" in out and "external data: none" in out


def test_unsupported_ops_say_why(tmp_path, capsys):
    nodes = [helper.make_node("Relu", ["x"], ["r"], name="relu"),
             helper.make_node("NonMaxSuppression", ["boxes", "scores"], ["sel"], name="nms"),
             helper.make_node("FancyOp", ["r"], ["y"], domain="com.example", name="fancy")]
    m = _model(nodes, [_vi("x", [1, 3, 4, 4]), _vi("boxes", [1, 6, 4]), _vi("scores", [1, 1, 6])],
               [_vi("y", None), _vi("sel", None, TensorProto.INT64)], domains=("com.example",))
    p, rc = _info(tmp_path, m, "--json", tmp_path / "r.json")
    out = capsys.readouterr().out
    assert rc == 1, out
    assert "2 of 3 op types unsupported: NonMaxSuppression (no kernel), com.example:FancyOp (custom domain" in out
    assert graph.NO_KERNEL in out and "'nms'" in out and "'fancy'" in out
    r = json.loads((tmp_path / "r.json").read_text())
    assert r["supported"] is False
    assert r["ops"]["NonMaxSuppression"]["status"] == "unsupported"
    assert r["ops"]["com.example:FancyOp"]["refused"][0]["reason"].startswith("custom domain 'com.example'")
    assert r["ops"]["Relu"]["status"] == "supported" and r["ops"]["Relu"]["limits"] == optable.OPS["Relu"]
    assert r["opsets"] == {"ai.onnx": 17, "com.example": 1}


def test_dynamo_style_external_data(tmp_path, capsys, monkeypatch):
    """What torch's default (dynamo) exporter writes: opset 18, symbolic batch, weights in
    a .onnx.data file beside the model, ReduceMean for AdaptiveAvgPool2d(1). The data file
    is never read: the report holds with it missing too, and says so."""
    nodes = [helper.make_node("Conv", ["x", "w"], ["c"], pads=[1, 1, 1, 1], name="conv"),
             helper.make_node("ReduceMean", ["c", "axes"], ["m"], keepdims=1, name="pool"),
             helper.make_node("Mul", ["c", "m"], ["y"], name="scale")]
    inits = [_w("w", (16, 3, 3, 3)), numpy_helper.from_array(np.array([2, 3], np.int64), "axes")]
    m = _model(nodes, [_vi("x", ["s0", 3, 32, 32])], [_vi("y", ["s0", 16, 32, 32])], inits, opset=18,
               producer=("pytorch", "2.13.0"))
    loads = []
    real = onnx.load_external_data_for_model
    monkeypatch.setattr(onnx, "load_external_data_for_model", lambda *a, **k: loads.append(a) or real(*a, **k))
    p, rc = _info(tmp_path, m, name="net.onnx", save_as_external_data=True, all_tensors_to_one_file=True,
                  location="net.onnx.data", size_threshold=0)
    out = capsys.readouterr().out
    assert rc == 0, out
    assert (tmp_path / "net.onnx.data").stat().st_size > 16 * 27 * 4
    assert "producer pytorch 2.13.0" in out and "opset: 18" in out
    assert "external data: 2 tensor(s) in net.onnx.data" in out and "not read here" in out
    assert "ReduceMean" in out and "verdict: all 3 op types supported" in out
    assert not loads
    (tmp_path / "net.onnx.data").unlink()
    assert main(["model", "info", str(p)]) == 1
    out = capsys.readouterr().out
    assert "net.onnx.data (" in out and "MISSING" in out and "external data file 'net.onnx.data' is missing" in out


def test_symbolic_dims_are_shown_with_a_hint(tmp_path, capsys):
    nodes = [helper.make_node("Relu", ["x"], ["y"])]
    m = _model(nodes, [_vi("x", ["N", 3, "H", "W"])], [_vi("y", ["N", 3, "H", "W"])])
    p, rc = _info(tmp_path, m, "--json", tmp_path / "s.json")
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "input  x: float ['N', 3, 'H', 'W']" in out
    assert "--input-shape x=1x3x64x64" in out
    r = json.loads((tmp_path / "s.json").read_text())
    assert r["inputs"] == [{"name": "x", "type": "float", "shape": ["N", 3, "H", "W"], "symbolic": True}]


def test_folded_chains_need_no_kernel(tmp_path, capsys):
    """Shape -> Gather -> Range -> Cast: no kernel for Shape or Range, but clss evaluates
    them at load; a Range of a run-time value would be unsupported."""
    nodes = [helper.make_node("Shape", ["x"], ["s"]),
             helper.make_node("Gather", ["s", "i"], ["n"], axis=0),
             helper.make_node("Range", ["zero", "n", "one"], ["r"]),
             helper.make_node("Cast", ["r"], ["rf"], to=TensorProto.FLOAT),
             helper.make_node("Add", ["x", "rf"], ["y"])]
    inits = [numpy_helper.from_array(np.array(3, np.int64), "i"),
             numpy_helper.from_array(np.array(0, np.int64), "zero"),
             numpy_helper.from_array(np.array(1, np.int64), "one")]
    m = _model(nodes, [_vi("x", [1, 2, 3, 5])], [_vi("y", None)], inits)
    p, rc = _info(tmp_path, m, "--json", tmp_path / "f.json")
    out = capsys.readouterr().out
    assert rc == 0, out
    r = json.loads((tmp_path / "f.json").read_text())
    assert r["ops"]["Range"]["status"] == "folded" and r["ops"]["Shape"]["status"] == "folded"
    assert r["ops"]["Gather"]["folded"] == 1 and r["ops"]["Add"]["folded"] == 0
    # Range of a graph input's value: runs with the model, and clss has no kernel for it
    nodes[2] = helper.make_node("Range", ["zero", "lim", "one"], ["r"])
    m = _model(nodes, [_vi("x", [1, 2, 3, 5]), _vi("lim", [], TensorProto.INT64)], [_vi("y", None)], inits)
    p, rc = _info(tmp_path, m)
    out = capsys.readouterr().out
    assert rc == 1 and "Range (no kernel)" in out, out


def test_opsets(tmp_path, capsys):
    # an op of a later opset than the model's; one that changed after the last opset clss knows
    m = _model([helper.make_node("Gelu", ["x"], ["y"])], [_vi("x", [2, 3])], [_vi("y", [2, 3])], opset=17)
    p, rc = _info(tmp_path, m)
    out = capsys.readouterr().out
    assert rc == 1 and "not an ONNX op at opset 17 (it came with opset 20)" in out, out
    m = _model([helper.make_node("Range", ["a", "b", "c"], ["y"]), helper.make_node("Relu", ["x"], ["z"])],
               [_vi("a", []), _vi("b", []), _vi("c", []), _vi("x", [2])], [_vi("y", None), _vi("z", [2])],
               opset=27)
    p, rc = _info(tmp_path, m)
    out = capsys.readouterr().out
    assert rc == 1 and "Range (changed at opset 27)" in out and "Relu" in out, out
    m = _model([helper.make_node("Relu", ["x"], ["y"])], [_vi("x", [2])], [_vi("y", [2])], opset=9)
    p, rc = _info(tmp_path, m)
    out = capsys.readouterr().out
    assert rc == 1 and "opset 9 is below 11" in out, out


def test_inputs_clss_needs_known_at_load(tmp_path, capsys):
    """Resize scales fed at run time: a value input where clss plans for the inputs'
    values, else a refused node."""
    nodes = [helper.make_node("Resize", ["x", "", "sc"], ["y"], mode="nearest", name="up")]
    m = _model(nodes, [_vi("x", [1, 3, 4, 4]), _vi("sc", [4])], [_vi("y", None)])
    p, rc = _info(tmp_path, m)
    out = capsys.readouterr().out
    if hasattr(graph, "find_value_inputs"):
        assert rc == 0 and "value input sc: clss reads its value at each run" in out, out
    else:
        assert rc == 1 and "Resize 'up' (input 2 ('sc') must be known at load)" in out, out


@pytest.mark.parametrize("content, expected", [(b"not a model", "not an ONNX model"),
                                               (b"", "not an ONNX model: no IR version, opset or nodes"),
                                               (None, "no such model file")])
def test_bad_file_is_one_line(tmp_path, capsys, content, expected):
    p = tmp_path / "bad.onnx"
    if content is not None:
        p.write_bytes(content)
    rc, cap = _run(capsys, ["model", "info", p])
    assert rc == 2 and expected in cap.err and cap.err.startswith("clss model info: ")
    assert len(cap.err.strip().splitlines()) == 1
    rc, cap = _run(capsys, ["model", "info", tmp_path])
    assert rc == 2 and "is a directory" in cap.err


def test_json_report(tmp_path, capsys):
    p, rc = _info(tmp_path, _conv_relu(), "--json", tmp_path / "r.json")
    capsys.readouterr()
    assert rc == 0
    r = json.loads((tmp_path / "r.json").read_text())
    assert r["supported"] is True and r["verdict"] == "all 2 op types supported"
    assert r["opset"] == 17 and r["nodes"] == 2 and r["external_data"] == {"tensors": 0, "files": []}
    assert r["ops"]["Conv"] == {"op": "Conv", "domain": "", "nodes": 1, "folded": 0, "supported": True,
                                "status": "supported", "limits": optable.OPS["Conv"],
                                "opsets": optable.opsets_text("Conv"), "refused": []}
    rc, cap = _run(capsys, ["model", "info", p, "--json", p])
    assert rc == 2 and "is an input file" in cap.err


def test_help_and_group(capsys):
    rc, cap = _run(capsys, ["model", "info", "--help"])
    assert rc == 0
    for text in ("examples:", "clss model info net.onnx", "how it differs from `clss info`", "exit status"):
        assert text in cap.out
    rc, cap = _run(capsys, ["model", "--help"])
    assert rc == 0 and "info" in cap.out and "run" in cap.out
    rc, cap = _run(capsys, ["model"])
    assert rc == 2
    rc, cap = _run(capsys, ["model", "nosuch"])
    assert rc == 2 and "unknown subcommand 'nosuch'" in cap.err
    rc, cap = _run(capsys, ["--help"])
    assert "model" in cap.out and "info" in cap.out and "run" in cap.out
    rc, cap = _run(capsys, ["model", "run", "--help"])
    assert rc == 0 and "--compare-ort" in cap.out


def test_agrees_with_the_load(tmp_path, capsys):
    """The op types `clss model info` calls unsupported are those clss.Model refuses."""
    import clss
    from clss.model import UnsupportedModelError
    nodes = [helper.make_node("Relu", ["x"], ["r"], name="relu"),
             helper.make_node("NonMaxSuppression", ["boxes", "scores"], ["sel"], name="nms"),
             helper.make_node("Sigmoid", ["r"], ["y"], name="sig")]
    m = _model(nodes, [_vi("x", [1, 3, 4, 4]), _vi("boxes", [1, 6, 4]), _vi("scores", [1, 1, 6])],
               [_vi("y", [1, 3, 4, 4]), _vi("sel", None, TensorProto.INT64)])
    p, rc = _info(tmp_path, m, "--json", tmp_path / "r.json")
    capsys.readouterr()
    r = json.loads((tmp_path / "r.json").read_text())
    with pytest.raises(UnsupportedModelError) as e:
        clss.Model(str(p))
    assert {op for _, op, _, _ in e.value.nodes} == {k for k, o in r["ops"].items() if not o["supported"]}


_EXPORTED = sorted(glob.glob(os.path.join(os.path.dirname(__file__), "fixtures", "exported", "*.onnx")))


@pytest.mark.skipif(not _EXPORTED, reason="no exported-model fixtures (tests/fixtures/exported)")
def test_exported_suite_is_supported(capsys):
    """Every PyTorch export of the exported-model suite (both exporters; the dynamo ones
    keep external data) passes: the suite is what clss.Model runs."""
    for p in _EXPORTED:
        rc, cap = _run(capsys, ["model", "info", p])
        assert rc == 0 and "verdict: all " in cap.out, (p, cap.out)
        if os.path.exists(p + ".data"):
            assert "not read here" in cap.out, p
