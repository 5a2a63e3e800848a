"""The exported conv SR models (tests/fixtures/exported, issue 49) at 540x960 input through
clss.Model against onnxruntime: `python -m bench.exported [--precision fp32,fp16]
[--only espcn,rcan] [--size 540x960] [--runs 5]`.

The fixtures tagged "conv-sr" in the manifest are exported with dynamic height and width,
so the same files the tests run at 23x37 are sized here by ``input_shapes=``. Each model is
timed after a warm-up run: clss on the device (inputs uploaded once, run_device, then the
queue finished), onnxruntime (CPU execution provider, intra-op threads = the CPUs) host to
host; the median of --runs each. The outputs are compared (the largest error as a fraction
of the house's whole-network tolerance, tests/test_exported_models.py). Writes nothing."""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import numpy as np

FIXTURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                        "tests", "fixtures", "exported")


def _size(s):
    h, w = (int(v) for v in s.lower().split("x"))
    return h, w


def _median_time(fn, runs):
    fn()                                     # warm-up
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_entry(entry, prec, size, runs, device=None):
    """(clss seconds, ort seconds, err/tol, note) of one fixture at size (H, W)."""
    import onnxruntime as ort

    import clss
    from clss.model import ModelError
    from clss.tolerance import Tolerance, compare
    h, w = size
    shapes = {i["name"]: tuple(i["shape"][:2]) + (h, w) for i in entry["inputs"]}
    rng = np.random.default_rng(entry["seed"])
    host = {k: rng.uniform(0.0, 1.0, s).astype(np.float32) for k, s in shapes.items()}
    path = os.path.join(FIXTURES, entry["file"])
    so = ort.SessionOptions()
    so.intra_op_num_threads = os.cpu_count() or 1
    so.log_severity_level = 3
    sess = ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])
    t_ort = _median_time(lambda: sess.run(None, host), runs)
    try:
        m = clss.Model(path, device, precision=prec, input_shapes=shapes)
    except ModelError as e:
        return None, t_ort, None, str(e).splitlines()[0] + " " + " ".join(
            f"{op}" for _, op, _, _ in getattr(e, "nodes", []))
    d_in = m.upload(host)

    def run():
        m.run_device(d_in)
        m.device.queue.finish()
    t_clss = _median_time(run, runs)
    outs = m.run(host)
    refs = sess.run(None, host if prec == "fp32" else
                    {k: v.astype(np.float16).astype(np.float32) for k, v in host.items()})
    tol = Tolerance(2e-5, 2e-4) if prec == "fp32" else Tolerance(5e-3, 5e-3)
    ratio = max(compare(outs[n], r, tol).ratio for n, r in zip(m.output_names, refs))
    return t_clss, t_ort, ratio, f"{len(m.graph.nodes)} steps"


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m bench.exported", description=__doc__.split("\n\n")[0])
    p.add_argument("--precision", default="fp32", help="comma-separated: fp32,fp16")
    p.add_argument("--only", help="comma-separated architectures (default: every conv-sr fixture)")
    p.add_argument("--exporters", default="torchscript,dynamo")
    p.add_argument("--size", type=_size, default=(540, 960), help="input HxW (default 540x960)")
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--device", help="OpenCL device (as clss --device; default: clss's default)")
    a = p.parse_args(argv)
    with open(os.path.join(FIXTURES, "manifest.json")) as fh:
        manifest = json.load(fh)
    only = set(a.only.split(",")) if a.only else None
    exporters = a.exporters.split(",")
    entries = [e for e in manifest["models"] if "conv-sr" in e["tags"] and e["exporter"] in exporters
               and (only is None or e["arch"] in only)]
    if not entries:
        print("no fixture matches", file=sys.stderr)
        return 2
    print(f"{'model':24s} {'prec':5s} {'input':>9s} {'clss ms':>9s} {'ort ms':>9s} {'ort/clss':>8s} "
          f"{'err/tol':>8s}  note")
    for e in entries:
        for prec in a.precision.split(","):
            m = e["hw_multiple"]
            size = (a.size[0] // m * m, a.size[1] // m * m)
            t_c, t_o, ratio, note = bench_entry(e, prec, size, a.runs, a.device)
            speed = f"{t_o / t_c:7.2f}x" if t_c else "       -"
            print(f"{e['name']:24s} {prec:5s} {size[0]:>4d}x{size[1]:<4d} "
                  f"{t_c * 1e3 if t_c else float('nan'):9.1f} {t_o * 1e3:9.1f} {speed:>8s} "
                  f"{ratio if ratio is not None else float('nan'):8.3f}  {note}", flush=True)
    print("ort/clss: onnxruntime's time over clss's (> 1: clss is faster); err/tol <= 1 passes")
    return 0


if __name__ == "__main__":
    from clss.exiting import leave   # past pip's PoCL 3.0 teardown abort
    leave(main())
