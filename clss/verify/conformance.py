"""Diff kernels against onnxruntime: the rows of `clss verify` and of the op tests."""
from __future__ import annotations

import time
import traceback
from dataclasses import asdict, dataclass

import numpy as np

from ..device import Device, kernel_label
from ..tolerance import compare
from .case import Case, round_inputs
from .twin import run_ort


@dataclass
class Row:
    op: str
    variant: str
    precision: str
    max_abs: float
    max_rel: float
    ratio: float
    tolerance: str
    passed: bool
    detail: str = ""
    ms: float = 0.0

    def as_dict(self) -> dict:
        return asdict(self)


def reference(case: Case, precision: str) -> list[np.ndarray]:
    """onnxruntime on the twin, fed the inputs the engine stores (fp16-rounded in
    half modes); for bit-exact ops the reference is then rounded like the storage."""
    refs = run_ort(case.twin, round_inputs(case, precision))
    if precision != "fp32" and case.exact:
        refs = [r.astype(np.float16).astype(np.float32) if r.dtype.kind == "f" else r for r in refs]
    return refs


def check(case: Case, dev: Device, precision: str) -> Row:
    t0 = time.perf_counter()
    try:
        refs = reference(case, precision)
        outs = case.run(dev, precision, round_inputs(case, precision))
    except Exception as e:  # a failing kernel is a FAIL row, not a crash of the whole run
        last = traceback.format_exception_only(type(e), e)[-1].strip()
        return Row(case.op, case.variant, precision, np.inf, np.inf, np.inf,
                   str(case.tolerance(precision)), False, last[:2000])
    ms = (time.perf_counter() - t0) * 1e3
    if len(outs) != len(refs):
        return Row(case.op, case.variant, precision, np.inf, np.inf, np.inf,
                   str(case.tolerance(precision)), False,
                   f"{len(outs)} outputs, reference has {len(refs)}", ms)
    worst = None
    for i, (o, r) in enumerate(zip(outs, refs)):
        c = compare(o, r, case.tolerance(precision))
        if len(outs) > 1 and c.detail:
            c.detail = f"output {i}: {c.detail}"
        if worst is None or (not c.passed and worst.passed) or (c.passed == worst.passed and c.ratio > worst.ratio):
            worst = c
    return Row(case.op, case.variant, precision, worst.max_abs, worst.max_rel, worst.ratio,
               worst.tol, worst.passed, worst.detail, ms)


def format_table(rows: list[Row]) -> str:
    head = ("op", "variant", "prec", "max abs err", "max rel err", "tolerance", "err/tol", "result")
    body = []
    for r in rows:
        ratio = f"{r.ratio:.0f} bad" if r.tolerance == "bit-exact" and r.ratio else (
            "0" if r.tolerance == "bit-exact" else f"{r.ratio:.3f}")
        body.append((r.op, r.variant, r.precision, f"{r.max_abs:.2e}", f"{r.max_rel:.2e}",
                     r.tolerance, ratio, "PASS" if r.passed else "FAIL"))
    widths = [max(len(str(x[i])) for x in [head] + body) for i in range(len(head))]
    fmt = "  ".join(f"{{:{'<' if i < 3 or i == 5 else '>'}{w}}}" for i, w in enumerate(widths))
    lines = [fmt.format(*head), fmt.format(*("-" * w for w in widths))]
    lines += [fmt.format(*b) for b in body]
    fails = [r for r in rows if not r.passed]
    for r in fails:
        if r.detail:
            lines.append(f"FAIL {r.op}[{r.variant}] {r.precision}: {r.detail}")
    return "\n".join(lines)


