"""Measuring conv2d's variant rows on one layer: the core of `clss tune --level`
(bench/tune_layers.py) and of the probe at first use.

The probe: where a device has rows that are chosen by timing them at first use (a Variant's
`probe(dev)` is true: the tensor-core and GEMM rows on GPUs), and neither the tuning database
nor the shipped table names a row for the layer, the first conv2d of that layer runs every
such row and the default row on seeded tensors of its shapes, rejects a row whose output
differs from the default's (the precision's tolerance), times the rest and stores the fastest
in the tuning database (`probed: true`). A row is therefore used only where it compiled,
passed its self-check, matched the default on the layer itself and measured faster. On a
device with no probed rows (every CPU class) nothing runs. CLSS_PROBE=0 turns it off."""
from __future__ import annotations

import os
import statistics
import time

import numpy as np

from .. import tuning
from ..tolerance import DEFAULT_TOL, compare

MARGIN = 0.05       # a rival replaces the default row only when at least 5 % faster
PROBE_RUNS = 3


def time_layer(run, dev, prec: str, layer, tensors, tuning_, runs: int) -> tuple[float, np.ndarray]:
    """(median wall ms of `runs` after a warm-up that builds and packs, the first output) of
    run(dev, prec, layer, tensors, tuning) (clss.ops.conv.run_layer)."""
    out = run(dev, prec, layer, tensors, tuning_)
    first = np.asarray(dev.to_host(out), np.float32)
    walls = []
    for _ in range(runs):
        t0 = time.perf_counter()
        run(dev, prec, layer, tensors, tuning_)
        dev.queue.finish()
        walls.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(walls), first


def trial(run, dev, prec: str, layer, tensors, ref, row: str, params: dict, runs: int) -> tuple:
    """(ms or None, note): one row with its params, checked against ref, then timed."""
    try:
        ms, out = time_layer(run, dev, prec, layer, tensors, {"VARIANT": row, **params}, runs)
        cmp = compare(out, ref, DEFAULT_TOL[prec])
        if not cmp.passed:
            return None, f"wrong: max abs err {cmp.max_abs:.3g} ({cmp.ratio:.3g} x tolerance)"
        return ms, "pass"
    except Exception as e:      # a row that does not build or launch is just rejected
        return None, f"error: {type(e).__name__}: {str(e).splitlines()[0][:160]}"


def pick(trials, default: str):
    """The fastest passing (row, params, ms, note), the default row's own trial unless a rival
    beats it by MARGIN (timing noise never flips a measured choice)."""
    ok = [t for t in trials if t[2] is not None]
    if not ok:
        return None
    best = min(ok, key=lambda t: t[2])
    base = next((t for t in ok if t[0] == default and not t[1]), None)
    if base is not None and best[2] > base[2] * (1 - MARGIN):
        return base
    return best


def enabled() -> bool:
    return os.environ.get("CLSS_PROBE", "1").strip() not in ("0", "off", "no", "false")


def probe(dev, prec: str, key: str, layer, rows, default: str, *, tensors, run) -> str:
    """Time the probed rows against `default` on this layer, store the winner (module doc) and
    return its name.
    tensors(dev, prec, layer) and run(dev, prec, layer, tensors, tuning): the op's own
    (clss.ops.conv.layer_tensors, run_layer)."""
    base = getattr(dev, "base", dev)    # a model's planning device: measure on the real one
    data = tensors(base, prec, layer)
    ref_ms, ref = time_layer(run, base, prec, layer, data, {"VARIANT": default}, PROBE_RUNS)
    trials = [(default, {}, ref_ms, "pass")]
    for r in rows:
        ms, note = trial(run, base, prec, layer, data, ref, r.name, {}, PROBE_RUNS)
        trials.append((r.name, {}, ms, note))
    best = pick(trials, default)
    tuning.store(base, "conv2d", key, {"VARIANT": best[0]}, ms=best[2], default_ms=ref_ms, default=default,
                 layer=str(layer), precision=prec, probed=True,
                 trials={t[0]: (round(t[2], 4) if t[2] is not None else t[3]) for t in trials})
    return best[0]
