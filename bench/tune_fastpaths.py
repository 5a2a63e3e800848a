"""`clss tune --level`'s fast-path step: whether each fast path that is a speed choice
(clss.selfcheck.FastPath.measured: a method's stages fused into one pass, pixels as vectors)
is used on this device, by timing the frame steps that use it with and without it.

Until a device (or its class's shipped table) has been measured, such a path applies where it
was measured first, the CPUs; a GPU runs the reference variants, one launch per stage. On a
GPU the fused passes may win by launching less, or lose to its wider, narrower work-items:
only a measurement says which.

1. Each frame case selected runs once inside selfcheck.asking(): the measured fast paths its
   frame step asks about.
2. A path whose self-check fails on the device is stored as not used.
3. Otherwise every case that asks for it is built and timed twice (median wall of `runs` after
   a warm-up, clss bench's timing): with the path forced off, then on. The fused output must
   match the reference output within the case's tolerance. The path is used when the sum of
   its cases' times is at least conv_probe.MARGIN lower with it.
4. The verdict is stored in the tuning database (op "fast_path", key the path's name), where
   FastPath.applies_on reads it; `make gpu-report` copies it into the shipped-table candidate.

When both fp32 and fp16 are tuned, each method's frame step is then timed in both at the
tier's size (`tune_precisions`, step_device on frames already on the device) and op "fp16"
stores whether fp16 was at least MARGIN faster: precision="auto" (clss/pipeline/precision.py)
picks fp16 on a GPU only where it verifies and was not measured slower.
"""
from __future__ import annotations

import statistics
import time
from dataclasses import dataclass, field

import numpy as np

from clss import selfcheck, tuning
from clss.ops.conv_probe import MARGIN

from .runner import check_outputs, time_engine


@dataclass
class PathResult:
    name: str
    cases: list = field(default_factory=list)     # (label, prec, off ms, on ms, off event ms, on event ms)
    use: bool | None = None                        # None: not measured (budget, or no case ran)
    note: str = ""

    def total(self, i: int) -> float:
        return sum(c[i] for c in self.cases)


def measured_paths(cases, dev, precs, log=print) -> dict:
    """{fast path name: [(case, prec), ...]}: the measured fast paths each frame case asks for."""
    uses: dict = {}
    for case in cases:
        for prec in precs:
            if prec not in case.precisions:
                continue
            try:
                with selfcheck.asking() as asked:
                    setup = case.build(dev, prec, dict(case.defaults))
                    setup.run()
                    dev.queue.finish()
                if setup.release:
                    setup.release()
            except Exception as e:      # a case that cannot build here: report, measure the rest
                log(f"  {case.label} [{prec}]: not run ({type(e).__name__}: {str(e).splitlines()[0][:160]})")
                continue
            for name in sorted(asked):
                fp = selfcheck.REGISTRY.get(name)
                if fp is not None and fp.measured:
                    uses.setdefault(name, []).append((case, prec))
    return uses


def _timed(case, dev, prec, name: str, on: bool, runs: int):
    """(wall ms, event ms, host outputs, tolerance) of the case with path `name` forced."""
    with selfcheck.forcing(name, on):
        setup = case.build(dev, prec, dict(case.defaults))
        try:
            setup.run()                 # a warm-up beyond time_engine's own: the builds
            dev.queue.finish()
            wall, event, first, _ = time_engine(setup, dev, runs)
            return wall, event, first, setup
        finally:
            if setup.release:
                setup.release()


def tune_path(dev, name: str, uses, *, runs=5, store=True, db=None, deadline=None, log=print) -> PathResult:
    res = PathResult(name)
    bad = [prec for prec in dict.fromkeys(p for _, p in uses)
           if not (v := selfcheck.verdict(dev, prec, name)) or not v.ok]
    if bad:
        res.use, res.note = False, f"self-check fails or not checked in {', '.join(bad)}"
    else:
        for case, prec in uses:
            if deadline and time.monotonic() > deadline:
                res.note = "budget ran out"
                break
            try:
                off = _timed(case, dev, prec, name, False, runs)
                on = _timed(case, dev, prec, name, True, runs)
            except Exception as e:      # the fused variant fails on this case: it is not used
                res.use, res.note = False, f"{case.label} [{prec}]: {type(e).__name__}: {str(e).splitlines()[0][:160]}"
                break
            status, _ = check_outputs(on[2], off[2], off[3].tol, off[3].refs_round)
            if status != "pass":
                res.use, res.note = False, f"{case.label} [{prec}]: the fast output differs from the reference's ({status})"
                break
            res.cases.append((case.label, prec, off[0], on[0], off[1], on[1]))
            log(f"  {name}: {case.label} [{prec}] reference {off[0]:.3f} ms, fast {on[0]:.3f} ms")
        else:
            res.use = res.total(3) <= res.total(2) * (1 - MARGIN)
    if store and res.use is not None:
        tuning.store(dev, tuning.FAST_PATH_OP, name, {"use": res.use}, path=db,
                     ms=round(res.total(3), 4) if res.cases else None,
                     default_ms=round(res.total(2), 4) if res.cases else None,
                     cases=[list(c[:2]) for c in res.cases], note=res.note)
    return res


def tune_paths(cases, dev, precs, *, runs=5, store=True, db=None, deadline=None, log=print) -> list[PathResult]:
    uses = measured_paths([c for c in cases if c.kind == "frame"], dev, precs, log=log)
    return [tune_path(dev, name, u, runs=runs, store=store, db=db, deadline=deadline, log=log)
            for name, u in uses.items()]