def format_fast_paths(verdicts) -> str:
    """The section after the table: which fast variants the self-check disabled here."""
    bad = [v for v in verdicts if not v.ok]
    names = sorted({v.name for v in verdicts})
    lines = [f"fast paths: {len(names)} variant(s) self-checked against their reference variants "
             f"(clss/selfcheck.py); {len(bad)} disabled on this device"]
    from ..selfcheck import REGISTRY
    for v in bad:
        fp = REGISTRY.get(v.name)
        ref = f", using {fp.options(False)}" if fp else ""
        src = kernel_label(fp.kernel) if fp else v.kernel
        lines.append(f"  DISABLED {v.name} [{v.precision}] ({v.options}, {src}): {v.detail}{ref}")
    return "\n".join(lines)


def format_device_choices(dev) -> str:
    """What this device runs where a choice is per device: each measured fast path (used or
    not, and whether the tuning database, the shipped table or the default said so), and
    what precision="auto" resolves to for each method (on a GPU: checked here, once)."""
    from .. import methods, selfcheck, tuning
    from ..pipeline import precision
    lines = [f"fused frame-step fast paths (measured per device: clss tune --level fast; class "
             f"{tuning.device_class(dev)}):"]
    for name, fp in sorted(selfcheck.REGISTRY.items()):
        if not fp.measured:
            continue
        tuned = tuning.entry(dev, tuning.FAST_PATH_OP, name)
        shipped = tuning.shipped(dev).get(tuning.FAST_PATH_OP, {}).get(name)
        src = ("tuned here" if tuned and isinstance(tuned.get("params", {}).get("use"), bool)
               else "shipped table" if isinstance(shipped, bool) else
               "default: measured on CPUs" if dev.is_cpu else "default: not measured on this class")
        lines.append(f"  {name:28s} {'used' if fp.applies_on(dev) else 'not used'} ({src})")
    if dev.is_cpu:
        lines.append('precision="auto" (every method\'s default): fp32 on a CPU')
        return "\n".join(lines)
    lines.append('precision="auto" (every method\'s default): fp16 storage where the method\'s fp16 '
                 'frame step verifies against fp32 here and was not measured slower (clss/pipeline/precision.py)')
    for name in methods.names():
        spec = methods.spec(name)
        if "fp16" not in spec.precisions:
            lines.append(f"  {name:14s} fp32 (no fp16)")
            continue
        if tuning.measured_choice(dev, tuning.FP16_OP, name) is False:
            lines.append(f"  {name:14s} fp32 (its fp16 frame step measured slower here: clss tune --level)")
            continue
        v = precision.verdict(spec, dev)
        lines.append(f"  {name:14s} {precision.resolve(spec, dev, 'auto')} ({v.detail})")
    return "\n".join(lines)


def format_variants(dev, precisions, verdicts) -> str:
    """The conv variant table on this device: each row, whether it applies here and its
    self-checks' verdicts per precision, and the shipped table the chooser reads
    (docs/kernels.md, the conv variant table)."""
    from .. import tuning
    from ..ops import conv
    from .. import selfcheck
    from ..selfcheck import REGISTRY
    got = {(v.name, v.precision): v.ok for v in verdicts}
    table = tuning.shipped(dev)
    order = table.get("ops", {}).get("conv2d", {}).get("order", [])
    lines = [f"conv variants: shipped table {tuning.device_class(dev)} (order: {', '.join(order) or '-'}; "
             f"a tuned or probed entry per layer comes first: clss tune --level fast)"]
    for row in conv.VARIANTS:
        states = []
        for prec in precisions:
            paths = [REGISTRY[n] for n in row.fast_paths if n in REGISTRY]
            if any(not fp.applies_on(dev) for fp in paths):
                states.append(f"{prec} does not apply here")
            elif all(got.get((fp.name, prec), selfcheck.enabled(dev, prec, fp.name)) for fp in paths):
                states.append(f"{prec} passes" if paths else f"{prec} reference")
            else:
                states.append(f"{prec} DISABLED")
        lines.append(f"  {row.name:12s} {'; '.join(dict.fromkeys(states))}  ({row.what})")
    return "\n".join(lines)
