"""Every method against the rules region by region, on any DATA.md sequences with
output-resolution depth (`depth_hr`: the Blender shards, the generated sets with
G-buffers), issue 53 part 4. The general form of 2026-11-29-nss-regions.py, which needs
the generator's labels and scores NSS only: here the regions come from the G-buffers and
the reference, so they exist for Blender's held-out families too (the game family:
make eval-game). Per scored frame t (warm-up 4 after a reset, as the eval), at output
resolution:

  disocclusion  clss.metrics.disocclusion_mask (the eval's `disocc` column): reprojected
                into frame t - 1 the render pixel lands off screen or on another surface
  thin          thin geometry (grass blades, leaves, poles, sparks): depth_hr has a ridge
                at most 3 pixels wide (the pixel is 10 % nearer than a pixel 1-2 away on
                both sides, along x or along y; the sky is farthest), dilated by 1 pixel
  edges         the other geometry edges: depth_hr varies by more than 10 % (or meets
                the sky) in the 3x3 neighbourhood, not thin
  hdr           emissive or specular highlights: the reference exceeds 1.5 (linear) in
                some channel in the 3x3 neighbourhood (lamps, sparks, glints; diffusely
                lit surfaces and the sky stay below 1.2 in these scenes)
  texture       none of the above; the tone-mapped reference's 3x3 standard deviation
                (mean of the channels) at least 0.03
  flat          none of the above, below that
  all           the whole frame

PSNR over each region's pixels of the scored frames, on the display values clss.metrics
scores, pooled over the sequences (one mean squared error per region). The frames are
run through clss.evaluate.evaluate_sequence, the house's evaluation: its per-sequence
and mean PSNR / SSIM / tPSNR / FLIP are written too (JSON `eval`), so one pass gives
both tables.

    .venv/bin/python studies/2026-11-29-regions.py SEQ.npz ... [--methods a,b,...]
        [--json FILE] [--warmup 4] [--flip-every 4] [--out DIR] [--weights PATH]
    .venv/bin/python studies/2026-11-29-regions.py --merge A.json B.json ... [--json FILE]

--merge pools the JSON of runs on disjoint sequences (the squared errors and pixel counts
per region are summed; the eval's records are put together and averaged), so the
sequences of a set can be scored in separate processes. --weights scores other weights than
the package's: clss.evaluate's --weights, for the one method with weights among --methods
(a candidate beside the rules: --methods clss-rules,nss --weights out/train-nss/.../
weights.safetensors).
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from clss import evaluate as ev
from clss import metrics
from clss.device import get_device

REGIONS = ("disocclusion", "thin", "edges", "hdr", "texture", "flat", "all")
REL = 0.1           # relative depth step of a geometry edge
HDR = 1.5           # linear reference value of an emitter or a highlight
TEXTURE_STD = 0.03  # tone-mapped 3x3 standard deviation of texture


def _shift(a, dy, dx, fill):
    """a shifted so that out[i, j] = a[i + dy, j + dx] (fill outside)."""
    out = np.full_like(a, fill)
    h, w = a.shape[:2]
    ys, yd = (slice(dy, h), slice(0, h - dy)) if dy >= 0 else (slice(0, h + dy), slice(-dy, h))
    xs, xd = (slice(dx, w), slice(0, w - dx)) if dx >= 0 else (slice(0, w + dx), slice(-dx, w))
    out[yd, xd] = a[ys, xs]
    return out


def _dilate(m):
    out = m.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            out |= _shift(m, dy, dx, False)
    return out


def masks(seq, t, ref_display):
    """{region: H x W bool} of frame t."""
    H, W = ref_display.shape[:2]
    d = seq["gbuffers"].get("depth_hr")
    d = (d[t] if d is not None else metrics.nearest(seq["depth"][t], H, W)).astype(np.float64)
    # reversed-Z: larger is nearer; sky 0 is farthest. "nearer by 10 %": d > n * (1 + REL)
    thin = np.zeros((H, W), bool)
    for axis in ((0, 1), (1, 0)):
        side = {}
        for s in (-1, 1):
            nb = [_shift(d, s * k * axis[0], s * k * axis[1], np.inf) for k in (1, 2)]
            side[s] = (d > nb[0] * (1 + REL)) | (d > nb[1] * (1 + REL))
        thin |= side[-1] & side[1] & (d > 0)
    thin = _dilate(thin)
    lo, hi = d.copy(), d.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            n = _shift(d, dy, dx, np.nan)
            lo, hi = np.fmin(lo, n), np.fmax(hi, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        edges = np.where(lo <= 0, hi > 0, hi / lo > 1 + REL) & ~thin
    ref = seq["reference"][t].astype(np.float32)
    hdr = _dilate(ref.max(-1) > HDR)
    dis = np.zeros((H, W), bool)
    if t > 0 and not seq["reset"][t]:
        dis = metrics.disocclusion_mask(seq["depth"][t - 1], seq["depth"][t],
                                        seq["motion"][t], (H, W))
    m1, m2 = np.zeros((H, W, 3)), np.zeros((H, W, 3))
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            n = _shift(ref_display, dy, dx, 0.0)
            m1, m2 = m1 + n, m2 + n * n
    std = np.sqrt(np.maximum(m2 / 9 - (m1 / 9) ** 2, 0)).mean(-1)
    rest = ~(dis | thin | edges | hdr)
    return {"disocclusion": dis, "thin": thin, "edges": edges, "hdr": hdr,
            "texture": rest & (std >= TEXTURE_STD), "flat": rest & (std < TEXTURE_STD),
            "all": np.ones((H, W), bool)}


class Recorder:
    """A method's runner that also adds its frames' squared errors per region."""

    def __init__(self, runner, acc):
        self.runner, self.acc = runner, acc
        self.up = getattr(runner, "up", None)

    def __call__(self, seq, t):
        out = self.runner(seq, t)
        if t in seq["_masks"]:
            d2 = (metrics.display(out) - seq["_ref"][t]) ** 2
            for r, m in seq["_masks"][t].items():
                self.acc[r] += float(d2[m].sum())
        return out


def report(methods, sse, count, records, json_path, meta):
    """Print the eval's mean table and the region table; write the JSON."""
    result = {"sequences": records}
    if len(records) > 1:
        result["mean"] = ev.mean_over_sequences(records)
        print(f"\nmean over {len(records)} sequences")
        print(ev.format_table(result["mean"]))
    table = {m: {r: (10 * np.log10(count[r] / sse[m][r]) if sse[m][r] > 0 else None)
                 for r in REGIONS} for m in methods}
    share = {r: count[r] / count["all"] for r in REGIONS}
    w = max(len(m) for m in methods) + 2
    print("\nregion PSNR dB (minus clss-rules')" if "clss-rules" in methods else "\nregion PSNR dB")
    print("region".ljust(14) + "".join(f"{m:>{w + 8}s}" for m in methods) + "   share")
    for r in REGIONS:
        cells = []
        for m in methods:
            v = table[m][r]
            base = table.get("clss-rules", {}).get(r)
            cells.append(f"{v:.2f}" + (f" ({v - base:+.2f})" if base is not None and
                                        m != "clss-rules" else "") if v is not None else "-")
        print(r.ljust(14) + "".join(f"{c:>{w + 8}s}" for c in cells) + f"   {share[r]:.3f}")
    if json_path:
        with open(json_path, "w") as f:
            json.dump(dict(meta, regions=table, share=share, sse=sse, count=count,
                           methods=methods, thresholds={"rel_depth": REL, "hdr": HDR,
                                                        "texture_std": TEXTURE_STD},
                           eval=result), f, indent=1, default=ev._jsonable)


