"""What a bench run leaves behind: the terminal table, the JSON document, the
markdown summary, the roofline PNG, the targets, and the comparison of two runs."""
from __future__ import annotations

import datetime
import json
import math
import os
import platform
import re
import subprocess
import sys
from pathlib import Path

from .peak import Peak

SCHEMA = "clss-bench/1"
# How the rows' tiers are named: by the frame's output resolution (bench/cases.py TIERS).
# Files without the field named CLSS's tiers by the render size; load_json renames theirs.
TIER_NAMING = "output"
ROW_KEYS = ("name", "tier", "family", "kind", "precision", "shape", "status", "engine_ms", "engine_min_ms",
            "engine_event_ms", "engine_event_min_ms", "ort_ms", "ort_min_ms", "speedup_vs_ort", "flops",
            "bytes", "ort_bytes", "intensity", "gflops", "gbs", "ort_gflops", "ort_gbs", "bound",
            "peak_share", "launches", "runs", "check", "max_err")

# The issue's targets (benchmark figures, not test assertions), PoCL CPU, 1080p output.
CONV_TARGET = 0.5          # every CLSS conv layer at >= 0.5x onnxruntime's speed
MEMORY_TARGET = 0.60       # memory-bound kernels at >= 60% of the stream bandwidth
FRAME_TARGET = 1.0         # the net-mode frame step at >= 1.0x onnxruntime
MEMORY_FAMILIES = ("warp", "resize", "space_to_depth", "elementwise")


# --- the document -------------------------------------------------------------------

def _git(*args) -> str:
    try:
        root = Path(__file__).resolve().parent.parent
        return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True,
                              timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def git_state() -> dict:
    """The checkout's commit and whether tracked files differ from it (a run records it at
    its start too, as "git_start": the tree may move under a long run)."""
    return {"commit": _git("rev-parse", "HEAD"), "dirty": bool(_git("status", "--porcelain", "--untracked-files=no"))}


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _versions() -> dict:
    out = {"python": platform.python_version()}
    from importlib import metadata
    for pkg in ("clss", "numpy", "pyopencl", "pocl-binary-distribution", "onnx", "onnxruntime", "openvino",
                "matplotlib"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = None
    if out.get("openvino") is None:
        out.pop("openvino")
    if out.get("clss") is None:
        import clss
        out["clss"] = clss.__version__
    return out


def document(rows, dev, peak: Peak | None, settings, level: str, unavailable=(), extra=None) -> dict:
    return {
        "schema": SCHEMA,
        "tier_naming": TIER_NAMING,
        "created": datetime.datetime.now().isoformat(timespec="seconds"),
        "level": level,
        "machine": {"hostname": platform.node(), "cpu": _cpu_model(), "cores": os.cpu_count(),
                    "os": platform.platform(), "load_avg": _loadavg(), "simd": _simd(),
                    "vector_width": _vector_width(dev)},
        "device": dev.info.__dict__ if dev is not None else None,
        "driver": dev.info.driver if dev is not None else None,
        "packages": _versions(),
        "git": git_state(),
        "settings": {k: v for k, v in vars(settings).items()} if settings is not None else {},
        "command": " ".join(sys.argv),
        "peak": peak.as_dict() if peak else None,
        "unavailable": [{"what": w, "why": y} for w, y in unavailable],
        "targets": targets(rows),
        "rows": [_clean(r.as_dict() if hasattr(r, "as_dict") else dict(r)) for r in rows],
        **(extra or {}),
    }


def _simd() -> str:
    """The CPU's widest x86 vector extension (the figures depend on it), or ""."""
    try:
        flags = next((line.split(":", 1)[1].split() for line in Path("/proc/cpuinfo").read_text().splitlines()
                      if line.startswith("flags")), [])
    except OSError:
        return ""
    for f, name in (("amx_tile", "AVX-512 + AMX"), ("avx512f", "AVX-512"), ("avx2", "AVX2"), ("sse4_2", "SSE4.2")):
        if f in flags:
            return name
    return ""


def _vector_width(dev):
    """The float lanes clss's conv tiles are sized to on dev (clss.ops.conv.vector_width)."""
    if dev is None:
        return None
    try:
        from clss.ops.conv import vector_width
        return int(vector_width(dev))
    except Exception:
        return None


def _loadavg():
    try:
        return list(os.getloadavg())
    except OSError:
        return None


def _clean(v):
    """JSON has no NaN: missing numbers become null, at any depth."""
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    return None if isinstance(v, float) and not math.isfinite(v) else v


def write_json(doc: dict, path) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1, default=str))


