"""python -m weights_tools classifier SEQ.npz ...: how well CLSS's classifier classifies,
against the generator's labels and against rule detectors that any trained classifier must
beat (issue 23).

For every labelled sequence (DATA.md `label_ghost`, `label_alias`) the net frame step runs
through its torch twin (held to clss.Upscaler by tests/test_torch_twin.py); on the pixels
where the classifier's decision matters (history valid: on screen, not a reset frame) it
scores each head by balanced accuracy (the mean of the per-class recalls; chance is 1/3)
and prints the confusion matrices. Beside it, rule detectors on frames t and t-1, their
thresholds picked on the first half of the sequences and scored on the second half:

  ghosting  visibility where the pixel reprojected into frame t-1 (p + motion, nearest
            sample) is off screen or lands on a view depth more than `vis` (relative) away
            (clss.metrics.disocclusion_mask); otherwise shading where the tone-mapped colour
            at the reprojected pixel differs by more than `shade` (largest channel);
            otherwise none.
  aliasing  geometry where the view depth jumps by more than `geo` (relative) inside the
            2x2 render samples starting at the pixel; otherwise texture where the tone-mapped
            luminance of the 3x3 render neighbourhood spans more than `tex`; otherwise none.

The ghosting head is also scored against the labels that `train --ghost-labels useful`
trains on (visibility where the frame step's clipped history is further from the reference
than the current upsample; the generator's shading, else none), made in the same run.

Rule detectors see the previous frame's true depth, which the frame step keeps since issue 23
(before, it rebuilt the previous depth from the current one and the motion). The numbers
are the floor under the classifier, and the bound that half-resolution logits put on it (the
best constant per 2x2 output block) is printed as the ceiling.
"""
from __future__ import annotations

import argparse
import itertools
import json
import os
import sys

import numpy as np

from clss.io import tonemap
from clss.metrics import disocclusion_mask, nearest

LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)
GHOST_NAMES = ("visibility", "shading", "none")
# the useful labels as `train --ghost-labels useful` makes them by default
USEFUL_RATIO, USEFUL_FLOOR = 2.0, 1e-3
ALIAS_NAMES = ("geometry", "texture", "none")
GRID = {"vis": (0.02, 0.05, 0.1, 0.2, 0.3), "shade": (0.01, 0.02, 0.04, 0.08),
        "geo": (0.05, 0.1, 0.2, 0.4), "tex": (0.01, 0.02, 0.04, 0.08)}


def balanced_accuracy(pred, label, n=3):
    """(mean recall over the classes present, confusion [label, pred] counts)."""
    conf = np.bincount(label.astype(np.int64) * n + pred.astype(np.int64),
                       minlength=n * n).reshape(n, n)
    rows = conf.sum(1)
    present = rows > 0
    return float(np.mean(np.diag(conf)[present] / rows[present])), conf


def rule_ghost(seq, t, out_hw, vis, shade):
    """Rule ghosting classes H x W (0 visibility, 1 shading, 2 none) of frame t."""
    h, w = seq["depth"].shape[1:3]
    v = disocclusion_mask(seq["depth"][t - 1], seq["depth"][t], seq["motion"][t], (h, w), vis)
    ii, jj = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    pi = np.clip(np.rint(ii + seq["motion"][t][..., 1]).astype(np.int64), 0, h - 1)
    pj = np.clip(np.rint(jj + seq["motion"][t][..., 0]).astype(np.int64), 0, w - 1)
    cur = tonemap(seq["color"][t].astype(np.float32))
    prev = tonemap(seq["color"][t - 1].astype(np.float32))[pi, pj]
    s = np.abs(cur - prev).max(-1) > shade
    cls = np.where(v, 0, np.where(s, 1, 2))
    return nearest(cls, *out_hw)


