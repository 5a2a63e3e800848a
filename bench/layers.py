"""`clss bench --layers NETWORK`: where one network's time goes, per step of clss.Model's
plan, beside each peer's time for the same ONNX nodes.

Per clss step (one kernel launch or a few: a node after the load-time fusions, named by the
ONNX nodes it stands for, `Node.sources`): the OpenCL event time of its launches (median over
the runs), GFLOP/s and the share of the device's FMA peak (bench/peak.py), the bytes it moves
(every input, weights included, and output once, at the storage type), and the conv variant
chosen (clss.ops.conv.describe_choice). The peers time the same graph with their profilers on
(onnxruntime's enable_profiling, OpenVINO's PERF_COUNT) and name their nodes after the ONNX
nodes or tensors they came from; each peer node's time goes to the clss step that holds the
first ONNX node it names. A peer node that names none (its own layout reorders) or only ONNX
nodes clss folded away at load is summed on a row of its own; a peer node that fused ONNX
nodes which clss runs as several steps is marked.
"""
from __future__ import annotations

import datetime
import math
import statistics
import sys
from pathlib import Path

import numpy as np
import onnx

from clss.cli.args import UsageError, check_output_file, prepare_output_dir
from clss.errors import cli_message

from .cases import fixed_inputs
from .netcases import seeded_feeds
from .peers import onnx_names

RUNS = 5


# --- which network -----------------------------------------------------------------------

def resolve(network: str, input_shapes, tier: str):
    """(name, ONNX model, input shapes or None for the file's own) of --layers NETWORK: an
    .onnx file, or one of the bench's network cases by its name without "network "."""
    if network.lower().endswith(".onnx") or Path(network).is_file():
        if not Path(network).is_file():
            raise UsageError(f"--layers {network}: no such file")
        from clss.cli.model import _shapes
        try:
            shapes = _shapes(input_shapes)
            model = onnx.load(network)
        except (ValueError, OSError) as e:
            raise UsageError(f"--layers {network}: {cli_message(e)}") from None
        except Exception as e:      # a protobuf decode error: not an ONNX file
            raise UsageError(f"--layers {network}: not an ONNX model ({type(e).__name__})") from None
        return Path(network).stem, model, shapes or None
    from .suite import all_cases
    cases, _ = all_cases("full", (tier,))
    nets = {c.name[len("network "):]: c for c in cases if c.kind == "network" and c.network}
    want = network.lower().removeprefix("network ").strip()
    hit = [k for k in nets if k == want] or [k for k in nets if want in k]
    if len(hit) != 1:
        why = "matches several" if hit else "matches none"
        raise UsageError(f"--layers {network!r} {why} of the bench's networks at {tier}: "
                         + ", ".join(hit or nets))
    c = nets[hit[0]]
    return hit[0], c.network[0], c.network[1]


def named(model: onnx.ModelProto) -> onnx.ModelProto:
    """A copy whose every node has a unique name (peers name their nodes after them)."""
    m = onnx.ModelProto()
    m.CopyFrom(model)
    seen = set()
    for i, n in enumerate(m.graph.node):
        if not n.name or n.name in seen:
            n.name = f"{n.op_type}_{i}"
        seen.add(n.name)
    return m


# --- clss's steps ---------------------------------------------------------------------------

class _NodeEvents(list):
    """The `events` list of a run that also notes which plan step enqueued each command."""

    def __init__(self, pdev):
        super().__init__()
        self.pdev, self.nodes = pdev, []

    def append(self, e):
        super().append(e)
        self.nodes.append(self.pdev.node)


def clss_steps(m, feeds: dict, runs: int) -> tuple[list[float], float]:
    """(median event ms per plan step, median wall ms of a run) over `runs` runs after one
    warm-up. The steps are told apart by the executor's current node (a clss.Model
    internal: the bench reads it, the runtime never times per node). The outputs are
    written into buffers allocated once, as a frame step's are: fresh ones per run made the
    steps that write the graph's outputs pay the pages' first touch (NSRR's features concat
    read 9.5 ms here against 5.2 in the network's own run). Each run records its launches
    again (no plan replay), so that every launch is still told by its node."""
    import time
    dev = m.device
    d_in = m.upload(feeds)
    pdev = m._exec.pdev
    outs = m.run_device(d_in)
    dev.queue.finish()
    per, walls = [[] for _ in m.graph.nodes], []
    for _ in range(runs):
        ev = _NodeEvents(pdev)
        m._current().launch_plans = []
        t0 = time.perf_counter()
        m.run_device(d_in, out=outs, events=ev)
        dev.queue.finish()
        walls.append((time.perf_counter() - t0) * 1e3)
        ms = [0.0] * len(per)
        for e, i in zip(ev, ev.nodes):
            if 0 <= i < len(ms):
                ms[i] += (e.profile.end - e.profile.start) * 1e-6
        for i, v in enumerate(ms):
            per[i].append(v)
    d_in.clear()
    return [statistics.median(v) for v in per], statistics.median(walls)