def write_outputs(doc: dict, md: str, out, json_path, stem: str = "bench") -> list[Path]:
    """<out>/<stem>.json and <stem>.md (out: a directory, or empty for none) and --json's
    file; the paths written."""
    written = []
    if out:
        out = Path(out)
        write_json(doc, out / f"{stem}.json")
        (out / f"{stem}.md").write_text(md)
        written += [out / f"{stem}.json", out / f"{stem}.md"]
    if json_path:
        write_json(doc, json_path)
        written.append(Path(json_path))
    return written


def load_json(path) -> dict:
    try:
        doc = json.loads(Path(path).read_text())
    except ValueError as e:
        raise ValueError(f"{path}: not a clss bench result (not JSON: {e})") from None
    schema = doc.get("schema") if isinstance(doc, dict) else None
    if schema != SCHEMA:
        raise ValueError(f"{path}: not a clss bench result (schema {schema!r}, expected {SCHEMA!r})")
    if "tier_naming" not in doc:
        doc["rows"] = output_named(doc["rows"])
        doc["tier_naming"] = TIER_NAMING
    return doc


# The method rooms' cases other than CLSS's (frame steps "frame step <method> x<scale>",
# "network <method> <net>", "layer ..."): their tiers were named by the output already.
_ROOM_CASE = re.compile(r"frame step \S+ x\d|network (?!classifier$|composition$)|layer ")


def output_named(rows) -> list:
    """Rows of a file written before tiers were named by the output: CLSS's "540p" (render
    540x960, output 1080x1920) becomes "1080p" and its "1080p" "2160p"; the rooms' "1080p"
    stays. A workload that the old naming listed in both tiers (bicubic x2, mlp x2 at
    540x960) is kept once, as its first row."""
    out, seen = [], set()
    for r in rows:
        old = r["tier"]
        tier = {"540p": "1080p", "1080p": "1080p" if _ROOM_CASE.match(r["name"]) else "2160p"}.get(old, old)
        key = (r["name"], tier, r["precision"])
        if key not in seen:
            seen.add(key)
            out.append(dict(r, tier=tier))
    return out


def _get(r, k):
    v = r.get(k) if isinstance(r, dict) else getattr(r, k)
    return float("nan") if v is None else v


# --- targets ---------------------------------------------------------------------------

def targets(rows) -> dict:
    """Where each of the issue's three targets stands, from the 1080p-output rows in fp32."""
    rs = [r if isinstance(r, dict) else r.as_dict() for r in rows]
    ok = [r for r in rs
          if r.get("status") == "ok" and r.get("tier") == "1080p" and r.get("precision") == "fp32"]

    def summary(sel, key, goal, lower_is_worse=True):
        vals = [(r["name"], _get(r, key)) for r in sel if math.isfinite(_get(r, key))]
        if not vals:
            return {"goal": goal, "status": "not measured", "cases": 0}
        worst = min(vals, key=lambda t: t[1])
        met = [n for n, v in vals if v >= goal]
        return {"goal": goal, "cases": len(vals), "met": len(met), "worst": {"name": worst[0], "value": worst[1]},
                "status": "met" if len(met) == len(vals) else f"{len(met)}/{len(vals)} met",
                "missed": sorted(((n, v) for n, v in vals if v < goal), key=lambda t: t[1])}
    return {
        "conv_vs_ort": summary([r for r in ok if r["kind"] == "conv"], "speedup_vs_ort", CONV_TARGET),
        "memory_bandwidth_share": summary([r for r in ok if r["family"] in MEMORY_FAMILIES],
                                          "peak_share", MEMORY_TARGET),
        "frame_net_vs_ort": summary([r for r in ok if r["kind"] == "frame" and "net" in r["name"]],
                                    "speedup_vs_ort", FRAME_TARGET),
    }


