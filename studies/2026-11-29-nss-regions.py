"""Where NSS loses to the rules, region by region (issue 53 part 3), on generated held-out
sequences, whose labels say what each output pixel is (weights_tools/scenegen.py):

  disocclusion   label_ghost == visibility on a frame that is not a reset (newly visible)
  lighting       label_ghost == shading (the same surface point, its radiance changed:
                 moving shadows, specular highlights, blinking lamps)
  thin geometry  label_alias == geometry (more than one primitive inside the pixel: edges,
                 wires, cut-outs)
  texture        label_alias == texture (one primitive, sub-pixel texture)
  flat           label_ghost == none and label_alias == none

PSNR over each region's pixels of the scored frames (warm-up 4 after a reset), on the
display values clss.metrics scores (clss.io.tonemap), pooled over the sequences.

    .venv/bin/python studies/2026-11-29-nss-regions.py SEQ.npz ... \
        [--nss NAME=WEIGHTS ...] [--json FILE]

Methods: clss-rules and nss with each --nss weights (default: the package's).
"""
from __future__ import annotations

import argparse
import json

import numpy as np

import clss
from clss.evaluate import load_sequence
from clss.io import tonemap

WARMUP = 4
REGIONS = ("disocclusion", "lighting", "thin geometry", "texture", "flat", "all")


def masks(z, t):
    g, a = z["label_ghost"][t], z["label_alias"][t]
    return {"disocclusion": (g == 0) & ~z["reset"][t], "lighting": g == 1,
            "thin geometry": a == 0, "texture": a == 1, "flat": (g == 2) & (a == 2),
            "all": np.ones_like(g, bool)}


def run(method, seq, weights=None):
    kw = {} if weights is None else {"weights": weights}
    up = clss.Upscaler(method=method, scale=seq["scale"], **kw)
    outs = []
    for t in range(len(seq["color"])):
        outs.append(up.step(seq["color"][t], seq["depth"][t], seq["motion"][t],
                            tuple(seq["jitter"][t]), reset=bool(seq["reset"][t])))
    return outs


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("seqs", nargs="+")
    p.add_argument("--nss", action="append", default=[], help="NAME=WEIGHTS")
    p.add_argument("--json", default=None)
    a = p.parse_args()
    methods = [("clss-rules", "clss-rules", None)]
    methods += [("nss " + n, "nss", w) for n, w in (x.split("=", 1) for x in a.nss)] or \
               [("nss", "nss", None)]
    sse = {m: {r: 0.0 for r in REGIONS} for m, _, _ in methods}
    count = {r: 0 for r in REGIONS}
    for path in a.seqs:
        seq, z = load_sequence(path), np.load(path)
        since = np.zeros(len(seq["reset"]), int)
        for t in range(len(since)):
            since[t] = 0 if seq["reset"][t] else since[t - 1] + 1
        scored = [t for t in range(len(since)) if since[t] >= WARMUP]
        ref = {t: tonemap(seq["reference"][t]) for t in scored}
        for t in scored:
            for r, m in masks(z, t).items():
                count[r] += int(m.sum()) * 3
        for label, method, w in methods:
            outs = run(method, seq, w)
            for t in scored:
                d2 = (tonemap(outs[t]) - ref[t]) ** 2
                for r, m in masks(z, t).items():
                    sse[label][r] += float(d2[m].sum())
        print(f"{path}: done", flush=True)
    table = {label: {r: (10 * np.log10(count[r] / sse[label][r]) if sse[label][r] > 0 else None)
                     for r in REGIONS} for label in sse}
    share = {r: count[r] / count["all"] for r in REGIONS}
    print("region".ljust(14) + "".join(f"{label:>16s}" for label in table) + "   share")
    for r in REGIONS:
        print(r.ljust(14) + "".join(f"{table[label][r]:16.2f}" for label in table)
              + f"   {share[r]:.3f}")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"psnr": table, "share": share, "sequences": a.seqs, "warmup": WARMUP}, f,
                      indent=1)


if __name__ == "__main__":
    main()
