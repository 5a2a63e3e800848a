"""Timing: the engine and onnxruntime on the same case, in one process, alternating.

Per case: build (upload seeded inputs, build the twin's session), warm up both
(PoCL compiles and specialises kernels on their first launches; onnxruntime
plans its arena), check the engine's output against onnxruntime's once, then
alternate engine and onnxruntime runs so that drifting machine load hits both
alike. Engine wall time covers enqueue to queue.finish(); engine event time is
the sum of its kernels' profiled durations. Reported: median and minimum.
"""
from __future__ import annotations

import gc
import os
import statistics
import time
import traceback
from dataclasses import asdict, dataclass, field

import numpy as np

from clss.device import Device, DeviceError
from clss.tolerance import compare

from .capture import Capture
from .cases import BenchCase, Setup
from .peak import Peak


@dataclass
class Settings:
    runs: int | None = None          # fixed number of timed runs; None: by time budget
    min_runs: int = 3
    max_runs: int = 15
    budget_s: float = 4.0            # timed-loop budget per case (both sides together)
    warmup: int = 2
    ort_threads: int = field(default_factory=lambda: os.cpu_count() or 1)
    # onnxruntime's workers spin after each run by default; alternating with the
    # engine in one process, that spinning would eat the cores the engine runs on next.
    ort_spinning: bool = False
    check: bool = True


@dataclass
class Row:
    name: str
    tier: str
    family: str
    kind: str
    precision: str
    shape: str = ""
    status: str = "ok"               # ok | error: ... | mismatch: ...
    engine_ms: float = float("nan")          # median wall
    engine_min_ms: float = float("nan")
    engine_event_ms: float = float("nan")    # median of summed kernel event times
    engine_event_min_ms: float = float("nan")
    ort_ms: float = float("nan")
    ort_min_ms: float = float("nan")
    speedup_vs_ort: float = float("nan")     # ort_ms / engine_ms (> 1: the engine is faster)
    flops: float = 0.0
    bytes: float = 0.0
    ort_bytes: float = 0.0
    intensity: float = 0.0                   # FLOP / byte (engine bytes)
    gflops: float = float("nan")             # engine, from median wall
    gbs: float = float("nan")
    ort_gflops: float = float("nan")
    ort_gbs: float = float("nan")
    bound: str = ""                          # compute | memory (by the measured ridge point)
    peak_share: float = float("nan")         # of the bound's peak
    launches: int = 0
    runs: int = 0
    check: str = ""                          # pass | FAIL ... | skipped
    max_err: float = float("nan")
    note: str = ""
    # {kernel: event ms} of the last timed run (a frame step that times its stages: {stage: ms})
    kernels: dict = field(default_factory=dict)
    # peer columns other than onnxruntime's (bench/peers.py): {key: {label, fp32, status, ms,
    # min_ms, max_err}}; vs_peer: the faster f32 peer's time / engine time (which: vs_peer_name)
    peers: dict = field(default_factory=dict)
    vs_peer: float = float("nan")
    vs_peer_name: str = ""

    def as_dict(self) -> dict:
        return asdict(self)


class OrtRunner:
    """One onnxruntime session per twin: CPU execution provider, intra-op threads
    = cores (settings), all graph optimisations, as a user would run it (but for
    the spinning of idle workers, off unless asked for: see Settings)."""

    def __init__(self, threads: int, spinning: bool = False):
        self.threads = threads
        self.spinning = spinning

    def session(self, model, profile_prefix: str | None = None):
        """profile_prefix: with onnxruntime's per-node profiler on, its file named so."""
        import onnxruntime as ort
        so = ort.SessionOptions()
        if profile_prefix:
            so.enable_profiling = True
            so.profile_file_prefix = profile_prefix
        so.intra_op_num_threads = self.threads
        so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        so.log_severity_level = 3
        so.add_session_config_entry("session.intra_op.allow_spinning", "1" if self.spinning else "0")
        return ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])