def format_targets(t: dict) -> str:
    names = {"conv_vs_ort": f"1. every CLSS conv layer >= {CONV_TARGET}x onnxruntime",
             "memory_bandwidth_share": f"2. memory-bound kernels >= {MEMORY_TARGET:.0%} of stream bandwidth",
             "frame_net_vs_ort": f"3. net-mode frame step >= {FRAME_TARGET}x onnxruntime"}
    lines = []
    for k, label in names.items():
        s = t.get(k, {})
        if s.get("status") == "not measured" or not s:
            lines.append(f"{label}: not measured")
            continue
        w = s["worst"]
        fmt = (lambda v: f"{v:.0%}") if k == "memory_bandwidth_share" else (lambda v: f"{v:.2f}x")
        lines.append(f"{label}: {s['status']} ({s['cases']} cases; worst {w['name']} at {fmt(w['value'])})")
    return "\n".join(lines)


# --- the terminal table --------------------------------------------------------------------

def _f(v, fmt):
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)


def format_table(rows) -> str:
    keys = peer_keys(rows)
    if keys:
        return "\n".join(_case_grid(rows, ("case", "tier", "prec", "clss ms", "ort ms", *peer_heads(keys),
                                            "vs f32 peer", "check"),
                                     lambda r: (_f(r["engine_ms"], ".2f"), _f(r["ort_ms"], ".2f"),
                                                *peer_cells(r, keys), vs_peer_cell(r), _check(r)),
                                     left=(0, 1, 2)))
    head = ("case", "tier", "prec", "engine ms", "min", "event ms", "ort ms", "vs ort", "GFLOP/s", "GB/s",
            "bound", "of peak", "check")
    lines = _case_grid(rows, head, lambda r: (
        _f(r["engine_ms"], ".2f"), _f(r["engine_min_ms"], ".2f"), _f(r["engine_event_ms"], ".2f"),
        _f(r["ort_ms"], ".2f"), _f(r["speedup_vs_ort"], ".2f"), _f(r["gflops"], ".1f") if r["flops"] else "-",
        _f(r["gbs"], ".1f"), r["bound"] or "-", _f(r["peak_share"], ".0%"), _check(r)), left=(0, 1, 2, 10, 12))
    for r in rows:
        r = r if isinstance(r, dict) else r.as_dict()
        if r["check"].startswith("FAIL"):
            lines.append(f"{r['name']} [{r['precision']}]: {r['check']}")
    return "\n".join(lines)


def _check(r) -> str:
    return r["check"] if r["check"] in ("pass", "skipped") else "FAIL"


# --- peer columns (bench/peers.py) ------------------------------------------------------------

def _row(r) -> dict:
    return r if isinstance(r, dict) else r.as_dict()


def peer_keys(rows) -> list[tuple]:
    """(key, label, fp32) of the peer columns other than onnxruntime's that any row has, in
    first-seen order."""
    keys = {}
    for r in rows:
        for k, p in (_row(r).get("peers") or {}).items():
            keys.setdefault(k, (k, p["label"], bool(p.get("fp32"))))
    return list(keys.values())


def peer_heads(keys) -> list[str]:
    """A heading per column: "<label> ms", and "<label> err" after a column not held to f32."""
    out = []
    for _, label, fp32 in keys:
        out.append(f"{label} ms")
        if not fp32:
            out.append(f"{label.split(' (')[0]} err")
    return out


