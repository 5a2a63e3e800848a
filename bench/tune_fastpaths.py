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
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

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