def rule_alias(seq, t, out_hw, geo, tex):
    """Rule aliasing classes H x W (0 geometry, 1 texture, 2 none) of frame t."""
    d = seq["depth"][t].astype(np.float64)
    h, w = d.shape
    pad = np.pad(d, ((0, 1), (0, 1)), mode="edge")
    quad = np.stack([pad[:h, :w], pad[1:, :w], pad[:h, 1:], pad[1:, 1:]])
    hi, lo = quad.max(0), quad.min(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.where(hi > 0, (hi - lo) / np.maximum(hi, 1e-12), 0.0) > geo
    y = np.tensordot(tonemap(seq["color"][t].astype(np.float32)), LUMA, 1)
    yp = np.pad(y, 1, mode="edge")
    win = np.stack([yp[a:a + h, b:b + w] for a in range(3) for b in range(3)])
    x = (win.max(0) - win.min(0)) > tex
    return nearest(np.where(g, 0, np.where(x, 1, 2)), *out_hw)


def frames_scored(seq):
    return [t for t in range(1, len(seq["reset"])) if not seq["reset"][t]]


def run_classifier(seq, weights, device=None):
    """{t: (ghost class, alias class, valid, ghost class at the runtime margin, useful
    ghost label)} of the torch twin of the net frame step: the heads' argmax, the ghosting
    head as net mode decides it (visibility where its logit leads the others by
    contract.VIS_MARGIN, else the larger of shading and none), and the label that
    `train --ghost-labels useful` trains on by default (visibility where the clipped
    history's squared error exceeds USEFUL_RATIO x the current upsample's plus
    USEFUL_FLOOR; the generator's shading, else none)."""
    import torch
    from clss.methods.clss.contract import VIS_MARGIN, ghost_classes
    from .twin import TorchUpscaler, pq_encode
    from .recipe import useful_ghost_labels
    up = TorchUpscaler(float(seq["scale"]), "net", weights, device=device)
    out = {}
    for t in range(len(seq["reset"])):
        up.step(seq["color"][t], seq["depth"][t], seq["motion"][t], tuple(seq["jitter"][t]),
                reset=bool(seq["reset"][t]))
        r = up.last
        lg = r["logits"][0].cpu().numpy()
        at_margin = ghost_classes(lg[0:3], VIS_MARGIN)
        dev = r["up"].device
        ref = torch.from_numpy(np.ascontiguousarray(seq["reference"][t].transpose(2, 0, 1)))
        ref_pq = pq_encode(ref[None].to(dev), up.step_fn.nits)
        gen = torch.from_numpy(seq["label_ghost"][t].astype(np.int64))[None].to(dev)
        useful, _ = useful_ghost_labels(r, gen, ref_pq, USEFUL_RATIO, USEFUL_FLOOR)
        out[t] = (lg[0:3].argmax(0), lg[3:6].argmax(0), r["valid"][0, 0].cpu().numpy() > 0.5,
                  at_margin, useful[0].cpu().numpy())
    return out


def block_bound(label, valid):
    """Balanced accuracy of the best constant per 2x2 block (what half-resolution logits
    can reach at most): each block predicts its most frequent valid label."""
    H, W = label.shape
    H2, W2 = H // 2 * 2, W // 2 * 2
    lb = label[:H2, :W2].reshape(H2 // 2, 2, W2 // 2, 2).transpose(0, 2, 1, 3).reshape(-1, 4)
    vb = valid[:H2, :W2].reshape(H2 // 2, 2, W2 // 2, 2).transpose(0, 2, 1, 3).reshape(-1, 4)
    counts = np.stack([((lb == c) & vb).sum(1) for c in range(3)], 1)
    best = counts.argmax(1)
    pred = np.repeat(best[:, None], 4, 1)
    return pred[vb], lb[vb]


def report(paths, weights=None, device=None, log=sys.stderr):
    from clss.evaluate import load_sequence
    seqs = []
    for p in paths:
        seq = load_sequence(p)
        with np.load(p) as z:
            if "label_ghost" not in z.files:
                print(f"{p}: no labels, left out", file=log)
                continue
            seq["label_ghost"], seq["label_alias"] = z["label_ghost"], z["label_alias"]
        seqs.append(seq)
    if len(seqs) < 2:
        raise ValueError("classifier: needs at least 2 labelled sequences (half tune the "
                         "rule thresholds, half score them)")
    half = len(seqs) // 2
    tune, score = seqs[:half], seqs[half:]
    gathered = []            # per scored sequence: (frames, valid masks, labels, classifier)
    for seq in score:
        H, W = seq["reference"].shape[1:3]
        cl = run_classifier(seq, weights, device)
        gathered.append((seq, cl, (H, W)))
        print(f"{seq['name']}: classified", file=log, flush=True)

    def masks(seq, cl):
        return {t: cl[t][2] for t in frames_scored(seq)}

    # the rule thresholds, on the tuning half (over its valid-history pixels: reprojection
    # on screen, as the twin's `valid`; the label's own visibility is kept)
    def tune_rule(fn, keys, head):
        best = None
        for vals in itertools.product(*(GRID[k] for k in keys)):
            preds, labs = [], []
            for seq in tune:
                H, W = seq["reference"].shape[1:3]
                for t in frames_scored(seq):
                    preds.append(fn(seq, t, (H, W), *vals).ravel())
                    labs.append(seq[head][t].ravel())
            ba, _ = balanced_accuracy(np.concatenate(preds), np.concatenate(labs))
            if best is None or ba > best[0]:
                best = (ba, dict(zip(keys, vals)))
        return best[1]
    th_g = tune_rule(rule_ghost, ("vis", "shade"), "label_ghost")
    th_a = tune_rule(rule_alias, ("geo", "tex"), "label_alias")

    res = {"sequences": [s["name"] for s in score], "tuned_on": [s["name"] for s in tune],
           "thresholds": {"ghost": th_g, "alias": th_a}, "heads": {}}
    for head, names, k, rule, th in (("ghost", GHOST_NAMES, 0, rule_ghost, th_g),
                                     ("alias", ALIAS_NAMES, 1, rule_alias, th_a)):
        P, R, L, BP, BL, M = [], [], [], [], [], []
        for seq, cl, hw in gathered:
            for t, valid in masks(seq, cl).items():
                lab = seq[f"label_{head}"][t]
                P.append(cl[t][k][valid])
                M.append(cl[t][3 if k == 0 else 1][valid])
                R.append(rule(seq, t, hw, *th.values())[valid])
                L.append(lab[valid])
                bp, bl = block_bound(lab, valid)
                BP.append(bp)
                BL.append(bl)
        L = np.concatenate(L)
        res["heads"][head] = _head(names, L, {
            "classifier": (P, L), "rules": (R, L), "2x2 bound": (BP, np.concatenate(BL)),
            "classifier at margin": (M, L)})
    # the ghosting head against the labels consistent with the history it sees (`train
    # --ghost-labels useful` trains on these; no rule detector was tuned for them)
    P, M, L = [], [], []
    for seq, cl, hw in gathered:
        for t, valid in masks(seq, cl).items():
            P.append(cl[t][0][valid])
            M.append(cl[t][3][valid])
            L.append(cl[t][4][valid])
    L = np.concatenate(L)
    res["heads"]["useful"] = _head(GHOST_NAMES, L, {"classifier": (P, L),
                                                    "classifier at margin": (M, L)})
    return res


def _head(names, labels, rows):
    """One head's entry: its classes, the label frequencies of `labels`, and per row
    (name: (list of prediction arrays, the labels they are scored against)) the balanced
    accuracy and the confusion."""
    out = {"classes": list(names), "label_frequency": (
        np.bincount(labels.astype(np.int64), minlength=3) / max(len(labels), 1)).tolist()}
    for who, (preds, lab) in rows.items():
        ba, conf = balanced_accuracy(np.concatenate(preds), lab)
        out[who] = {"balanced_accuracy": ba, "confusion": conf.tolist()}
    return out


def format_report(res) -> str:
    lines = [f"scored on {len(res['sequences'])} sequences (rule thresholds tuned on "
             f"{len(res['tuned_on'])} others: ghost {res['thresholds']['ghost']}, "
             f"alias {res['thresholds']['alias']})",
             f"{'balanced accuracy':22s} {'ghosting':>9s} {'aliasing':>9s}"]
    for who in ("classifier", "classifier at margin", "rules", "2x2 bound"):
        lines.append(f"{who:22s} " + " ".join(
            f"{res['heads'][h][who]['balanced_accuracy']:9.3f}" for h in ("ghost", "alias")))
    if "useful" in res["heads"]:
        u = res["heads"]["useful"]
        lines.append(f"{'ghosting, useful labels':22s} " + " ".join(
            f"{u[who]['balanced_accuracy']:.3f} ({who})"
            for who in ("classifier", "classifier at margin")))
    for h in [k for k in ("ghost", "alias", "useful") if k in res["heads"]]:
        r = res["heads"][h]
        lines.append(f"\n{h}: label share " + ", ".join(
            f"{n} {f:.1%}" for n, f in zip(r["classes"], r["label_frequency"])))
        for who in ("classifier", "classifier at margin") if h != "alias" else ("classifier",):
            lines.append(f"  {who} confusion (rows: label, columns: predicted)")
            for n, row in zip(r["classes"], r[who]["confusion"]):
                lines.append(f"    {n:11s} " + " ".join(f"{v:9d}" for v in row))
    return "\n".join(lines)


def add_parser(sub):
    p = sub.add_parser("classifier", help="score CLSS's classifier against the labels and "
                       "rule detectors (balanced accuracy per head)",
                       description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="example:\n  python -m weights_tools classifier "
                              "out/data/heldout/*.npz --json out/classifier.json")
    p.add_argument("sequences", nargs="+", metavar="SEQ.npz")
    p.add_argument("--weights", default=None,
                   help="a .safetensors file (default: the package's trained weights)")
    p.add_argument("--device", default=None, help="torch device")
    p.add_argument("--json", default=None, help="also write the figures here")
    p.set_defaults(fn=cmd)


def cmd(a):
    import torch
    torch.set_num_threads(2)
    weights = a.weights
    if weights is None:
        from clss.methods.clss.upscaler import SHIPPED_WEIGHTS
        weights = SHIPPED_WEIGHTS
    res = report(a.sequences, weights, a.device)
    res["weights"] = os.fspath(weights)
    print(format_report(res))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(res, fh, indent=1)
    return 0