def peer_cells(r, keys) -> list[str]:
    """A row's cells under peer_heads: ms (or the peer's status where it did not run), err."""
    out = []
    for k, _, fp32 in keys:
        p = (r.get("peers") or {}).get(k) or {}
        ok = p.get("status") == "ok"
        out.append(_f(p.get("ms"), ".2f") if ok else p.get("status", "-").split(":")[0])
        if not fp32:
            out.append(_f(p.get("max_err"), ".1e") if ok else "-")
    return out


def vs_peer_cell(r) -> str:
    """clss against the faster f32 peer: "1.25x ort"."""
    v = r.get("vs_peer")
    return "-" if v is None or not math.isfinite(v) else f"{v:.2f}x {r.get('vs_peer_name', '').replace('_', ' ')}".strip()


def _grid(head, body, left) -> list[str]:
    """Header, rule and body lines of a table whose columns fit their widest cell; the
    columns in `left` align left, the rest (numbers) right."""
    widths = [max(len(str(x[i])) for x in [head] + body) for i in range(len(head))]
    fmt = "  ".join(f"{{:{'<' if i in left else '>'}{w}}}" for i, w in enumerate(widths))
    return [fmt.format(*head), fmt.format(*("-" * w for w in widths))] + [fmt.format(*b) for b in body]


def _case_grid(rows, head, cells, left) -> list[str]:
    """_grid of a line per row: its name, tier and precision, then cells(row); a row that did
    not run has "-" there and its status last."""
    body = []
    for r in rows:
        r = r if isinstance(r, dict) else r.as_dict()
        if r["status"].startswith(("error", "skipped")):
            body.append((r["name"], r["tier"], r["precision"], *("-",) * (len(head) - 4), r["status"][:60]))
        else:
            body.append((r["name"], r["tier"], r["precision"], *cells(r)))
    return _grid(head, body, left)


def format_methods(rows, top: int = 4) -> str:
    """clss bench --methods: a line per frame step and precision, clss's time against
    onnxruntime's, and where clss's time goes: the event ms of the `top` kernels (or the
    room's stages) of one timed frame step (the row's `kernels`), largest first, with the
    rest summed."""
    head = ("frame step", "tier", "prec", "clss ms", "ort ms", "ort/clss",
            "where clss's time goes: event ms per kernel or stage, one frame (share)")

    def cells(r):
        ks = list((r.get("kernels") or {}).items())
        total = sum(v for _, v in ks) or float("nan")
        where = [f"{k} {v:.2f} ({v / total:.0%})" for k, v in ks[:top]]
        if ks[top:]:
            rest = sum(v for _, v in ks[top:])
            where.append(f"{len(ks) - top} more {rest:.2f} ({rest / total:.0%})")
        return (_f(r["engine_ms"], ".2f"), _f(r["ort_ms"], ".2f"), _f(r["speedup_vs_ort"], ".2f"),
                ", ".join(where) or "-")
    return "\n".join(_case_grid(rows, head, cells, left=(0, 1, 2, 6)))


def format_peak(peak: Peak) -> str:
    fma = ", ".join(f"{k} {v:.1f}" for k, v in peak.fma_gflops.items())
    bw = ", ".join(f"{k} {v:.1f}" for k, v in peak.stream_gbs.items())
    return (f"measured peak: FMA {peak.gflops:.1f} GFLOP/s ({fma}); stream {peak.gbs:.1f} GB/s ({bw}); "
            f"ridge {peak.ridge:.2f} FLOP/byte")


# --- markdown ------------------------------------------------------------------------------