def merge(paths, json_path):
    runs = [json.load(open(p)) for p in paths]
    methods = runs[0]["methods"]
    sse = {m: {r: sum(x["sse"][m][r] for x in runs) for r in REGIONS} for m in methods}
    count = {r: sum(x["count"][r] for x in runs) for r in REGIONS}
    records = [rec for x in runs for rec in x["eval"]["sequences"]]
    report(methods, sse, count, records, json_path,
           {"sequences": [s for x in runs for s in x["sequences"]], "warmup": runs[0]["warmup"],
            "merged": list(paths)})
    return 0


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("seqs", nargs="+")
    p.add_argument("--merge", action="store_true", help="SEQS are JSON files of this study")
    p.add_argument("--methods", default="bicubic,jbicubic,clss-rules,clss,mlp,nsrr,nss,nsrd")
    p.add_argument("--warmup", type=int, default=4)
    p.add_argument("--flip-every", type=int, default=4)
    p.add_argument("--out", default=None, help="the eval's pictures (default: none)")
    p.add_argument("--json", default=None)
    p.add_argument("--weights", default=None, help="the weights of the one method with weights "
                   "among --methods (default: the package's)")
    a = p.parse_args(argv)
    if a.merge:
        return merge(a.seqs, a.json)
    methods = ev.canonical_methods(a.methods.split(","))
    net_kwargs, _ = ev.method_kwargs(a.weights, methods)
    dev = get_device(None)
    sse = {m: {r: 0.0 for r in REGIONS} for m in methods}
    count = {r: 0 for r in REGIONS}
    records = []
    for path in a.seqs:
        seq = ev.load_sequence(path)
        these = [m for m in methods if not ev.missing_gbuffers(m, seq)]
        scored = ev.scored_frames(seq["reset"], a.warmup)
        seq["_ref"] = {t: metrics.display(seq["reference"][t]) for t in scored}
        seq["_masks"] = {t: masks(seq, t, seq["_ref"][t]) for t in scored}
        for ms in seq["_masks"].values():
            for r, m in ms.items():
                count[r] += int(m.sum()) * 3
        run = {m: Recorder(ev.make_method(m, seq, dev, net_kwargs=net_kwargs), sse[m])
               for m in these}
        rec = ev.evaluate_sequence(seq, these, dev, warmup=a.warmup, out_dir=a.out,
                                   flip_every=a.flip_every, run=run)
        rec["name"] = seq["name"]
        records.append(rec)
        print(f"\n{seq['name']}: {len(scored)} scored frames")
        print(ev.format_table(rec["methods"]), flush=True)
    report(methods, sse, count, records, a.json, {"sequences": a.seqs, "warmup": a.warmup,
                                                  "weights": a.weights})
    return 0


if __name__ == "__main__":
    sys.exit(main())