def _classify(row: Row, peak: Peak | None, kind: str) -> None:
    if not np.isfinite(row.engine_ms) or row.engine_ms <= 0:
        return
    s = row.engine_ms * 1e-3
    row.intensity = row.flops / row.bytes if row.bytes else 0.0
    row.gflops = row.flops / s * 1e-9
    row.gbs = row.bytes / s * 1e-9
    if np.isfinite(row.ort_ms) and row.ort_ms > 0:
        row.ort_gflops = row.flops / (row.ort_ms * 1e-3) * 1e-9
        row.ort_gbs = row.ort_bytes / (row.ort_ms * 1e-3) * 1e-9
    if peak is None:
        return
    # Memory-bound families are judged by bandwidth whatever their nominal FLOPs.
    compute = kind in ("conv", "compute", "network", "frame") and row.intensity >= peak.ridge
    row.bound = "compute" if compute else "memory"
    row.peak_share = row.gflops / peak.gflops if compute else row.gbs / peak.gbs


def check_outputs(outs, refs, tol, refs_round) -> tuple[str, float]:
    if len(outs) != len(refs):
        return f"FAIL: {len(outs)} outputs, reference has {len(refs)}", float("inf")
    worst, detail = 0.0, ""
    for i, (o, r) in enumerate(zip(outs, refs)):
        if refs_round and r.dtype.kind == "f":
            r = r.astype(np.float16).astype(np.float32)
        c = compare(o.reshape(r.shape) if o.size == r.size else o, r, tol)
        worst = max(worst, c.max_rel)
        if not c.passed:
            detail = f"FAIL: output {i}: {c.detail or 'out of tolerance'} (err/tol {c.ratio:.3g})"
    return (detail or "pass"), worst


def check_setup(setup: Setup, host: list, refs: list) -> tuple[str, float]:
    """The engine's host outputs against onnxruntime's, in the twin's layout."""
    if setup.post:
        host = setup.post(host)
    if setup.out_index is not None:
        refs = [refs[setup.out_index]]
    return check_outputs(host, refs, setup.tol, setup.refs_round)


def run_case(case: BenchCase, dev: Device, prec: str, settings: Settings, peak: Peak | None,
             ort: OrtRunner, params: dict | None = None, columns=None) -> Row:
    """One case, alternating the engine with each peer column (bench/peers.py; default:
    onnxruntime alone). onnxruntime is the oracle whether or not it is timed."""
    row = Row(case.name, case.tier, case.family, case.kind, prec, case.shape, flops=case.flops)
    cap = Capture(dev)
    setup: Setup | None = None
    try:
        setup = case.build(dev, prec, dict(params or {}))
        row.bytes, row.ort_bytes = setup.bytes, setup.ort_bytes
        oracle = ort.session(setup.twin)
        out_names = [o.name for o in oracle.get_outputs()]
        # (key, column or None for onnxruntime, run(feeds) -> outputs)
        peers = [("ort", None, lambda f: oracle.run(out_names, f))]
        if columns is not None:
            peers = [p for p in peers if any(c.key == "ort" for c in columns)]
            for c in columns:
                if c.key != "ort":
                    try:
                        peers.append((c.key, c, c.session(setup.twin)))
                    except Exception as e:      # a peer that cannot run the twin: a status, not a lost row
                        row.peers[c.key] = {"label": c.label, "fp32": c.fp32, "status": _status(e)}
        stages = {}

        def engine_once():
            cap.start_run()
            t0 = time.perf_counter()
            outs = setup.run()
            dev.queue.finish()
            wall = (time.perf_counter() - t0) * 1e3
            if setup.stages is None:
                return wall, cap.event_ms(), outs
            stages.clear()
            stages.update(setup.stages())
            return wall, sum(stages.values()), outs

        def peer_once(run):
            t0 = time.perf_counter()
            res = run(setup.feeds)
            return (time.perf_counter() - t0) * 1e3, res

        def peers_once():
            return {k: peer_once(run)[0] for k, _, run in peers}

        row.note = setup.note
        with cap.active():
            # Run 1 compiles (PoCL builds and specialises kernels on their first launches)
            # and is the one checked: stateful cases (the frame step) start from a reset there.
            # Further warm-up runs only while they are cheap next to the time budget.
            _, _, outs = engine_once()
            host = [dev.to_host(o) for o in outs] if settings.check else None
            del outs
            p_ms, got = {}, {}
            for k, _, run in peers:
                p_ms[k], got[k] = peer_once(run)
            refs = got.pop("ort", None) or oracle.run(out_names, setup.feeds)
            for k, c, _ in peers:
                if c is not None:
                    row.peers[k] = {"label": c.label, "fp32": c.fp32, "status": "ok",
                                    "max_err": _peer_error(setup, got.pop(k), refs)}
            if settings.check:
                row.check, row.max_err = check_setup(setup, host, refs)
            else:
                row.check = "skipped"
            del host, refs
            first_ms = engine_once()[0]
            row.launches = len(cap.events)
            for _ in range(settings.warmup - 1):
                if first_ms + sum(p_ms.values()) > settings.budget_s * 1e3 / 4:
                    break
                first_ms = engine_once()[0]
                p_ms = peers_once()
            n = settings.runs or int(np.clip(settings.budget_s * 1e3 / max(first_ms + sum(p_ms.values()), 1e-3),
                                             settings.min_runs, settings.max_runs))
            e_wall, e_ev, p_wall = [], [], {k: [] for k, _, _ in peers}
            for _ in range(n):
                w, ev, outs = engine_once()
                del outs
                e_wall.append(w)
                e_ev.append(ev)
                for k, t in peers_once().items():
                    p_wall[k].append(t)
            by_time = sorted(stages.items(), key=lambda kv: -kv[1]) if stages else cap.per_kernel_ms().items()
            row.kernels = {k: round(v, 4) for k, v in by_time}
        row.runs = n
        row.engine_ms, row.engine_min_ms = statistics.median(e_wall), min(e_wall)
        row.engine_event_ms, row.engine_event_min_ms = statistics.median(e_ev), min(e_ev)
        for k, ts in p_wall.items():
            if k == "ort":
                row.ort_ms, row.ort_min_ms = statistics.median(ts), min(ts)
            else:
                row.peers[k].update(ms=statistics.median(ts), min_ms=min(ts))
        row.speedup_vs_ort = row.ort_ms / row.engine_ms
        _versus_peers(row)
        if row.check.startswith("FAIL"):
            row.status = "mismatch"
        _classify(row, peak, case.kind)
    except Exception as e:
        row.status = _status(e)
    finally:
        cap.release()
        if setup is not None and setup.release:
            setup.release()
        del setup
        gc.collect()
    return row