def markdown(doc: dict) -> str:
    d, m, p = doc.get("device") or {}, doc["machine"], doc.get("peak")
    out = [f"# clss bench ({doc['level']})", "",
           f"- created {doc['created']}, commit `{doc['git']['commit'][:12]}`{' (dirty)' if doc['git']['dirty'] else ''}"
           + (f", at the start `{doc['git_start']['commit'][:12]}`{' (dirty)' if doc['git_start']['dirty'] else ''}"
              if doc.get("git_start") and doc["git_start"] != doc["git"] else ""),
           f"- machine: {m['cpu']}, {m['cores']} cores"
           + (f", {m['simd']}" if m.get("simd") else "")
           + (f", clss vector width {m['vector_width']}" if m.get("vector_width") else "")
           + f", load average at the end {m.get('load_avg')}",
           f"- device: {d.get('platform')} / {d.get('name')}, driver {d.get('driver')}",
           "- packages: " + ", ".join(f"{k} {v}" for k, v in doc["packages"].items() if v),
           f"- onnxruntime: CPU execution provider, {doc['settings'].get('ort_threads')} intra-op threads"]
    if p:
        out.append(f"- {format_peak(Peak.from_dict(p))}")
    if doc.get("peers"):
        out.append(f"- peers: {', '.join(doc['peers'])}" + (
            f"; OpenVINO {doc['packages'].get('openvino')} CPU plugin, default precision "
            f"{doc.get('openvino_default_precision')}" if "openvino" in doc["peers"] else ""))
    out += peers_markdown(doc["rows"])
    out += ["", "## Targets", ""] + [f"- {line}" for line in format_targets(doc["targets"]).splitlines()]
    out += ["", "## Results", "",
            "engine and onnxruntime times are medians of wall time over the runs (min in brackets); "
            "event = summed OpenCL kernel time; vs ort = onnxruntime time / engine time (> 1: engine faster); "
            "of peak = share of the measured FMA peak (compute-bound) or stream bandwidth (memory-bound).", "",
            "| case | tier | prec | engine ms | event ms | ort ms | vs ort | GFLOP/s | GB/s | bound | of peak | check |",
            "|---|---|---|---:|---:|---:|---:|---:|---:|---|---:|---|"]
    for r in doc["rows"]:
        if r["status"].startswith(("error", "skipped")):
            out.append(f"| {r['name']} | {r['tier']} | {r['precision']} | | | | | | | | | {r['status'][:80]} |")
            continue
        out.append(f"| {r['name']} | {r['tier']} | {r['precision']} | {_f(r['engine_ms'], '.2f')} "
                   f"({_f(r['engine_min_ms'], '.2f')}) | {_f(r['engine_event_ms'], '.2f')} | "
                   f"{_f(r['ort_ms'], '.2f')} ({_f(r['ort_min_ms'], '.2f')}) | {_f(r['speedup_vs_ort'], '.2f')} | "
                   f"{_f(r['gflops'], '.1f') if r['flops'] else '-'} | {_f(r['gbs'], '.1f')} | {r['bound'] or '-'} | "
                   f"{_f(r['peak_share'], '.0%')} | {r['check']} |")
    multi = [r for r in doc["rows"] if r["status"] == "ok" and len(r.get("kernels") or {}) > 1]
    if multi:
        out += ["", "## Where the time goes (kernel event ms of one run)", ""]
        for r in multi:
            ks = ", ".join(f"{k} {v:.2f}" for k, v in list(r["kernels"].items())[:8])
            out.append(f"- {r['name']} [{r['tier']} {r['precision']}]: {ks}"
                       + (f" ({r['note']})" if r.get("note") else ""))
    slow = slowest(doc["rows"], 3)
    if slow:
        out += ["", "## Slowest relative to onnxruntime", ""]
        out += [f"- {r['name']} [{r['tier']} {r['precision']}]: {r['speedup_vs_ort']:.2f}x "
                f"({r['engine_ms']:.2f} ms vs {r['ort_ms']:.2f} ms; {r['bound']}-bound, "
                f"{_f(r['peak_share'], '.0%')} of peak)" for r in slow]
    if doc.get("host_waits"):
        from .hostwait import TARGET, markdown as host_waits_md
        out += ["", "## Host waits: wall time per frame step against its summed event time", "",
                f"Warm frames, medians; enqueue = host milliseconds to enqueue one frame. Target: "
                f"wall <= {TARGET}x event at 540p -> 1080p.", "", host_waits_md(doc["host_waits"])]
    if doc.get("unavailable"):
        out += ["", "## Not benchmarked", ""] + [f"- {u['what']}: {u['why']}" for u in doc["unavailable"]]
    return "\n".join(out) + "\n"


