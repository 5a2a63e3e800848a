"""The count of the ONNX backend node cases run as shipped (tests/test_node_cases_raw.py):
how many run and match, how many are wrong, refused (by the ops the refusal names) or
fail otherwise, single-node and expanded cases apart.

    python tests/node_case_report.py                 # every case, the default device
    python tests/node_case_report.py -k softmax -v   # the cases whose name has "softmax", each listed
    python tests/node_case_report.py --json r.json   # the outcome of every case as JSON

Deviations (cases listed with a reason) are counted apart from the refusals and errors.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import warnings
from collections import Counter, defaultdict

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("-k", default="", help="only the cases whose name contains this")
    p.add_argument("-v", action="store_true", help="list every case that is not a pass or a skip")
    p.add_argument("--device", default=None, help="a clss device spec (default: the default device)")
    p.add_argument("--json", metavar="FILE", help="write every case's outcome as JSON")
    a = p.parse_args(argv)
    warnings.filterwarnings("ignore")
    from test_node_cases_raw import CASES, deviation, run_case

    from clss.device import get_device
    dev = get_device(a.device)
    rows = {}
    for d in CASES:
        name = os.path.basename(d)
        if a.k and a.k not in name:
            continue
        outcome, detail = run_case(d, dev)
        if outcome not in ("pass", "pass-no-ort", "skip") and deviation(name):
            outcome = "deviation"
        rows[name] = (outcome, detail)
        if a.v and outcome not in ("pass", "pass-no-ort", "skip"):
            print(f"{name}: {outcome}: {detail.splitlines()[0] if detail else ''}"[:300], flush=True)
    kinds = {"single-node": {k: v for k, v in rows.items() if "_expanded" not in k},
             "expanded": {k: v for k, v in rows.items() if "_expanded" in k}}
    for kind, rs in kinds.items():
        c = Counter(o for o, _ in rs.values())
        ran = len(rs) - c["skip"]
        ok = c["pass"] + c["pass-no-ort"]
        print(f"{kind}: {ok} of {ran} run ({c['pass-no-ort']} of them without onnxruntime), "
              f"{c['wrong'] + c['wrong-ort']} wrong ({c['wrong-ort']} only vs onnxruntime), "
              f"{c['refused']} refused, {c['error']} other errors, {c['deviation']} deviations; "
              f"{c['skip']} skipped")
        by_op = defaultdict(list)
        for name, (o, detail) in rs.items():
            if o == "refused":
                by_op[detail.partition("\n")[0]].append(name)
        for ops, names in sorted(by_op.items(), key=lambda kv: -len(kv[1])):
            print(f"  refused naming {ops}: {len(names)}  ({', '.join(names[:4])}{', ...' if len(names) > 4 else ''})")
        skips = Counter(d.split(":")[0] for o, d in rs.values() if o == "skip")
        if skips:
            print("  skipped: " + "; ".join(f"{k} {v}" for k, v in skips.most_common()))
    if a.json:
        with open(a.json, "w") as f:
            json.dump({k: {"outcome": o, "detail": d} for k, (o, d) in rows.items()}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