def step_bytes(g, n, itemsize: int) -> float:
    """The bytes a step reads and writes once: every input (weights too) and output."""
    total = 0.0
    for t in set(filter(None, list(n.inputs) + list(n.outputs))):
        shape = g.shapes.get(t)
        if shape is None:
            continue
        dt = np.dtype(g.dtypes.get(t, np.float32))
        total += float(np.prod(shape, dtype=np.float64)) * (itemsize if dt.kind == "f" else dt.itemsize)
    return total


def conv_flops(g, n) -> float | None:
    """2 x the multiply-adds of a conv step from its own shapes (a step may run a part of an
    ONNX Conv that clss split, e.g. one branch of a concat), None for another step."""
    if n.op != "clss.Conv":
        return None
    w = float(np.prod(g.shapes[n.inputs[1]], dtype=np.float64))
    at = g.shapes[n.inputs[0]] if n.attrs.get("transpose") else g.shapes[n.outputs[0]]
    return 2.0 * at[0] * float(np.prod(at[2:], dtype=np.float64)) * w


def variant(dev, prec: str, g, n) -> str:
    """The conv variant clss runs for a step (clss.ops.conv.describe_choice), "-" for others
    or where this checkout has no describe_choice."""
    import clss.ops.conv as conv
    describe = getattr(conv, "describe_choice", None)
    if describe is None or n.op != "clss.Conv" or n.attrs.get("transpose"):
        return "-"
    a = n.attrs
    x = n.inputs[0]
    args = (dev, prec, g.shapes[x], g.shapes[n.inputs[1]], a["strides"], a["pads"], a["dilations"], a["group"])
    blocked = g.blocked.get(x)
    try:
        return describe(*args, block_in=int(blocked[4]) if blocked is not None and len(blocked) == 5 else 0,
                        out_blocked=bool(a.get("blocked_out")))
    except TypeError:              # an older signature without the layout arguments
        return describe(*args)
    except Exception as e:         # a table cell, never a lost table
        return f"? ({type(e).__name__})"


# --- the peers ------------------------------------------------------------------------------

def peer_steps(col, model, feeds: dict, runs: int, step_of) -> dict:
    """A peer column's per-node times folded onto clss's steps: {"steps": {step: ms},
    "spans": {step: how many clss steps its nodes' ONNX nodes fall in, where > 1},
    "folded": ms on ONNX nodes clss has no step for, "unmapped": ms on nodes named after no
    ONNX node, "unmapped_names": a few of them, "total": ms}, or {"status": why}."""
    try:
        sess = col.session(model, profile=True)
        for _ in range(runs + 1):
            sess(feeds)
        times = sess.node_times(runs)
        fused = sess.fused_names() if hasattr(sess, "fused_names") else {}
    except Exception as e:
        return {"status": f"error: {type(e).__name__}: {str(e)[:200]}"}
    out = {"steps": {}, "spans": {}, "folded": 0.0, "unmapped": 0.0, "unmapped_names": [], "total": 0.0}
    for name, ms in times.items():
        out["total"] += ms
        hits = [step_of.get(c) for nm in onnx_names(name, fused) for c in onnx_names(nm)]
        known = [h for h in hits if h is not None and h != "folded"]
        if known:
            s = known[0]
            out["steps"][s] = out["steps"].get(s, 0.0) + ms
            if len(set(known)) > 1:
                out["spans"][s] = len(set(known))
        elif "folded" in hits:
            out["folded"] += ms
        else:
            out["unmapped"] += ms
            if len(out["unmapped_names"]) < 6:
                out["unmapped_names"].append(name)
    return out


