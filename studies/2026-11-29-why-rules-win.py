"""Why the learned methods lose to clss-rules on rendered frames (issue 53, the account its
done-when asks for): three measurements per method against the rules, per set of sequences
(DATA.md format with `depth_hr`), on the display values clss.metrics scores.

  ages      PSNR of the scored frames grouped by frames since the last reset (4-7, 8-15,
            16+; frame 0 and each reset count as age 0, the eval scores from age 4): do the
            methods lose on young histories only (the game family cuts every ~12 frames)?
  lowfreq   PSNR of outputs and reference both box-averaged over 8x8 output pixels (the
            colour and brightness of areas: a tone shift or a colour cast), beside the full
            PSNR. The block means are an orthogonal projection, so the squared error splits
            exactly into a block-mean part and a within-block part: `low sh` is the
            block-mean part's share of the method's squared error, `loss lo` the share of
            its squared error beyond the rules' that lies in the block means. The
            block-mean PSNR again by block: blocks with an `hdr` pixel, `flat` blocks (90 %
            of the pixels flat), `other` (geometry, disocclusion, texture), and where the
            block-mean error beyond the rules' lies. Also the mean signed error per channel
            (bias, R G B) over the scored pixels, in linear values (as a fraction of the
            reference's mean) and in display values (x 1e-3).
  noise     frame-to-frame fluctuation on flat surfaces that stay on the same surface: the
            regions study's `flat` region of frame t (no disocclusion, thin geometry, edge or
            highlight; 3x3 std of the tone-mapped reference below 0.03), not the sky, and
            reprojected to frame t - 1 (motion, nearest) within 2 % of its depth. There each
            image X is compared with its own previous frame warped by the motion (bilinear):
            d_X = X_t - warp(X_t-1); RMS of d over those pixels, x 1e-3 display units. The
            input's (16-spp colour at render resolution: the same test on the render
            pixels whose 2x2 output block is all in the mask) says how much sample noise it
            carries; the generator's sequences are noise-free, so there d_input is what
            warping, jitter and their animated lights leave (the jitter is not compensated:
            small on flat areas; the game family's zero twin has none). `input - reference`:
            the input against the reference at its own sample points on flat surfaces, the
            same frame (input_residual): sample noise without the warp (on the generator's
            frames, aliasing). A method's `excess` is RMS(d_out - d_ref): the temporal error
            there (the house's tPSNR restricted to these pixels, warped); `own` is
            RMS(d_out), the output's own fluctuation, next to RMS(d_ref) (the 32-spp
            reference's noise plus the warp's error).

The methods run through clss.evaluate.make_method (the house's runners), the regions come
from studies/2026-11-29-regions.py (imported, one code for one logic).

    .venv/bin/python studies/2026-11-29-why-rules-win.py [--set NAME=GLOB[,GLOB]] ...
        [--methods a,b,...] [--json FILE] [--warmup 4] [--input-noise 0.1,0.3]

--input-noise scores each set again with sample-like noise added to its colour input, the
noise of studies/2026-11-29-input-perturbations.py (imported: colour times 1 + sigma N(0, 1)
per render pixel and frame, common to the channels, the reference left clean): does noise
make the networks flicker, or lose their block means, on content where they win?

A method `NAME@PATH` runs NAME with the weights file PATH (labelled NAME@<its folder>, or
its file name when the file is not called weights.safetensors). Default sets: the held-out
Blender families (interior, particles; each apart), the game family at 2x with Halton jitter
and without jitter, and the generator's held-out set (no sample noise: one point sample per
pixel of an analytic scene).
"""
from __future__ import annotations

import argparse
import glob
import importlib.util
import json
import os
import sys
import tempfile

import numpy as np
from scipy.ndimage import map_coordinates

from clss import evaluate as ev
from clss import metrics
from clss.device import get_device