def peers_markdown(rows) -> list[str]:
    """The peers table (bench/peers.py): clss beside each peer column, the error of the
    columns not held to f32 against the oracle, clss against the faster f32 peer and against
    each column not held to f32 (peer ms / clss ms: > 1, clss is faster)."""
    keys = peer_keys(rows)
    if not keys:
        return []
    loose = [k for k in keys if not k[2]]
    head = ["case", "tier", "prec", "clss ms", "onnxruntime ms", *peer_heads(keys), "clss vs faster f32 peer",
            *(f"clss vs {label}" for _, label, _ in loose)]
    out = ["", "## Beside the peers", "",
           "Medians of wall time, each peer alternating with clss on the same ONNX twin and feeds in one "
           "process; err: the largest difference from onnxruntime's output (the oracle) over the "
           "reference's largest magnitude; vs: the peer's time / clss's (> 1: clss is faster).", "",
           "| " + " | ".join(head) + " |", "|" + "---|" * 3 + "---:|" * (len(head) - 3)]
    for r in rows:
        r = _row(r)
        if r["status"] not in ("ok", "mismatch"):
            out.append(f"| {r['name']} | {r['tier']} | {r['precision']} |" + " |" * (len(head) - 4)
                       + f" {r['status'][:80]} |")
            continue
        vs_loose = []
        for k, _, _ in loose:
            p = (r.get("peers") or {}).get(k) or {}
            vs_loose.append(_f(p.get("ms", float("nan")) / r["engine_ms"], ".2f") + "x"
                            if p.get("status") == "ok" and r.get("engine_ms") else "-")
        cells = [r["name"], r["tier"], r["precision"], _f(r["engine_ms"], ".1f"), _f(r["ort_ms"], ".1f"),
                 *peer_cells(r, keys), vs_peer_cell(r), *vs_loose]
        out.append("| " + " | ".join(cells) + " |")
    return out


def slowest(rows, n=3):
    ok = [r for r in rows if r.get("status") == "ok" and r.get("speedup_vs_ort") is not None
          and math.isfinite(r["speedup_vs_ort"])]
    return sorted(ok, key=lambda r: r["speedup_vs_ort"])[:n]


# --- roofline ---------------------------------------------------------------------------------