def format_paths(results) -> str:
    if not results:
        return "no measured fast path is used by the frame cases selected"
    head = ("fast path", "cases", "reference ms", "fast ms", "wall/event off", "wall/event on", "used")
    body = []
    for r in results:
        ratio = (lambda w, e: f"{w / e:.2f}" if e and e == e else "-")
        body.append((r.name, str(len(r.cases)),
                     f"{r.total(2):.3f}" if r.cases else "-", f"{r.total(3):.3f}" if r.cases else "-",
                     ratio(r.total(2), r.total(4)) if r.cases else "-",
                     ratio(r.total(3), r.total(5)) if r.cases else "-",
                     ("yes" if r.use else "no" if r.use is not None else "not measured")
                     + (f" ({r.note})" if r.note else "")))
    widths = [max(len(x[i]) for x in [head] + body) for i in range(len(head))]
    fmt = "  ".join(f"{{:{'<' if i in (0, 6) else '>'}{w}}}" for i, w in enumerate(widths))
    return "\n".join([fmt.format(*head), fmt.format(*("-" * w for w in widths))] + [fmt.format(*b) for b in body])


@dataclass
class PrecisionResult:
    method: str
    shape: str
    fp32_ms: float = float("nan")
    fp16_ms: float = float("nan")
    use: bool | None = None
    note: str = ""


def time_method(dev, method: str, render, scale: float, prec: str, runs: int = 5) -> float:
    """Median wall ms of the method's warm frame step (step_device on frames already on the
    device: no transfer is timed), on precision.sequence's synthetic frames."""
    from clss import methods
    from clss.pipeline import precision
    from clss.pipeline.contract import output_size
    from .hostwait import make_upscaler
    spec = methods.spec(method)
    color, depth, motion, jitter, gb = precision.sequence(spec, scale, frames=2, render=render)[1]
    d = [dev.to_device(a, "fp32") for a in (color, depth, motion)]
    gbd = {k: dev.to_device(v, "fp32") for k, v in gb.items()}
    out = dev.empty(output_size(*render, scale) + (3,), dtype=np.float32)
    up = make_upscaler(dev, method, scale, prec, False)
    walls = []
    for i in range(2 + runs):
        dev.queue.finish()
        t0 = time.perf_counter()
        up.step_device(*d, jitter, reset=i == 0, out=out, **gbd)
        dev.queue.finish()
        walls.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(walls[2:])


def tune_precisions(dev, render, scale: float, *, runs=5, store=True, db=None, deadline=None,
                    log=print, names=None) -> list[PrecisionResult]:
    """Each method's frame step in fp32 and fp16 (fp16 first checked against fp32 by
    precision.verdict); op "fp16" stores whether fp16 was at least MARGIN faster."""
    from clss import methods
    from clss.pipeline import precision
    from clss.pipeline.contract import output_size
    H, W = output_size(*render, scale)
    out = []
    for name in names or methods.names():
        spec = methods.spec(name)
        if "fp16" not in spec.precisions or not spec.scales[0] <= scale <= spec.scales[1]:
            continue
        res = PrecisionResult(name, f"{render[0]}x{render[1]}->{H}x{W}")
        out.append(res)
        if deadline and time.monotonic() > deadline:
            res.note = "budget ran out"
            continue
        v = precision.verdict(spec, dev)
        if not v.ok:
            res.use, res.note = False, f"fp16 does not verify: {v.detail}"
        else:
            try:
                res.fp32_ms = time_method(dev, name, render, scale, "fp32", runs)
                res.fp16_ms = time_method(dev, name, render, scale, "fp16", runs)
                res.use = res.fp16_ms <= res.fp32_ms * (1 - MARGIN)
            except Exception as e:      # a method that cannot run at this size: fp16 not chosen
                res.use, res.note = False, f"{type(e).__name__}: {str(e).splitlines()[0][:160]}"
        log(f"  fp16 {name} {res.shape}: fp32 {res.fp32_ms:.3f} ms, fp16 {res.fp16_ms:.3f} ms"
            + (f" ({res.note})" if res.note else ""))
        if store and res.use is not None:
            tuning.store(dev, tuning.FP16_OP, name, {"use": res.use}, path=db,
                         ms=round(res.fp16_ms, 4) if res.fp16_ms == res.fp16_ms else None,
                         default_ms=round(res.fp32_ms, 4) if res.fp32_ms == res.fp32_ms else None,
                         shape=res.shape, note=res.note)
    return out


def format_precisions(results) -> str:
    head = ("method", "shape", "fp32 ms", "fp16 ms", "fp16 with auto")
    body = [(r.method, r.shape, f"{r.fp32_ms:.3f}" if r.fp32_ms == r.fp32_ms else "-",
             f"{r.fp16_ms:.3f}" if r.fp16_ms == r.fp16_ms else "-",
             ("yes" if r.use else "no" if r.use is not None else "not measured")
             + (f" ({r.note})" if r.note else "")) for r in results]
    widths = [max(len(x[i]) for x in [head] + body) for i in range(len(head))]
    fmt = "  ".join(f"{{:{'<' if i in (0, 1, 4) else '>'}{w}}}" for i, w in enumerate(widths))
    return "\n".join([fmt.format(*head), fmt.format(*("-" * w for w in widths))] + [fmt.format(*b) for b in body])
