"""`clss tune --level fast|full`: choose the conv2d variant (and, at full, its tiles) per layer
of the networks the bench runs, on this device, by measurement.

1. Every network case selected runs once while clss.ops.variants records the conv layers it
   asks the chooser for (shapes, strides, pads, group, layout, precision).
2. Each distinct layer runs alone on seeded tensors with every row of the variant table
   that takes it and whose self-check passes on the device (clss/ops/conv.py VARIANTS):
   first checked against the row the device runs now (within the precision's tolerance:
   a wrong row is rejected however fast), then timed (median of `runs` after a warm-up).
   At level full, the two fastest rows also search their tunables (register and work-group
   tiles), up to `max_candidates` each, where their untuned time is within FULL_WITHIN of
   the fastest row's: on a CPU the GPU's GEMM rows run 10-50x slower than the register
   tiles, and searching their tiles spent a whole budget on one layer.
3. The fastest correct choice is stored in the tuning database under the device, driver,
   layer key and kernel-source hash (clss.ops.conv.layer_key), where conv2d's chooser
   reads it on every later run; a layer whose default won is stored too, so that the report
   and the shipped tables show it was measured.
A time budget bounds the whole search, shared out over the layers left (a layer may use twice
its share, never the rest): layers left when it runs out keep their defaults and are listed. Program binaries of every variant tried stay in the driver's and pyopencl's
caches (clss.cachedir), so a tuned device builds nothing on its next first frame."""
from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field


from clss import tuning
from clss.ops import conv, conv_probe, variants

from .tune_fastpaths import format_paths, format_precisions, tune_paths, tune_precisions

LEVELS = ("fast", "full")
PATHS_SHARE = 0.25  # of the budget, kept for the frame steps' fast paths (bench/tune_fastpaths.py)
FULL_WITHIN = 1.5   # level full searches the tiles of rows at most this much slower than the best


@dataclass
class LayerResult:
    layer: object
    prec: str
    key: str
    default: str
    default_ms: float
    best: str = ""
    best_params: dict = field(default_factory=dict)
    best_ms: float = float("nan")
    trials: list = field(default_factory=list)     # (variant, params, ms or None, note)
    flops: float = 0.0

    @property
    def gain(self) -> float:
        return self.default_ms / self.best_ms if self.best_ms == self.best_ms and self.best_ms > 0 else float("nan")


def conv_flops(layer) -> float:
    """2 * multiply-adds of a conv layer (the output size from its shapes, strides and pads)."""
    n, c, h, w = layer.x
    co, cig, kh, kw = layer.w
    ho = conv.conv_output_size(h, kh, layer.strides[0], layer.pads[0] + layer.pads[2], layer.dilations[0])
    wo = conv.conv_output_size(w, kw, layer.strides[1], layer.pads[1] + layer.pads[3], layer.dilations[1])
    return 2.0 * n * co * ho * wo * cig * kh * kw


def collect_layers(cases, dev, precs, log=print) -> list[tuple]:
    """The distinct (layer, precision) conv2d calls of the cases' networks, in first-seen order."""
    seen = {}
    for case in cases:
        for prec in precs:
            if prec not in case.precisions:
                continue
            try:
                setup = case.build(dev, prec, dict(case.defaults))
                with variants.recording() as rec:
                    outs = setup.run()
                    dev.queue.finish()
                del outs
                if setup.release:
                    setup.release()
            except Exception as e:      # a case that cannot build here: report, tune the rest
                log(f"  {case.label} [{prec}]: not run ({type(e).__name__}: {str(e).splitlines()[0][:160]})")
                continue
            for op, layer in rec:
                if op == "conv2d" and not layer.gated:
                    seen.setdefault((layer, prec), case.name)
    return list(seen)


def tune_layer(dev, prec, layer, *, level="fast", runs=5, max_candidates=24, store=True, db=None,
               deadline=None, log=print) -> LayerResult:
    key = conv.layer_key(layer, prec)
    rows = [r for r in variants.candidates(dev, prec, conv.VARIANTS, layer) if r.enabled(dev, prec)]
    tensors = conv.layer_tensors(dev, prec, layer)
    # the reference: the row the device would run with no tuned entry
    with tuning.ignoring_entries():
        ref_row = variants.choose(dev, prec, "conv2d", key, conv.VARIANTS, layer).name
        ref_ms, ref = conv_probe.time_layer(conv.run_layer, dev, prec, layer, tensors, {"VARIANT": ref_row}, runs)
    res = LayerResult(layer, prec, key, ref_row, ref_ms, flops=conv_flops(layer))

    def trial(row, params):
        ms, note = conv_probe.trial(conv.run_layer, dev, prec, layer, tensors, ref, row.name, params, runs)
        res.trials.append((row.name, dict(params), ms, note))
        log(f"  {layer} [{prec}] {row.name} {params or ''}: " + (f"{ms:.3f} ms" if ms is not None else note))
        return ms

    for row in rows:
        if deadline and time.monotonic() > deadline:
            break
        trial(row, {})
    if level == "full":
        by_speed = sorted((t for t in res.trials if t[2] is not None), key=lambda t: t[2])[:2]
        for name, _, ms, _ in by_speed:
            if ms > by_speed[0][2] * FULL_WITHIN:
                continue
            row = next(r for r in rows if r.name == name)
            space = row.tunables
            names = sorted(space)
            for vals in itertools.islice(itertools.product(*(space[n] for n in names)), max_candidates):
                if deadline and time.monotonic() > deadline:
                    break
                trial(row, dict(zip(names, vals)))
    best = conv_probe.pick(res.trials, ref_row)
    if best is not None:
        base = next((t for t in res.trials if t[0] == ref_row and not t[1] and t[2] is not None), None)
        if base is not None:
            res.default_ms = base[2]
        res.best, res.best_params, res.best_ms = best[0], best[1], best[2]
        if store:
            tuning.store(dev, "conv2d", key, {"VARIANT": res.best, **res.best_params}, path=db, ms=res.best_ms,
                         default_ms=res.default_ms, default=ref_row, layer=str(layer), precision=prec,
                         level=level)
    return res


