"""Does input noise or exposure explain why the learned methods lose to clss-rules on the
rendered (Blender) sets but beat it on the generator's? Issue 53, 2026-11-29.

The Blender renders differ from the generator's frames in two measurable ways besides
their content: their colour is 16-spp path tracing (the generator's is noise-free) and the
game-like family is darker (median linear luminance 0.30 against the generator's 0.49).
This perturbs the generated held-out set (out/data/heldout, 16 sequences) each way, scores
every method on the perturbed copies with the house's evaluation (clss.evaluate.run_eval)
and prints each method's PSNR / tPSNR minus clss-rules':

  noise SIGMA   the low-resolution colour times (1 + SIGMA n), n ~ N(0, 1) per render pixel
                and frame, common to the channels (a Monte Carlo estimate's relative
                error; the reference is left clean)
  exposure K    colour and reference times K (the same scene, exposed K times as bright)

If the learned methods' lead over the rules survives the perturbation, that difference is
not why they lose on rendered content.

    .venv/bin/python studies/2026-11-29-input-perturbations.py [--sets noise0.1,noise0.3,exposure0.5]
        [--methods clss-rules,clss,nss,nsrr,nsrd,mlp] [--json FILE]
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import sys
import tempfile

import numpy as np

from clss.evaluate import run_eval


def perturb(src_paths, kind, k, out_dir):
    paths = []
    for p in src_paths:
        d = dict(np.load(p))
        name = os.path.basename(p)
        if kind == "noise":
            rng = np.random.default_rng(int.from_bytes(name.encode()[-8:], "little"))
            c = d["color"].astype(np.float32)
            n = rng.standard_normal(c.shape[:3] + (1,), dtype=np.float32)
            d["color"] = np.maximum(c * (1 + k * n), 0).astype(d["color"].dtype)
        elif kind == "exposure":
            for key in ("color", "reference"):
                d[key] = (d[key].astype(np.float32) * k).astype(d[key].dtype)
        else:
            raise ValueError(kind)
        paths.append(os.path.join(out_dir, name))
        np.savez(paths[-1], **d)
    return paths


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default="out/data/heldout/seq_*.npz")
    p.add_argument("--sets", default="clean,noise0.1,noise0.3,exposure0.5")
    p.add_argument("--methods", default="clss-rules,clss,nss,nsrr,nsrd,mlp")
    p.add_argument("--json", default=None)
    a = p.parse_args()
    src = sorted(glob.glob(a.data))
    if not src:
        sys.exit(f"--data {a.data}: no sequences")
    result = {}
    for s in a.sets.split(","):
        with tempfile.TemporaryDirectory() as tmp:
            if s == "clean":
                paths = src
            else:
                kind = "noise" if s.startswith("noise") else "exposure"
                paths = perturb(src, kind, float(s[len(kind):]), tmp)
            r = run_eval(paths, methods=a.methods.split(","), out_dir=os.path.join(tmp, "eval"),
                         flip_every=1000, log=open(os.devnull, "w"))
        mean = r["mean"] if "mean" in r else r
        result[s] = mean
        rules = mean["CLSS rules"] if "CLSS rules" in mean else mean["clss-rules"]
        print(f"{s}: clss-rules {rules['psnr']:.2f} / {rules['tpsnr']:.2f}; " + ", ".join(
            f"{m} {v['psnr'] - rules['psnr']:+.2f} / {v['tpsnr'] - rules['tpsnr']:+.2f}"
            for m, v in mean.items() if v is not rules), flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"what": __doc__.split("\n\n")[0], "data": a.data, "sets": result}, f, indent=1)


if __name__ == "__main__":
    main()