def roofline(doc: dict, path) -> None:
    """Left: the roofline (log-log GFLOP/s against FLOP/byte) with every kernel that
    does arithmetic, engine filled and onnxruntime hollow. Right: achieved bandwidth
    of every row against the stream peak (data movement has no FLOPs to place)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    p = doc.get("peak")
    rows = [r for r in doc["rows"] if r["status"] == "ok" and r.get("engine_ms")]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(15, 7), gridspec_kw={"width_ratios": [3, 2]})
    flops_rows = [r for r in rows if r["flops"] and r["intensity"]]
    if p:
        peak = Peak.from_dict(p)
        ai = np.logspace(-2, 3, 200)
        ax.loglog(ai, np.minimum(peak.gflops, ai * peak.gbs), "k-", lw=2, label="measured roof")
        for name, v in peak.fma_gflops.items():
            ax.axhline(v, color="0.75", lw=0.8, ls=":")
            ax.text(1.1e-2, v * 1.04, f"FMA {name}", fontsize=7, color="0.4")
        ax.axvline(peak.ridge, color="0.8", lw=0.8)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    fam_color = {}
    for r in flops_rows:
        c = fam_color.setdefault(r["family"], colors[len(fam_color) % len(colors)])
        mk = "o" if r["precision"] == "fp32" else "s"
        ax.loglog(r["intensity"], r["gflops"], mk, color=c, ms=6)
        if r.get("ort_gflops") and r.get("ort_bytes"):
            ax.loglog(r["flops"] / r["ort_bytes"], r["ort_gflops"], mk, mfc="none", color=c, ms=6)
        ax.annotate(r["name"].split(" ", 1)[-1][:28], (r["intensity"], r["gflops"]), fontsize=6,
                    xytext=(3, 2), textcoords="offset points")
    for fam, c in fam_color.items():
        ax.plot([], [], "o", color=c, label=fam)
    ax.plot([], [], "o", color="0.3", mfc="none", label="onnxruntime (hollow)")
    ax.plot([], [], "s", color="0.3", label="fp16 storage (square)")
    ax.set_xlabel("arithmetic intensity (FLOP / compulsory byte)")
    ax.set_ylabel("GFLOP/s")
    ax.set_title(f"roofline: {doc['device']['name'] if doc.get('device') else ''}", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    ax.grid(True, which="both", alpha=0.2)

    labels = [f"{r['name'][:40]} [{r['precision']}]" for r in rows]
    y = np.arange(len(rows))
    bx.barh(y, [r["gbs"] or 0 for r in rows], color=["C0" if r["precision"] == "fp32" else "C1" for r in rows],
            label="engine")
    bx.scatter([r.get("ort_gbs") or 0 for r in rows], y, marker="|", color="k", s=60, label="onnxruntime")
    if p:
        gbs = Peak.from_dict(p).gbs
        bx.axvline(gbs, color="k", lw=1.5, label=f"stream {gbs:.1f} GB/s")
        bx.axvline(0.6 * gbs, color="k", lw=0.8, ls="--", label="60% target")
    bx.set_yticks(y, labels, fontsize=6)
    bx.invert_yaxis()
    bx.set_xlabel("GB/s (compulsory bytes / median wall time)")
    bx.legend(fontsize=7)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --- comparison ------------------------------------------------------------------------------

def compare_docs(a: dict, b: dict) -> str:
    """Rows matched by (name, tier, precision): engine time before and after, the change,
    and each run's ratio to onnxruntime (which also tells how noisy the machine was)."""
    key = lambda r: (r["name"], r["tier"], r["precision"])
    ra, rb = {key(r): r for r in a["rows"]}, {key(r): r for r in b["rows"]}
    head = ("case", "tier", "prec", "A ms", "B ms", "change", "A vs ort", "B vs ort", "ort A/B")
    body = []
    for k in list(ra) + [k for k in rb if k not in ra]:
        x, y = ra.get(k), rb.get(k)
        if x is None or y is None:
            body.append((*k, _f(_get(x or {}, "engine_ms"), ".2f") if x else "-",
                         _f(_get(y or {}, "engine_ms"), ".2f") if y else "-", "only A" if y is None else "only B",
                         "-", "-", "-"))
            continue
        ea, eb = _get(x, "engine_ms"), _get(y, "engine_ms")
        ch = (eb / ea - 1) if math.isfinite(ea) and math.isfinite(eb) and ea > 0 else float("nan")
        oa, ob = _get(x, "ort_ms"), _get(y, "ort_ms")
        body.append((*k, _f(ea, ".2f"), _f(eb, ".2f"), "-" if not math.isfinite(ch) else f"{ch:+.1%}",
                     _f(_get(x, "speedup_vs_ort"), ".2f"), _f(_get(y, "speedup_vs_ort"), ".2f"),
                     _f(oa / ob if ob else float("nan"), ".2f")))
    lines = [f"A: {a['created']} {a['git']['commit'][:10]} {a['device']['name'] if a.get('device') else ''}",
             f"B: {b['created']} {b['git']['commit'][:10]} {b['device']['name'] if b.get('device') else ''}",
             "change = B engine time / A engine time - 1 (negative: B faster); "
             "ort A/B far from 1 means the machine's load differed", ""]
    return "\n".join(lines + _grid(head, body, left=(0, 1, 2)))