def _status(e: Exception) -> str:
    last = traceback.format_exception_only(type(e), e)[-1].strip()
    # A tensor past the device's max allocation is a limit of the device, not a bug.
    limit = isinstance(e, DeviceError) or any(t in str(e) for t in (
        "max allocation", "max_alloc", "INVALID_BUFFER_SIZE", "MEM_OBJECT_ALLOCATION_FAILURE"))
    return f"{'skipped' if limit else 'error'}: {last[:500]}"


def _peer_error(setup: Setup, outs: list, refs: list) -> float:
    """A peer's largest error against the oracle (relative to the reference's largest
    magnitude, as the engine's max_err), on the outputs the engine's check reads."""
    if setup.out_index is not None:
        outs, refs = [outs[setup.out_index]], [refs[setup.out_index]]
    return check_outputs([np.asarray(o) for o in outs], refs, setup.tol, False)[1]


def _versus_peers(row: Row) -> None:
    """vs_peer: the faster f32 peer's time / the engine's (onnxruntime or OpenVINO f32)."""
    f32 = {"ort": row.ort_ms} if np.isfinite(row.ort_ms) else {}
    f32.update({k: p["ms"] for k, p in row.peers.items() if p.get("fp32") and np.isfinite(p.get("ms", np.nan))})
    if f32 and np.isfinite(row.engine_ms):
        row.vs_peer_name = min(f32, key=f32.get)
        row.vs_peer = f32[row.vs_peer_name] / row.engine_ms


def time_engine(setup: Setup, dev: Device, runs: int, local_size=None) -> tuple[float, float, list]:
    """(median wall ms, median event ms, first run's outputs as host arrays, launches)
    of the engine alone; `local_size` is forced on every launch it divides."""
    cap = Capture(dev)
    cap.local_size = local_size
    walls, evs, first = [], [], None
    try:
        with cap.active():
            for i in range(runs + 1):
                cap.start_run()
                t0 = time.perf_counter()
                outs = setup.run()
                dev.queue.finish()
                w = (time.perf_counter() - t0) * 1e3
                ev = cap.event_ms()
                if i == 0:
                    first = [dev.to_host(o) for o in outs]
                else:
                    walls.append(w)
                    evs.append(ev)
                del outs
        return statistics.median(walls), statistics.median(evs), first, list(cap.launches)
    finally:
        cap.release()
