"""The bench suite itself (bench/, kernels/peak.cl, clss/tuning.py), on tiny shapes:
the numbers are meaningless here, the plumbing is what is tested."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bench import report
from bench.capture import Capture, fit_local
from bench.cases import BenchCase, make_setup
from bench.suite import all_cases
from bench.cli import bench_main
from bench.peak import fma_gflops, stream_gbs
from bench.tune import tune_case
from clss import tuning
from clss.ops.space_to_depth import space_to_depth
from clss.verify.twin import node_model


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    rc = bench_main(["--quick", "--tiny", "--runs", "2", "-p", "fp32", "--out", str(out),
                     "--json", str(out / "copy.json")])
    return rc, out


def test_quick_tiny_run_writes_every_output(quick_run):
    rc, out = quick_run
    for f in ("bench.json", "bench.md", "roofline.png", "copy.json"):
        assert (out / f).stat().st_size > 0, f
    doc = json.loads((out / "bench.json").read_text())
    rows = doc["rows"]
    assert rows, "the quick set is empty"
    bad = [(r["name"], r["status"], r["check"]) for r in rows
           if r["status"] != "ok" and not r["status"].startswith("skipped")]
    assert rc == (1 if bad else 0)
    assert len(bad) < len(rows), bad
    # A case that cannot even be built (an API it uses moved) is the bench's own bug.
    assert not [r for r in rows if r["status"].startswith("error")], bad
    assert (out / "roofline.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "# clss bench" in (out / "bench.md").read_text()


def test_json_schema(quick_run):
    _, out = quick_run
    doc = report.load_json(out / "bench.json")
    for key in ("schema", "created", "level", "machine", "device", "driver", "packages", "git", "settings",
                "peak", "targets", "rows", "unavailable"):
        assert key in doc, key
    assert doc["machine"]["cores"] >= 1
    assert doc["device"]["name"] and doc["driver"]
    assert {"numpy", "pyopencl", "onnxruntime", "onnx"} <= set(doc["packages"])
    assert doc["peak"]["gflops"] > 0 and doc["peak"]["gbs"] > 0
    assert set(doc["targets"]) == {"conv_vs_ort", "memory_bandwidth_share", "frame_net_vs_ort"}
    for r in doc["rows"]:
        assert set(report.ROW_KEYS) <= set(r), set(report.ROW_KEYS) - set(r)
        if r["status"] == "ok":
            assert r["engine_ms"] > 0 and r["ort_ms"] > 0 and r["runs"] == 2
            assert r["engine_min_ms"] <= r["engine_ms"]
            assert math.isclose(r["speedup_vs_ort"], r["ort_ms"] / r["engine_ms"], rel_tol=1e-9)
            assert r["bytes"] > 0 and r["bound"] in ("compute", "memory") and r["peak_share"] > 0
            assert r["check"] == "pass", (r["name"], r["check"])
    json.dumps(doc, allow_nan=False)   # strict JSON: no NaN


def test_compare(quick_run, tmp_path, capsys):
    _, out = quick_run
    a = report.load_json(out / "bench.json")
    b = json.loads(json.dumps(a))
    first = next(r for r in b["rows"] if r["status"] == "ok")
    first["engine_ms"] *= 2
    b["rows"].append(dict(first, name="only in B"))
    (tmp_path / "b.json").write_text(json.dumps(b))
    text = report.compare_docs(a, b)
    assert "+100.0%" in text and "only B" in text
    assert bench_main(["--compare", str(out / "bench.json"), str(tmp_path / "b.json")]) == 0
    assert first["name"] in capsys.readouterr().out
    (tmp_path / "bad.json").write_text("{}")
    assert bench_main(["--compare", str(out / "bench.json"), str(tmp_path / "bad.json")]) == 2


def test_compare_pairs_files_of_the_old_tier_naming(quick_run, tmp_path):
    """A file written when CLSS's tiers were named by the render size (no "tier_naming")
    is read with the output-named tiers: CLSS's 540p is 1080p, its 1080p 2160p; the rooms'
    1080p stays, and a workload the old naming listed twice is kept once."""
    _, out = quick_run
    new = report.load_json(out / "bench.json")
    assert new["tier_naming"] == report.TIER_NAMING
    old = json.loads(json.dumps(new))
    del old["tier_naming"]
    row = dict(old["rows"][0], tier="540p")
    old["rows"] = [row, dict(row, name="frame step net", tier="1080p"),
                   dict(row, name="frame step bicubic x2", tier="540p"),
                   dict(row, name="frame step bicubic x2", tier="1080p", engine_ms=-1.0),
                   dict(row, name="network classifier", tier="1080p"),
                   dict(row, name="network nsrr features x2", tier="1080p"),
                   dict(row, name="layer nsrd net.dn 3x3/s2 16->32 leaky_relu", tier="1080p")]
    (tmp_path / "old.json").write_text(json.dumps(old))
    got = report.load_json(tmp_path / "old.json")
    assert [(r["name"], r["tier"]) for r in got["rows"]] == [
        (row["name"], "1080p"), ("frame step net", "2160p"), ("frame step bicubic x2", "1080p"),
        ("network classifier", "2160p"), ("network nsrr features x2", "1080p"),
        ("layer nsrd net.dn 3x3/s2 16->32 leaky_relu", "1080p")]
    assert got["rows"][2]["engine_ms"] != -1.0
    # the old 540p row pairs with the new file's 1080p row of the same case
    new["rows"] = [dict(row, tier="1080p", engine_ms=row["engine_ms"] * 2)]
    line = next(ln for ln in report.compare_docs(got, new).splitlines() if ln.startswith(row["name"] + " "))
    assert "1080p" in line and "+100.0%" in line


def test_tiers_are_named_by_the_output():
    """One tier, one output size: every frame step's shape ends at its tier's resolution,
    and no (case, shape) is in two tiers; the default level leaves the rooms whose cases
    cost minutes (FULL_ONLY) to --full and says why."""
    full, _ = all_cases("full")
    frames = [c for c in full if c.kind == "frame"]
    assert {c.tier for c in full} == {"1080p", "2160p"}
    for c in frames:
        assert c.shape.split("->")[1].split("x")[0] == c.tier[:-1], c.label
    assert len({(c.name, c.shape) for c in full}) == len(full)
    default, skipped = all_cases("default")
    names = {c.name for c in default}
    assert {"frame step net", "frame step mlp x2", "frame step bicubic x2"} <= names
    assert not [n for n in names if n.startswith(("frame step ns", "network ns", "layer "))]
    assert {w.split()[0] for w, why in skipped if "only with --full" in why} == {"nsrr", "nsrd", "nss"}


def test_methods_table(tmp_path, capsys):
    """clss bench --methods: a row per frame step, clss and onnxruntime time and where clss's
    frame time goes (the room's stages where it times them, else the kernels). Three rooms
    (stages from CLSS and NSRR, kernels from the MLP): every room's frame step costs CI about
    2.5 minutes of kernel builds under load; --list checks that each room has its row."""
    out = tmp_path / "m"
    assert bench_main(["--methods", "--tiny", "--runs", "1", "-p", "fp32", "--no-check", "--out", str(out),
                       "--filter", "frame step net,frame step mlp x2,frame step nsrr x2"]) == 0
    text = capsys.readouterr().out
    rows = json.loads((out / "bench.json").read_text())["rows"]
    assert [r["name"] for r in rows] == ["frame step net", "frame step mlp x2", "frame step nsrr x2"]
    for r in rows:
        assert r["status"] == "ok" and r["engine_ms"] > 0 and r["ort_ms"] > 0, r["name"]
        assert r["kernels"] and math.isclose(sum(r["kernels"].values()), r["engine_event_ms"], rel_tol=1e-2,
                                             abs_tol=1e-3), r["name"]
        line = next(ln for ln in text.splitlines() if ln.startswith(r["name"] + " "))
        assert f"{r['speedup_vs_ort']:.2f}" in line and next(iter(r["kernels"])) in line
    assert "classifier" in rows[0]["kernels"] and "reconstruct" in rows[2]["kernels"]
    assert "where clss's time goes" in text


def test_targets_summary():
    rows = [dict(name="conv a", tier="1080p", precision="fp32", status="ok", kind="conv", family="conv",
                 speedup_vs_ort=0.4, peak_share=0.1),
            dict(name="conv b", tier="1080p", precision="fp32", status="ok", kind="conv", family="conv",
                 speedup_vs_ort=0.9, peak_share=0.2),
            dict(name="warp", tier="1080p", precision="fp32", status="ok", kind="memory", family="warp",
                 speedup_vs_ort=3.0, peak_share=0.7),
            dict(name="conv c", tier="2160p", precision="fp32", status="ok", kind="conv", family="conv",
                 speedup_vs_ort=0.1, peak_share=0.1)]
    t = report.targets(rows)
    assert t["conv_vs_ort"]["status"] == "1/2 met" and t["conv_vs_ort"]["worst"]["name"] == "conv a"
    assert t["memory_bandwidth_share"]["status"] == "met"
    assert t["frame_net_vs_ort"]["status"] == "not measured"
    assert "1/2 met" in report.format_targets(t)


def test_peak_probes_positive(dev):
    assert fma_gflops(dev, 4, target_s=0.01, repeats=1, chains=4) > 0
    assert fma_gflops(dev, 1, target_s=0.01, repeats=1, chains=8) > 0
    assert stream_gbs(dev, "copy", mib=4, target_s=0.01, repeats=1) > 0
    assert stream_gbs(dev, "triad", mib=4, target_s=0.01, repeats=1) > 0
    with pytest.raises(ValueError):
        stream_gbs(dev, "scale", mib=1)


def test_cases_tiny_suite_is_well_formed():
    cases, unavailable = all_cases("default", ("tiny",))
    assert cases
    labels = [c.label for c in cases]
    assert len(labels) == len(set(labels))
    assert all(c.tier == "tiny" and c.kind in ("conv", "memory", "compute", "network", "frame") for c in cases)
    quick, _ = all_cases("quick", ("tiny",))
    assert quick and set(c.label for c in quick) <= set(labels) and len(quick) < len(cases)
    # every room's frame step has its --methods row
    assert [c.name for c in cases if c.kind == "frame"] == [
        "frame step bicubic x2", "frame step net", "frame step rule", "frame step mlp x2",
        "frame step mlp x3", "frame step nsrr x2", "frame step nsrr x4", "frame step nsrd x2",
        "frame step nsrd x4", "frame step nss x2"]
    for what, why in unavailable:
        assert what and why


def test_capture_pools_allocations_and_records_events(dev):
    x = dev.to_device(np.arange(2 * 4 * 4, dtype=np.float32).reshape(1, 2, 4, 4))
    cap = Capture(dev)
    outs = []
    with cap.active():
        for _ in range(2):
            cap.start_run()
            outs.append(space_to_depth(dev, "fp32", x, 2))
            assert len(cap.events) == 1 and cap.event_ms() >= 0
    assert "launch" not in dev.__dict__ and "empty" not in dev.__dict__
    assert outs[0].data.int_ptr == outs[1].data.int_ptr      # run 2 reused run 1's buffer
    assert cap.launches == [("space_to_depth", (1, 2, 4))]   # (ceil(W/8), H, N*C*B)
    assert fit_local((4,), (8, 2, 1)) == (4, 1, 1) and fit_local((3,), (8, 2)) is None


def _s2d_case(calls):
    """Candidate MODE=1 is fast (no kernel at all) and wrong: the tuner must reject it."""
    def build(dev, prec, params):
        x = np.random.default_rng(0).standard_normal((1, 3, 8, 8)).astype(np.float32)
        wrong = dev.to_device(np.zeros((1, 12, 4, 4), np.float32), prec)

        def engine(d):
            calls.append(params.get("MODE"))
            return wrong if params.get("MODE") == 1 else space_to_depth(dev, prec, d["x"], 2)
        return make_setup(dev, prec, {"x": x}, lambda h: node_model("SpaceToDepth", {"x": h["x"]}, blocksize=2),
                          engine, [(1, 12, 4, 4)], exact=True)
    return BenchCase("s2d tune test", "space_to_depth", "memory", "tiny", 0.0, build,
                     tunables={"MODE": (1, 0)}, defaults={"MODE": 0}, tune_op="s2d_test", tune_key="1x3x8x8")


def test_tuner_rejects_wrong_candidate(dev, tmp_path):
    calls = []
    db = tmp_path / "tuning.json"
    res = tune_case(_s2d_case(calls), dev, "fp32", runs=2, search_local=True, db=db, log=lambda m: None)
    assert 1 in calls and 0 in calls
    wrong = [t for t in res.trials if t.params == {"MODE": 1}]
    assert wrong and all(t.check.startswith("FAIL") for t in wrong)
    assert res.best is not None and res.best.params == {"MODE": 0} and res.best.ok
    # the default won, so no parameter entry; work-group entries only where one beat the driver
    assert all(op.startswith("local_size:") for op, _ in res.stored)


def test_tuning_database(dev, tmp_path, monkeypatch):
    db = tmp_path / "t.json"
    monkeypatch.setenv("CLSS_TUNING_DB", str(db))
    defaults = {"XV": 2, "CB": 4}
    assert tuning.lookup(dev, "conv2d", "k", defaults) == defaults          # no file
    tuning.store(dev, "conv2d", "k", {"XV": 4, "STALE": 1}, ms=1.0)
    assert tuning.lookup(dev, "conv2d", "k", defaults) == {"XV": 4, "CB": 4}
    assert tuning.lookup(dev, "conv2d", "other", defaults) == defaults
    assert tuning.lookup("another device | 1.0", "conv2d", "k", defaults) == defaults
    stored = json.loads(db.read_text())
    assert stored["devices"][tuning.device_key(dev)]["conv2d"]["k"]["params"]["XV"] == 4
    with tuning.override("conv2d", {"CB": 8}):
        assert tuning.lookup(dev, "conv2d", "k", defaults) == {"XV": 2, "CB": 8}
    with tuning.recording() as seen:
        tuning.lookup(dev, "conv2d", "k", defaults)
    assert seen == [("conv2d", "k", defaults)]
    tuning.store(dev, "local_size:conv2d", tuning.shape_key((64, 8, 2)), {"local": [16, 1, 1]})
    assert tuning.local_size(dev, "conv2d", (64, 8, 2)) == (16, 1, 1)
    # no entry: the CPU default (balanced groups), the driver's choice elsewhere
    assert tuning.local_size(dev, "conv2d", (60, 8, 2)) == \
        (tuning.balanced_local_size((60, 8, 2), dev.info.compute_units) if dev.is_cpu else None)
    db.write_text("not json")
    with pytest.warns(UserWarning, match="unreadable"):
        assert tuning.lookup(dev, "conv2d", "k", defaults) == defaults


def test_host_waits_table(tmp_path):
    """clss bench --host-waits: a wall / event / enqueue row per method, in bench.json."""
    out = tmp_path / "hw"
    # one timed frame: the assertions are about the table's plumbing, not the figures
    assert bench_main(["--host-waits", "--tiny", "--runs", "1", "-p", "fp32", "--out", str(out)]) == 0
    doc = json.loads((out / "bench.json").read_text())
    rows = doc["host_waits"]
    assert [r["method"] for r in rows] == ["clss", "clss-rules", "jbicubic", "mlp", "nsrr",
                                                 "nsrd", "nss"]
    for r in rows:
        assert r["wall_ms"] > 0 and r["event_ms"] > 0
        assert (r["enqueue_ms"] > 0) if r["method"] not in ("mlp", "nsrr", "nsrd", "nss") \
            else r["enqueue_ms"] is None
        assert r["ratio"] == pytest.approx(r["wall_ms"] / r["event_ms"], rel=1e-2)
    assert "Host waits" in (out / "bench.md").read_text()


def test_tiny_suite_benches_nsrr_and_nsrd_networks_and_layers(dev):
    """NSRR's and NSRD's networks are "network" cases and every conv layer in them a
    "layer" case (one per distinct workload) at the tiny tier; a layer of each builds and
    matches onnxruntime on the same node."""
    from bench.cases import layer_key, network_layers
    from bench.methods import nsrd, nsrr
    from bench.runner import OrtRunner, check_setup
    cases, _ = all_cases("default", ("tiny",))
    by_name = {c.name: c for c in cases}
    for room in (nsrr, nsrd):
        m = room.__name__.rsplit(".", 1)[1]
        nets = [c for c in cases if c.name.startswith(f"network {m} ")]
        layers = [c for c in cases if c.name.startswith(f"layer {m} ")]
        assert nets and all(c.kind == "network" for c in nets), m
        assert layers and all(c.kind == "conv" and c.family == "conv" for c in layers), m
        keys = {layer_key(L) for _, _, model in room.networks("tiny") for L in network_layers(model)}
        assert len(layers) == len(keys), m
    # NSRR's last layer carries the residual Add, NSRD's down layer is a stride-2 LeakyReLU
    for name in ("layer nsrr reconstruct.un.9 3x3 16->3 add x2",
                 "layer nsrd net.dn 3x3/s2 16->32 leaky_relu"):
        st = by_name[name].build(dev, "fp32", {})
        host = [dev.to_host(o) for o in st.run()]
        refs = OrtRunner(1).session(st.twin).run(None, st.feeds)
        assert check_setup(st, host, refs)[0] == "pass", name
        st.release()