def step_index(model: onnx.ModelProto, nodes) -> dict:
    """{ONNX node or output tensor name: the clss step that runs it, or "folded"}."""
    step_of = {}
    for i, n in enumerate(nodes):
        for name, _ in n.sources:
            step_of.setdefault(name, i)
    for n in model.graph.node:
        s = step_of.get(n.name, "folded")
        step_of.setdefault(n.name, s)
        for t in n.output:
            step_of.setdefault(t, s)
    return step_of


# --- the table -------------------------------------------------------------------------------

def profile(name: str, model, shapes, dev, prec: str, cols, runs: int, peak_gflops: float) -> dict:
    """The --layers document of one network at one precision."""
    from clss.device import storage_dtype
    from clss.model import Model, _label
    from clss.model.info import _shapes as onnx_shapes, node_flops
    model = named(model)
    m = Model(model, device=dev, precision=prec, input_shapes=shapes)
    shapes = {k: tuple(v) for k, v in m.input_shapes.items()}
    feeds = seeded_feeds(name, shapes, prec)
    clss_ms, wall = clss_steps(m, feeds, runs)
    g, nodes = m.graph, m.graph.nodes
    fixed = onnx.shape_inference.infer_shapes(fixed_inputs(model, shapes))
    known, by_name = onnx_shapes(fixed), {n.name: n for n in fixed.graph.node}
    itemsize = storage_dtype(prec).itemsize
    step_of = step_index(model, nodes)
    peers = {c.key: dict(label=c.label, **peer_steps(c, fixed_inputs(model, shapes), feeds, runs, step_of))
             for c in cols}
    split = {}          # ONNX node -> how many clss steps run a part of it
    for n in nodes:
        for s, _ in n.sources:
            split[s] = split.get(s, 0) + 1
    steps = []
    for i, n in enumerate(nodes):
        flops = conv_flops(g, n)
        if flops is None:    # a part of a node that clss split gets its share
            flops = float(sum(node_flops(by_name[s], known) / split[s] for s, _ in n.sources if s in by_name))
        ms = clss_ms[i]
        gflops = flops / (ms * 1e-3) * 1e-9 if ms > 0 and flops else float("nan")
        steps.append(dict(
            step=i, op=_label(n), onnx=[s for s, _ in n.sources], ms=ms, flops=flops, gflops=gflops,
            split=max(split[s] for s, _ in n.sources),
            peak_share=gflops / peak_gflops if peak_gflops and math.isfinite(gflops) else float("nan"),
            bytes=step_bytes(g, n, itemsize), variant=variant(dev, prec, g, n),
            peers={k: p["steps"].get(i) for k, p in peers.items() if "steps" in p},
            spans={k: p["spans"][i] for k, p in peers.items() if i in p.get("spans", {})}))
    return dict(network=name, precision=prec, input_shapes={k: list(v) for k, v in shapes.items()},
                runs=runs, clss_wall_ms=wall, clss_event_ms=sum(clss_ms), peak_gflops=peak_gflops,
                steps=steps, peers=peers)


def _f(v, fmt) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)


def table(doc: dict, markdown: bool = False) -> str:
    """The per-step table (terminal or markdown), then where the peers' other time went."""
    from .report import _grid
    peers = doc["peers"]
    head = ["#", "clss step", "ONNX nodes", "clss ms", "GFLOP/s", "of FMA peak", "MB moved", "variant",
            *(f"{p['label']} ms" for p in peers.values())]
    body = []
    for s in doc["steps"]:
        names = "+".join(s["onnx"])
        names = (names[:40] + "...") if len(names) > 43 else names
        if len(s["onnx"]) > 1:
            names += f" (fused {len(s['onnx'])})"
        if s.get("split", 1) > 1:
            names += f" (part, split in {s['split']})"
        cells = []
        for k, p in peers.items():
            if "status" in p:
                cells.append("-")
                continue
            v = s["peers"].get(k)
            cells.append(_f(v, ".3f") + (f" (spans {s['spans'][k]})" if k in s["spans"] else ""))
        body.append([str(s["step"]), s["op"], names, _f(s["ms"], ".3f"),
                     _f(s["gflops"], ".1f"), _f(s["peak_share"], ".0%"), _f(s["bytes"] / 1e6, ".1f"),
                     s["variant"], *cells])
    extra = []
    for label, key in (("ONNX nodes clss folds at load", "folded"),
                       ("their own nodes (reorders)", "unmapped")):
        cells = [_f(p.get(key), ".3f") if "status" not in p else "-" for p in peers.values()]
        extra.append(["", "peers only", label, "", "", "", "", "", *cells])
    extra.append(["", "total", "clss: event ms (wall ms)",
                  f"{doc['clss_event_ms']:.2f} ({doc['clss_wall_ms']:.2f})", "", "", "", "",
                  *(_f(p.get("total"), ".2f") if "status" not in p else p["status"][:40] for p in peers.values())])
    rows = body + extra
    if markdown:
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * 3 + "---:|" * 4 + "---|" + "---:|" * len(peers)]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
    else:
        lines = _grid(tuple(head), [tuple(r) for r in rows], left=(1, 2, 7))
    notes = [f"{p['label']}: unmapped nodes include {', '.join(p['unmapped_names'])}"
             for p in peers.values() if p.get("unmapped_names")]
    return "\n".join(lines + [""] + notes if notes else lines)


