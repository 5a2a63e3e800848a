"""clss bench --peers (OpenVINO beside onnxruntime) and clss bench --layers NETWORK (issue 51,
parts 1 and 5): the flags' errors, the peer columns on a tiny case, the per-layer table, and
how the peers' node names are mapped onto clss's steps."""
from __future__ import annotations

import json
import math
import shlex
from types import SimpleNamespace

import numpy as np
import pytest

from bench import layers, peers
from clss.cli.main import main

HAS_OPENVINO = peers.openvino_available()


def _one_line_error(argv, capsys) -> str:
    rc = main(shlex.split(argv))
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    return err


@pytest.mark.parametrize("argv,expected", [
    ("bench --peers ort,tensorrt --out ''", "--peers: unknown peer 'tensorrt'; the peers are ort, openvino"),
    ("bench --peers , --out ''", "--peers: name one or more of"),
    ("bench --host-waits --peers ort --out ''", "--peers goes with the cases or --layers, not with --host-waits"),
    ("bench --input-shape x=1x3x8x8 --out ''", "--input-shape goes with --layers"),
    ("bench --layers classifier --methods --out ''", "--layers and --methods exclude each other"),
    ("bench --layers nosuch.onnx --out ''", "--layers nosuch.onnx: no such file"),
    ("bench --layers nosuchnet --tiny --out ''", "--layers 'nosuchnet' matches none of the bench's networks"),
    ("bench --layers nsrr --tiny --out ''", "matches several"),
])
def test_flag_errors_are_one_line(argv, expected, capsys):
    assert expected in _one_line_error(argv, capsys)


def test_openvino_missing_names_the_flag_and_the_extra(monkeypatch, capsys):
    monkeypatch.setattr(peers, "openvino_available", lambda: False)
    err = _one_line_error("bench --peers ort,openvino --out ''", capsys)
    assert "--peers openvino: OpenVINO is not installed; pip install -e '.[peers]'" in err


def test_default_peer_is_onnxruntime_alone():
    assert peers.parse_peers(None) == ["ort"]
    assert peers.parse_peers(" ORT , ort") == ["ort"]


