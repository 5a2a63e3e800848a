"""`clss tune`: search kernel tunables and work-group sizes per case, shape and
device; keep the fastest candidate whose output matches onnxruntime.

Two search spaces:
* parameters: the case's own (BenchCase.tunables, e.g. conv's XV/CB register
  block), or, where an op asks the database itself (clss.tuning.lookup), the
  candidates its family declares in TUNABLES = {op: {param: candidates}};
* work-group sizes for every kernel the case launches (the driver's choice
  included), applied where they divide the global size.

Every candidate's first run is checked against the reference before it is timed;
a wrong candidate is rejected however fast it is. Results go to the tuning
database (clss/tuning.py) under the device's name and driver version.
"""
from __future__ import annotations

import itertools
import os
from dataclasses import dataclass, field

from clss import tuning
from clss.device import Device

from .cases import BenchCase
from .runner import OrtRunner, check_setup, time_engine

LOCAL_CANDIDATES = (None, (8,), (16,), (32,), (64,), (128,), (8, 2), (16, 4), (32, 2))


@dataclass
class Trial:
    params: dict
    local: tuple | None
    ms: float = float("nan")
    event_ms: float = float("nan")
    check: str = ""
    launches: list = field(default_factory=list)    # (kernel name, global size)

    @property
    def ok(self) -> bool:
        return self.check == "pass"


@dataclass
class TuneResult:
    case: str
    precision: str
    op: str
    key: str
    default_ms: float
    best: Trial | None
    trials: list = field(default_factory=list)
    stored: list = field(default_factory=list)

    @property
    def gain(self) -> float:
        return self.default_ms / self.best.ms if self.best and self.best.ms else float("nan")


def _grid(space: dict, limit: int) -> list[dict]:
    names = sorted(space)
    combos = [dict(zip(names, vals)) for vals in itertools.product(*(space[n] for n in names))]
    return combos[:limit]


def family_tunables(ops_seen) -> dict:
    """{op: {param: candidates}} declared by the families for the ops a case looked up."""
    import warnings
    from clss.ops import load_all
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mods = load_all()
    out = {}
    for mod in mods.values():
        for op, space in getattr(mod, "TUNABLES", {}).items():
            if op in ops_seen:
                out[op] = space
    return out


def tune_case(case: BenchCase, dev: Device, prec: str, *, runs: int = 5, max_candidates: int = 48,
              search_local: bool = True, store: bool = True, db=None, log=print) -> TuneResult:
    ort = OrtRunner(os.cpu_count() or 1)
    params: dict = dict(case.defaults)
    with tuning.recording() as seen:
        setup = case.build(dev, prec, params)   # the engine reads `params` on every run
        refs = ort.session(setup.twin).run(None, setup.feeds)
        base_ms, base_ev, outs, launches = time_engine(setup, dev, runs)
    check, _ = check_setup(setup, outs, refs)
    if check != "pass":
        raise RuntimeError(f"{case.name} [{prec}]: the default configuration does not match "
                           f"onnxruntime ({check}); fix the kernel before tuning it")
    looked_up = {op: (key, d) for op, key, d in seen}
    declared = family_tunables(looked_up)
    if declared:   # the op reads the database itself: search its declared space through overrides
        op = next(iter(declared))
        key, op_defaults = looked_up[op]
        space = declared[op]
    else:
        op, key, op_defaults, space = case.tune_op, f"{case.tune_key}/{prec}", dict(case.defaults), case.tunables
    res = TuneResult(case.name, prec, op, key, base_ms, None)

    def trial(cand: dict, local) -> Trial:
        t = Trial(dict(cand), local)
        params.clear()
        params.update({**case.defaults, **cand} if not declared else case.defaults)
        try:
            if declared:
                with tuning.override(op, cand):
                    t.ms, t.event_ms, out, t.launches = time_engine(setup, dev, runs, local)
            else:
                t.ms, t.event_ms, out, t.launches = time_engine(setup, dev, runs, local)
            t.check, _ = check_setup(setup, out, refs)
        except Exception as e:   # a candidate that does not build or launch is just rejected
            t.check = f"error: {type(e).__name__}: {str(e).splitlines()[0][:200]}"
        res.trials.append(t)
        log(f"  {case.name} [{prec}] {cand or ''} local={local}: "
            + (f"{t.ms:.2f} ms" if t.ok else t.check))
        return t

    cands = _grid(space, max_candidates) if space else [{}]
    default_cand = {k: op_defaults.get(k) for k in space} if space else {}
    trials = [trial(c, None) for c in cands]
    ok = [t for t in trials if t.ok]
    best = min(ok, key=lambda t: t.ms) if ok else None
    if best is not None and search_local:
        for loc in LOCAL_CANDIDATES[1:]:
            t = trial(best.params, loc)
            if t.ok and t.ms < best.ms:
                best = t
    res.best = best
    params.clear()
    params.update(case.defaults)
    if best is not None:
        entries = []
        if best.params and best.params != default_cand:
            entries.append((op, key, best.params))
        if best.local is not None:
            from .capture import fit_local
            for name, gs in best.launches:
                loc = fit_local(best.local, gs)
                if loc is not None:
                    entries.append((f"local_size:{name}", tuning.shape_key(gs), {"local": list(loc)}))
        for e_op, e_key, e_params in entries:
            if store:
                tuning.store(dev, e_op, e_key, e_params, path=db, ms=best.ms, default_ms=base_ms,
                             case=case.name, precision=prec)
            res.stored.append((e_op, e_key))
    if setup.release:
        setup.release()
    return res


def format_results(results) -> str:
    head = ("case", "prec", "op", "default ms", "best ms", "gain", "best", "rejected")
    body = []
    for r in results:
        b = r.best
        rejected = sum(not t.ok for t in r.trials)
        desc = "-" if b is None else (", ".join(f"{k}={v}" for k, v in b.params.items())
                                      + (f" local={b.local}" if b.local else ""))
        body.append((r.case, r.precision, r.op, f"{r.default_ms:.2f}", "-" if b is None else f"{b.ms:.2f}",
                     "-" if b is None else f"{r.gain:.2f}x", desc or "defaults", str(rejected)))
    widths = [max(len(str(x[i])) for x in [head] + body) for i in range(len(head))]
    fmt = "  ".join(f"{{:{'<' if i in (0, 1, 2, 6) else '>'}{w}}}" for i, w in enumerate(widths))
    return "\n".join([fmt.format(*head), fmt.format(*("-" * w for w in widths))] + [fmt.format(*b) for b in body])
