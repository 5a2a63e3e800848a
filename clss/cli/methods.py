"""`clss methods` (what each method needs and supports) and `clss eval` (score methods on
the user's own sequences, with the scoring code of `python -m weights_tools eval`)."""
from __future__ import annotations

import argparse
import json
import sys

from .args import ArgParser


def _spec_record(s) -> dict:
    from ..pipeline.contract import Contract
    return {"name": s.name, "label": s.label, "summary": s.summary, "inputs": list(s.inputs),
            "gbuffers": list(s.gbuffers), "optional": list(s.optional),
            "scales": list(s.scales), "precisions": list(s.precisions),
            "temporal": s.temporal, "weights": s.weights(), "doc": s.doc,
            # what it does with each of clss.Contract's parameters (input-contract.md s6)
            "contract": {p: dict(zip(("handling", "why"), s.handling(p)))
                         for p in Contract.names()},
            "parts": {k: list(v) if isinstance(v, tuple) else v for k, v in s.parts().items()}}


def cmd_methods(argv) -> int:
    p = ArgParser(prog="clss methods",
                  description="List the upscaling methods: the inputs each reads (the frame "
                              "contract's and the G-buffers of docs/input-contract.md), the "
                              "scales and precisions it supports, and the state of its weights. "
                              "`clss upscale --method NAME` and clss.Upscaler(method=NAME) run one.",
                  epilog="examples:\n  clss methods\n  clss methods --json",
                  formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--json", action="store_true",
                   help="print the table as JSON, with what each method owns and where it lives "
                        "(\"parts\": its room, kernels, weights, twins, recipe, bench, page, "
                        "tests; docs/architecture.md, 'Adding a method')")
    a = p.parse_args(argv)
    from .. import methods
    recs = [_spec_record(s) for s in methods.specs()]
    if a.json:
        print(json.dumps({"methods": recs, "planned": methods.PLANNED}, indent=1))
        return 0
    nw = max(len("method"), *(len(r["name"]) for r in recs))
    rows = []
    for r in recs:
        inputs = ", ".join(r["inputs"] + [f"{g} (needed)" for g in r["gbuffers"]]
                           + [f"{g} (optional)" for g in r["optional"]])
        lo, hi = r["scales"]
        rows.append((r["name"], inputs, f"{lo:g}-{hi:g}", ",".join(r["precisions"]),
                     "yes" if r["temporal"] else "no", r["weights"]))
    iw = max(len("inputs"), *(len(row[1]) for row in rows))
    print(f"{'method':{nw}s}  {'inputs':{iw}s}  {'scales':8s} {'precisions':10s} "
          f"{'history':7s} weights")
    for name, inputs, scales, precs, hist, weights in rows:
        print(f"{name:{nw}s}  {inputs:{iw}s}  {scales:8s} {precs:10s} {hist:7s} {weights}")
    print()
    for r in recs:
        print(f"  {r['name']:{nw}s}  {r['summary']} ({r['doc']})")
    print()
    if methods.PLANNED:         # every seeded method may be built: then no such line
        print("planned, not built yet: " + "; ".join(f"{k} ({v})" for k, v in
                                                    methods.PLANNED.items()))
    print("aliases: " + ", ".join(f"{k} = {v}" for k, v in methods.ALIASES.items()))
    return 0


def cmd_eval(argv) -> int:
    from .. import evaluate
    p = ArgParser(prog="clss eval",
                  description="Score methods on sequences against their reference frames: PSNR, "
                              "SSIM, tPSNR (flicker) and FLIP on tone-mapped values, with "
                              "side-by-sides and temporal profiles per sequence. A sequence is a "
                              ".npz file in the format of weights_tools/DATA.md (your frames in "
                              "the input contract plus a supersampled reference). The same "
                              "scoring code as `python -m weights_tools eval`; needs no torch.",
                  epilog="examples:\n  clss eval capture.npz\n"
                         "  clss eval a.npz b.npz --methods jbicubic,clss-rules,clss --out out/eval\n"
                         "  clss eval capture.npz --precision fp16 --flip-every 4",
                  formatter_class=argparse.RawDescriptionHelpFormatter)
    evaluate.add_arguments(p)
    a = p.parse_args(argv)
    return evaluate.main_args(a, p, log=sys.stderr)