def _study(name):
    """A sibling study imported as a module (its file name is no identifier)."""
    spec = importlib.util.spec_from_file_location(
        name.replace("-", "_"), os.path.join(os.path.dirname(os.path.abspath(__file__)),
                                             name + ".py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


regions = _study("2026-11-29-regions")              # the region masks
perturbations = _study("2026-11-29-input-perturbations")   # the added sample noise

AGES = ((4, 7), (8, 15), (16, 10 ** 9))
BOX = 8
BLOCKS = ("hdr", "flat", "other")   # block_class: where the block-mean error lies
SAME_SURFACE = 0.02     # relative depth change of "the same surface" for the noise test
SETS = {
    "blender-interior": "out/data/blender/test/interior_*.npz",
    "blender-particles": "out/data/blender/test/particles_*.npz",
    "game-halton": "out/data/game-salvage/blender-game/test/*.npz,"
                   "out/data/blender-game/test/*.npz",
    "game-zero": "out/data/game-salvage/blender-game-zero/test/*.npz,"
                 "out/data/blender-game-zero/test/*.npz",
    "heldout": "out/data/heldout/*.npz",
}
METHODS = "clss-rules,clss,mlp,nsrr,nsrd,nss"


def age_of(reset):
    """Frames since the last reset per frame (frame 0 is one): scored_frames' count."""
    out, since = [], 0
    for t, r in enumerate(reset):
        since = 0 if (r or t == 0) else since + 1
        out.append(since)
    return out


def bucket(age):
    for i, (lo, hi) in enumerate(AGES):
        if lo <= age <= hi:
            return i
    return None


def box(a, k=BOX):
    """k x k block means of an H x W x C image (cropped to whole blocks)."""
    H, W = a.shape[0] // k * k, a.shape[1] // k * k
    return a[:H, :W].reshape(H // k, k, W // k, k, -1).mean((1, 3))


def block_class(ms):
    """Per 8x8 block, the index into BLOCKS: `hdr` if one of its pixels is in the regions
    study's hdr region (emitters, highlights), `flat` if 90 % of its pixels are flat, else
    `other` (geometry edges, thin geometry, disocclusion, texture)."""
    hdr = box(ms["hdr"][..., None].astype(np.float32))[..., 0] > 0
    flat = box(ms["flat"][..., None].astype(np.float32))[..., 0] >= 0.9
    return np.where(hdr, 0, np.where(flat, 1, 2))


def warp(img, motion):
    """img's previous frame sampled where each pixel was (p + motion, bilinear): H x W x C,
    and the H x W mask of pixels whose source lies inside the frame."""
    H, W = img.shape[:2]
    ii, jj = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    y, x = ii + motion[..., 1], jj + motion[..., 0]
    inside = (y >= 0) & (y <= H - 1) & (x >= 0) & (x <= W - 1)
    out = np.stack([map_coordinates(img[..., c], [y, x], order=1, mode="nearest")
                    for c in range(img.shape[2])], -1)
    return out, inside


def input_residual(cin, ref, jitter, s, flat):
    """(sum of squares, count) of the input's display values minus the reference's at the
    same point (bilinear at the jittered sample position, DATA.md: sample (i, j) at
    (j + 0.5 + jx, i + 0.5 + jy) render pixels), over render pixels whose four reference
    neighbours are all in `flat`: the input's sample noise (plus the reference's, and on
    flat areas a little of the scene between output pixels)."""
    h, w = cin.shape[:2]
    H, W = ref.shape[:2]
    ii, jj = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    y = s * (ii + 0.5 + float(jitter[1])) - 0.5
    x = s * (jj + 0.5 + float(jitter[0])) - 0.5
    y0 = np.clip(np.floor(y).astype(np.int64), 0, H - 2)
    x0 = np.clip(np.floor(x).astype(np.int64), 0, W - 2)
    ok = flat[y0, x0] & flat[y0 + 1, x0] & flat[y0, x0 + 1] & flat[y0 + 1, x0 + 1]
    at = np.stack([map_coordinates(ref[..., c], [y, x], order=1, mode="nearest")
                   for c in range(3)], -1)
    d = (cin - at)[ok].astype(np.float64)
    return float((d * d).sum()), int(d.size)


def parse_method(m):
    """(label, registry name, net_kwargs) of a --methods entry NAME or NAME@PATH."""
    if "@" not in m:
        name = ev.canonical_methods([m])[0]
        return name, name, None
    name, path = m.split("@", 1)
    name = ev.canonical_methods([name])[0]
    stem = os.path.basename(path)
    tag = os.path.basename(os.path.dirname(path)) if stem == "weights.safetensors" else \
        os.path.splitext(stem)[0]
    return f"{name}@{tag}", name, {"weights": path}


class Acc:
    """One method's sums over a set."""

    def __init__(self):
        self.age_se, self.age_n = [0.0] * len(AGES), [0] * len(AGES)
        self.se = self.n = self.low_se = self.low_n = 0.0
        self.blk_se, self.blk_n = [0.0] * len(BLOCKS), [0] * len(BLOCKS)
        self.bias_lin, self.bias_disp = np.zeros(3), np.zeros(3)
        self.bias_n = 0
        self.d_own = self.d_excess = 0.0


def score_sequence(seq, runs, accs, ref_acc, warmup):
    """Run every method over seq and add its sums."""
    T = seq["color"].shape[0]
    H, W = seq["reference"].shape[1:3]
    ages = age_of(seq["reset"])
    scored = set(ev.scored_frames(seq["reset"], warmup))
    s = seq["scale"]
    prev = None                 # display values of frame t - 1: {label: ..., "ref", "in"}
    for t in range(T):
        outs = {lab: metrics.display(run(seq, t)) for lab, run in runs.items()}
        ref_lin = seq["reference"][t].astype(np.float64)
        ref = metrics.display(seq["reference"][t])
        cin = metrics.display(seq["color"][t])
        if t in scored:
            b = bucket(ages[t])
            ref_box = box(ref)
            ms = regions.masks(seq, t, ref)
            cls = block_class(ms)
            for lab, o in outs.items():
                a = accs[lab]
                d2 = float(((o - ref) ** 2).sum())
                a.se += d2
                a.n += o.size
                a.age_se[b] += d2
                a.age_n[b] += o.size
                low = ((box(o) - ref_box) ** 2).sum(-1) * BOX * BOX
                a.low_se += float(low.sum())
                a.low_n += ref_box.size * BOX * BOX
                for c in range(len(BLOCKS)):
                    a.blk_se[c] += float(low[cls == c].sum())
                    a.blk_n[c] += int((cls == c).sum()) * 3 * BOX * BOX
                a.bias_disp += (o - ref).reshape(-1, 3).sum(0)
                a.bias_n += H * W
            ref_acc["ref_mean"] += ref_lin.reshape(-1, 3).sum(0)
            ref_acc["ref_n"] += H * W
            flat = ms["flat"] & (seq["gbuffers"]["depth_hr"][t] > 0)
            if prev is not None and not seq["reset"][t]:
                same = ~metrics.disocclusion_mask(seq["depth"][t - 1], seq["depth"][t],
                                                  seq["motion"][t], (H, W), SAME_SURFACE)
                m_hr = metrics.nearest(seq["motion"][t], H, W) * s
                ref_w, inside = warp(prev["ref"], m_hr)
                mask = flat & same & inside
                d_ref = (ref - ref_w)[mask]
                ref_acc["d_ref"] += float((d_ref ** 2).sum())
                ref_acc["d_n"] += d_ref.size
                for lab, o in outs.items():
                    d = (o - warp(prev[lab], m_hr)[0])[mask]
                    accs[lab].d_own += float((d ** 2).sum())
                    accs[lab].d_excess += float(((d - d_ref) ** 2).sum())
                h, w = cin.shape[:2]
                blk = mask[:h * 2, :w * 2].reshape(h, 2, w, 2).all((1, 3)) if s == 2 else \
                    metrics.nearest(mask, h, w)
                cin_w, inside_lr = warp(prev["in"], seq["motion"][t])
                d_in = (cin - cin_w)[blk & inside_lr]
                ref_acc["d_in"] += float((d_in ** 2).sum())
                ref_acc["d_in_n"] += d_in.size
            r, n = input_residual(cin, ref, seq["jitter"][t], s, flat)
            ref_acc["r_in"] += r
            ref_acc["r_in_n"] += n
        prev = dict(outs, ref=ref, **{"in": cin})


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--set", action="append", default=None,
                   help="NAME=GLOB[,GLOB] (repeat; default: " + ", ".join(SETS) + ")")
    p.add_argument("--methods", default=METHODS)
    p.add_argument("--warmup", type=int, default=4)
    p.add_argument("--input-noise", default="0",
                   help="comma-separated sigmas: each set scored with that much sample-like "
                        "noise in its colour input (the input-perturbations study's: colour "
                        "times 1 + sigma N(0, 1) per render pixel; 0: as is)")
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    sets = dict(x.split("=", 1) for x in a.set) if a.set else SETS
    methods = [parse_method(m) for m in a.methods.split(",")]
    sigmas = [float(v) for v in a.input_noise.split(",")]
    dev = get_device(None)
    result = {"methods": [m[0] for m in methods], "warmup": a.warmup, "ages": AGES,
              "box": BOX, "same_surface": SAME_SURFACE, "sets": {}}
    for set_name, pattern in sets.items():
        paths = sorted(p for g in pattern.split(",") for p in glob.glob(g))
        for sigma in sigmas:
            name = set_name if sigma == 0 else f"{set_name}+noise{sigma:g}"
            accs = {lab: Acc() for lab, _, _ in methods}
            ref_acc = {"ref_mean": np.zeros(3), "ref_n": 0, "d_ref": 0.0, "d_n": 0,
                       "d_in": 0.0, "d_in_n": 0, "r_in": 0.0, "r_in_n": 0}
            tmp = tempfile.TemporaryDirectory()
            these = perturbations.perturb(paths, "noise", sigma, tmp.name) if sigma else paths
            for path in these:
                seq = ev.load_sequence(path)
                runs = {lab: ev.make_method(m, seq, dev, net_kwargs=kw)
                        for lab, m, kw in methods if not ev.missing_gbuffers(m, seq)}
                lin = LinearBias(runs, accs, set(ev.scored_frames(seq["reset"], a.warmup)))
                score_sequence(seq, lin.wrapped(), accs, ref_acc, a.warmup)
                print(f"{name}: {seq['name']} done", file=sys.stderr, flush=True)
            tmp.cleanup()
            result["sets"][name] = dict(summarise(name, paths, accs, ref_acc),
                                        input_noise=sigma)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(result, f, indent=1, default=ev._jsonable)
    return 0


class LinearBias:
    """The runners wrapped so that each scored frame's linear signed error is added (the
    display values score_sequence sees are the tone-mapped outputs)."""

    def __init__(self, runs, accs, scored):
        self.runs, self.accs, self.scored = runs, accs, scored

    def wrapped(self):
        def wrap(lab, run):
            def f(seq, t):
                out = run(seq, t)
                if t in self.scored:
                    d = out.astype(np.float64) - seq["reference"][t].astype(np.float64)
                    self.accs[lab].bias_lin += d.reshape(-1, 3).sum(0)
                return out
            return f
        return {lab: wrap(lab, run) for lab, run in self.runs.items()}


def _db(se, n):
    return 10 * np.log10(n / se) if se > 0 and n > 0 else None


def summarise(name, paths, accs, ref_acc):
    """The set's figures (dict) and their printed tables."""
    ref_mean = ref_acc["ref_mean"] / max(ref_acc["ref_n"], 1)
    rows = {}
    for lab, a in accs.items():
        if a.n == 0:
            continue
        rows[lab] = {
            "psnr": _db(a.se, a.n),
            "ages": [_db(se, n) for se, n in zip(a.age_se, a.age_n)],
            "age_pixels": a.age_n,
            "psnr_low": _db(a.low_se, a.low_n),
            "low_share": a.low_se / a.low_n / (a.se / a.n) if a.se > 0 else None,
            "psnr_low_blocks": {b: _db(se, n) for b, se, n in zip(BLOCKS, a.blk_se, a.blk_n)},
            "block_shares": {b: n / a.low_n for b, n in zip(BLOCKS, a.blk_n)},
            "bias_linear_rel": (a.bias_lin / a.bias_n / ref_mean).tolist(),
            "bias_display": (a.bias_disp / a.bias_n).tolist(),
            "noise_own": float(np.sqrt(a.d_own / ref_acc["d_n"])) if ref_acc["d_n"] else None,
            "noise_excess": float(np.sqrt(a.d_excess / ref_acc["d_n"])) if ref_acc["d_n"]
            else None}
    out = {"sequences": paths, "methods": rows, "reference_mean_linear": ref_mean.tolist(),
           "noise_ref": float(np.sqrt(ref_acc["d_ref"] / ref_acc["d_n"])) if ref_acc["d_n"]
           else None,
           "noise_input": float(np.sqrt(ref_acc["d_in"] / ref_acc["d_in_n"]))
           if ref_acc["d_in_n"] else None,
           "noise_pixels": ref_acc["d_n"] // 3, "noise_input_pixels": ref_acc["d_in_n"] // 3,
           "input_residual": float(np.sqrt(ref_acc["r_in"] / ref_acc["r_in_n"]))
           if ref_acc["r_in_n"] else None, "input_residual_pixels": ref_acc["r_in_n"] // 3}
    base = rows.get("clss-rules")
    if base is not None:
        ra = accs["clss-rules"]
        for lab, r in rows.items():
            a = accs[lab]
            extra = a.se / a.n - ra.se / ra.n
            r["extra_low_share"] = ((a.low_se / a.low_n - ra.low_se / ra.low_n) / extra
                                    if lab != "clss-rules" and extra > 0 else None)
            # the block-mean squared error beyond the rules' by block class, as shares
            xs = [x - y for x, y in zip(a.blk_se, ra.blk_se)]
            tot = a.low_se - ra.low_se
            r["extra_low_by_block"] = ({b: x / tot for b, x in zip(BLOCKS, xs)}
                                       if lab != "clss-rules" and tot > 0 else None)

    def rel(v, b):
        return "-" if v is None else (f"{v:.2f}" if b is None or v is b else f"{v - b:+.2f}")

    print(f"\n== {name}: {len(paths)} sequences; PSNR dB (others minus clss-rules')")
    ages = " ".join(f"{f'age {lo}-{hi}' if hi < 10 ** 9 else f'age {lo}+':>9s}"
                    for lo, hi in AGES)
    print(f"{'method':22s} {'all':>7s} {ages} {'8x8 low':>8s} {'low sh':>7s} {'loss lo':>7s}  "
          f"bias lin % (R G B)     bias disp e-3 (R G B)")
    for lab, r in rows.items():
        b = base if base is not None else {}
        cells = [rel(r["psnr"], b.get("psnr") if lab != "clss-rules" else None)]
        cells += [rel(v, (b.get("ages") or [None] * 3)[i] if lab != "clss-rules" else None)
                  for i, v in enumerate(r["ages"])]
        cells += [rel(r["psnr_low"], b.get("psnr_low") if lab != "clss-rules" else None)]
        lo = "-" if r.get("extra_low_share") is None else f"{r['extra_low_share']:.2f}"
        bl = " ".join(f"{100 * v:+5.1f}" for v in r["bias_linear_rel"])
        bd = " ".join(f"{1e3 * v:+5.1f}" for v in r["bias_display"])
        print(f"{lab:22s} {cells[0]:>7s} " + " ".join(f"{c:>9s}" for c in cells[1:4]) +
              f" {cells[4]:>8s} {r['low_share']:7.2f} {lo:>7s}  {bl}   {bd}")
    print(f"age pixels (per method): {rows[next(iter(rows))]['age_pixels']}")
    first = rows[next(iter(rows))]
    print("8x8 block-mean PSNR by block (" + ", ".join(
        f"{b} {first['block_shares'][b]:.2f}" for b in BLOCKS) + " of the blocks); "
        "others minus clss-rules'")
    for lab, r in rows.items():
        cells = [rel(r["psnr_low_blocks"][b], (base or {}).get("psnr_low_blocks", {}).get(b)
                     if lab != "clss-rules" else None) for b in BLOCKS]
        x = r.get("extra_low_by_block")
        print(f"  {lab:22s} " + " ".join(f"{c:>7s}" for c in cells) +
              ("" if x is None else "   extra block-mean error: " +
               ", ".join(f"{b} {100 * x[b]:.0f} %" for b in BLOCKS)))
    print(f"noise on flat same-surface pixels (RMS of X_t - warp(X_t-1), 1e-3 display): "
          f"input {1e3 * (out['noise_input'] or 0):.1f} ({out['noise_input_pixels']} render "
          f"px), reference {1e3 * (out['noise_ref'] or 0):.1f} ({out['noise_pixels']} px)")
    print(f"input minus reference at its sample positions, flat surfaces (RMS, 1e-3 "
          f"display): {1e3 * (out['input_residual'] or 0):.1f} "
          f"({out['input_residual_pixels']} render px over the scored frames)")
    for lab, r in rows.items():
        print(f"  {lab:22s} own {1e3 * r['noise_own']:6.1f}   excess "
              f"{1e3 * r['noise_excess']:6.1f}")
    sys.stdout.flush()
    return out


if __name__ == "__main__":
    sys.exit(main())