@pytest.mark.skipif(not HAS_OPENVINO, reason="OpenVINO not installed (pip install -e '.[peers]')")
def test_openvino_columns_on_a_tiny_case(tmp_path, capsys):
    """Both OpenVINO columns run the twin: finite times and errors against the oracle, and the
    fair ratio against the faster f32 peer, in the JSON, the table and the markdown."""
    from bench.cli import bench_main
    out = tmp_path / "b"
    assert bench_main(["--tiny", "--peers", "ort,openvino", "--filter", "network composition", "-p", "fp32",
                       "--runs", "1", "--no-peak", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    doc = json.loads((out / "bench.json").read_text())
    assert doc["peers"] == ["ort", "openvino"] and doc["openvino_default_precision"]
    assert doc["machine"]["vector_width"] >= 1
    (r,) = doc["rows"]
    assert r["status"] == "ok" and r["ort_ms"] > 0
    assert set(r["peers"]) == {"ov_f32", "ov"}
    for k, p in r["peers"].items():
        assert p["status"] == "ok" and p["ms"] > 0, k
        assert math.isfinite(p["max_err"]) and p["max_err"] < 0.1, (k, p["max_err"])
    assert r["peers"]["ov_f32"]["fp32"] and not r["peers"]["ov"]["fp32"]
    fastest = min(r["ort_ms"], r["peers"]["ov_f32"]["ms"])
    assert math.isclose(r["vs_peer"], fastest / r["engine_ms"], rel_tol=1e-9)
    assert "OpenVINO f32 ms" in text and "OpenVINO default err" in text and "vs f32 peer" in text
    md = (out / "bench.md").read_text()
    assert "## Beside the peers" in md and "clss vs faster f32 peer" in md


def test_layers_table_of_a_tiny_network(tmp_path, capsys):
    """--layers: a row per clss step with its time, bytes and conv variant, onnxruntime's time
    folded onto the steps, and its layout reorders on a row of their own."""
    from bench.cli import bench_main
    out = tmp_path / "l"
    assert bench_main(["--layers", "classifier", "--tiny", "--runs", "1", "--no-peak", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    doc = json.loads((out / "layers.json").read_text())
    (d,) = doc["networks"]
    steps = d["steps"]
    assert d["network"] == "classifier" and len(steps) > 5
    assert all(s["ms"] >= 0 and s["bytes"] > 0 for s in steps)
    convs = [s for s in steps if s["op"].startswith("Conv")]
    assert convs and all(s["flops"] > 0 for s in convs)
    assert all(s["variant"] != "-" for s in convs) and all(s["variant"] == "-" for s in steps if s not in convs)
    ort = d["peers"]["ort"]
    mapped = sum(v for v in ort["steps"].values())
    assert mapped > 0 and math.isclose(mapped + ort["folded"] + ort["unmapped"], ort["total"], rel_tol=1e-6)
    assert sum(1 for s in steps if s["peers"].get("ort")) >= len(convs) // 2
    assert "clss step" in text and "their own nodes (reorders)" in text
    assert "| clss step |" in (out / "layers.md").read_text()


def _conv_step():
    g = SimpleNamespace(shapes={"x": (1, 8, 16, 16), "w": (16, 8, 3, 3), "y": (1, 16, 16, 16)},
                        dtypes={}, blocked={})
    n = SimpleNamespace(op="clss.Conv", inputs=["x", "w", None, None], outputs=["y"],
                        attrs=dict(strides=(1, 1), pads=(1, 1, 1, 1), dilations=(1, 1), group=1))
    return g, n


def test_variant_column_without_describe_choice(dev, monkeypatch):
    import clss.ops.conv as conv
    g, n = _conv_step()
    assert layers.conv_flops(g, n) == 2.0 * 16 * 16 * 16 * 8 * 9
    assert layers.step_bytes(g, n, 4) == 4.0 * (8 * 256 + 16 * 8 * 9 + 16 * 256)
    if hasattr(conv, "describe_choice"):
        assert "(" in layers.variant(dev, "fp32", g, n)
        monkeypatch.delattr(conv, "describe_choice")
    assert layers.variant(dev, "fp32", g, n) == "-"


def test_peer_node_names_map_onto_clss_steps():
    """onnxruntime names a rewritten node after its output tensor ("u_nchwc"), OpenVINO lists
    the ONNX names it fused; both land on the clss step that runs those ONNX nodes."""
    from onnx import helper
    model = helper.make_model(helper.make_graph([
        helper.make_node("Conv", ["x", "w"], ["t"], name="c1"), helper.make_node("Relu", ["t"], ["u"], name="r1"),
        helper.make_node("Conv", ["u", "w2"], ["v"], name="c2"), helper.make_node("Shape", ["v"], ["s"], name="sh"),
    ], "g", [], []))
    nodes = [SimpleNamespace(sources=[("c1", "Conv"), ("r1", "Relu")]), SimpleNamespace(sources=[("c2", "Conv")])]
    step_of = layers.step_index(model, nodes)
    assert step_of["u"] == 0 and step_of["v"] == 1 and step_of["sh"] == "folded"

    class Fake:
        def __init__(self, times, fused=None):
            self.times, self.fused = times, fused

        def __call__(self, feeds):
            return []

        def node_times(self, runs):
            return self.times

        def fused_names(self):
            return self.fused or {}
    ort = SimpleNamespace(session=lambda m, profile=False: Fake(
        {"u_nchwc": 1.0, "v_nchwc": 2.0, "ReorderOutput_token_3": 0.5, "s": 0.25}))
    got = layers.peer_steps(ort, model, {}, 1, step_of)
    assert got["steps"] == {0: 1.0, 1: 2.0} and got["unmapped"] == 0.5 and got["folded"] == 0.25
    assert got["unmapped_names"] == ["ReorderOutput_token_3"] and got["total"] == 3.75
    ov = SimpleNamespace(session=lambda m, profile=False: Fake({"c1": 4.0}, {"c1": ["c1", "r1", "c2"]}))
    got = layers.peer_steps(ov, model, {}, 1, step_of)
    assert got["steps"] == {0: 4.0} and got["spans"] == {0: 2}
    broken = SimpleNamespace(session=lambda m, profile=False: (_ for _ in ()).throw(RuntimeError("no")))
    assert layers.peer_steps(broken, model, {}, 1, step_of)["status"].startswith("error: RuntimeError")
    assert np.isfinite(got["total"])