def markdown(docs: list, head: dict) -> str:
    out = [f"# clss bench --layers {docs[0]['network']}", ""]
    out += [f"- {k}: {v}" for k, v in head.items()]
    out += ["", "Per step of clss.Model's plan: OpenCL event ms (median of the runs), GFLOP/s and share of "
            "the measured FMA peak (a conv's FLOPs are a direct conv's: Winograd does fewer, so its share "
            "can pass 100 %), bytes read and written once, the conv variant clss chose; each peer's "
            "ms for the same ONNX nodes (its profiler; a peer node that fused ONNX nodes clss runs as "
            "several steps: spans N). \"fused N\": the clss step runs N ONNX nodes in one."]
    for d in docs:
        out += ["", f"## {d['precision']}, inputs {d['input_shapes']}", "", table(d, markdown=True)]
    return "\n".join(out) + "\n"


# --- the command ----------------------------------------------------------------------------

def main(a, dev, precs, tier: str) -> int:
    """clss bench --layers NETWORK at a shape tier (bench/cli.py parsed and checked the
    flags, chose the device and the precisions)."""
    from . import report
    from .peak import measure
    from .peers import columns
    from .runner import Settings
    name, model, shapes = resolve(a.layers, a.input_shape, tier)
    if a.json is not None:
        check_output_file(a.json, "--json")
    if a.out:
        prepare_output_dir(a.out, "--out", overwrite=True)    # layers.json / layers.md are replaced
    settings = Settings()
    threads = a.ort_threads or settings.ort_threads
    cols = columns(a.peer_names, threads, a.ort_spinning)
    runs = a.runs or (2 if a.tiny else RUNS)
    # the FMA peak alone, at the full level's probe lengths (a short probe on a loaded
    # machine reads low, and every share with it)
    peak = None if a.no_peak else measure(dev, log=lambda msg: print(msg, file=sys.stderr), stream=False,
                                           **(dict(target_s=0.02) if a.tiny else {}))
    docs = []
    for prec in precs:
        print(f"clss bench --layers {name} [{prec}]: {runs} runs each of clss and "
              f"{', '.join(c.label for c in cols)}", file=sys.stderr)
        try:
            d = profile(name, model, shapes, dev, prec, cols, runs, peak.gflops if peak else float("nan"))
        except Exception as e:    # a model clss cannot load or run: the loader's one line
            print(f"clss bench: --layers {a.layers}: {cli_message(e)}", file=sys.stderr)
            return 2
        docs.append(d)
        print(f"\n{name} [{prec}]\n" + table(d))
    head = {"device": f"{dev.info.platform} / {dev.info.name} (driver {dev.info.driver})",
            "machine": f"{report._cpu_model()}, {report._simd()}, clss vector width {report._vector_width(dev)}",
            "created": datetime.datetime.now().isoformat(timespec="seconds"),
            "commit": report._git("rev-parse", "HEAD")[:12] + (" (dirty)" if report.git_state()["dirty"] else ""),
            "FMA peak": f"{peak.gflops:.1f} GFLOP/s" if peak else "not measured (--no-peak)",
            "peers": ", ".join(c.label for c in cols)}
    doc = {"schema": "clss-bench-layers/1", "head": head, "networks": report._clean(docs)}
    written = report.write_outputs(doc, markdown(docs, head), a.out, a.json, "layers")
    if written:
        print("wrote " + ", ".join(str(w) for w in written))
    return 0