def format_layers(results, peak_gflops: float | None = None) -> str:
    head = ("layer", "prec", "default", "ms", "best", "ms", "gain", "GFLOP/s", "% peak", "rejected")
    body = []
    for r in results:
        gf = r.flops / (r.best_ms * 1e6) if r.best_ms == r.best_ms and r.best_ms else float("nan")
        params = ",".join(f"{k}={v}" for k, v in r.best_params.items())
        body.append((str(r.layer), r.prec, r.default, f"{r.default_ms:.3f}",
                     (r.best + (f" {params}" if params else "")) or "-",
                     f"{r.best_ms:.3f}" if r.best else "-", f"{r.gain:.2f}x" if r.best else "-",
                     f"{gf:.1f}" if gf == gf else "-",
                     f"{100 * gf / peak_gflops:.0f}" if peak_gflops and gf == gf else "-",
                     str(sum(t[2] is None for t in r.trials))))
    widths = [max(len(str(x[i])) for x in [head] + body) for i in range(len(head))]
    fmt = "  ".join(f"{{:{'<' if i in (0, 1, 2, 4) else '>'}{w}}}" for i, w in enumerate(widths))
    return "\n".join([fmt.format(*head), fmt.format(*("-" * w for w in widths))] + [fmt.format(*b) for b in body])


def main(a, dev, precs, cases, logger) -> int:
    """clss tune --level: bench/cli.py tune_main parsed the arguments, chose the device, the
    precisions and the network cases; logger(bar) -> log function."""
    import sys
    from pathlib import Path

    from clss.progress import progress

    from .peak import fma_gflops

    budget = a.budget or (240.0 if a.level == "fast" else 1200.0)
    frames = [c for c in cases if c.kind == "frame"]
    cases = [c for c in cases if c.kind == "network"]
    end = time.monotonic() + budget
    # the layers' search stops early enough to leave the frame steps' fast paths their share
    deadline = end - (PATHS_SHARE * budget if frames else 0.0)
    db = Path(a.db) if a.db else tuning.db_path()
    print(f"device: {dev.info.name} (driver {dev.info.driver}, class {tuning.device_class(dev)}); "
          f"{len(cases)} network and {len(frames)} frame case(s) x {len(precs)} precision(s); level {a.level}, "
          f"budget {budget:.0f} s; database {db}{' (dry run)' if a.dry_run else ''}", file=sys.stderr)
    log = logger(None)
    layers = collect_layers(cases, dev, precs, log=log)
    results, left = [], []
    bar = progress(layers, desc="tune layers", unit="layer")
    log = logger(bar)
    for i, (layer, prec) in enumerate(bar):
        now = time.monotonic()
        if now > deadline:
            left.append((layer, prec))
            continue
        share = 2 * (deadline - now) / (len(layers) - i)
        try:
            results.append(tune_layer(dev, prec, layer, level=a.level, runs=a.runs,
                                      max_candidates=a.max_candidates, store=not a.dry_run, db=db,
                                      deadline=min(deadline, now + share), log=log))
        except Exception as e:      # one layer that cannot run: report it, tune the rest
            log(f"{layer} [{prec}]: {type(e).__name__}: {str(e).splitlines()[0][:200]}")
    try:
        peak = max(fma_gflops(dev, vw, target_s=0.05, repeats=2) for vw in (8, 16))
    except Exception:
        peak = None
    print(format_layers(results, peak))
    if left:
        print(f"\n{len(left)} layer(s) left untuned when the {budget:.0f} s budget ran out:")
        for layer, prec in left:
            print(f"  {layer} [{prec}]")
    print(f"\n{sum(bool(r.best) for r in results)} layer choices {'would be ' if a.dry_run else ''}stored in {db}")
    if frames:
        paths = tune_paths(frames, dev, precs, runs=a.runs, store=not a.dry_run, db=db, deadline=end,
                           log=logger(None))
        print("\nfused frame-step fast paths (the frame cases' wall ms without and with each):")
        print(format_paths(paths))
        print(f"\n{sum(r.use is not None for r in paths)} fast-path choices "
              f"{'would be ' if a.dry_run else ''}stored in {db}")
    if frames and {"fp32", "fp16"} <= set(precs):
        from .cases import TIERS
        render, scale = TIERS["tiny" if a.tiny else a.tier or "1080p"]
        got = tune_precisions(dev, render, scale, runs=a.runs, store=not a.dry_run, db=db, deadline=end,
                              log=logger(None))
        print("\nfp16 storage against fp32, each method's frame step (precision=\"auto\" picks fp16 on a "
              "GPU where it verifies and is not slower):")
        print(format_precisions(got))
    return 0
