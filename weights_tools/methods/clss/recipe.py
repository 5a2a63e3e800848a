"""python -m weights_tools train: the CLSS networks trained as the paper does (s3.4, s4).

    python -m weights_tools train --data /work/data/train --out runs/a --seed 0 \
        [--heldout /work/data/heldout] [--cls-steps N] [--comp-steps N] [--resume]

Data: the DATA.md sequences (*.npz) in --data.  The recipe, with the choices the paper
leaves open (ours, marked *):

* Patches (s4): windows of --frames (8) consecutive frames and --patch x --patch output
  pixels (*64 by default: the paper's 256 does not fit the time budget on 2 cores; a
  patch is cut at the same place at render and output resolution, which needs an integer
  scale).  --candidates random windows are drawn, scored by the fraction of their
  pixels labelled ghosting or aliasing, and the top --keep (25 %) kept.  The first frame
  of a window is a reset, as are the data's own cuts.
* Recurrent training: every step runs the whole window through the torch twin of the
  frame step (twin.FrameStep), the state carried with gradients (BPTT over all
  frames); the loss is applied to every frame.  *Pixels whose history is invalid (reset,
  or motion leaving the patch) carry no loss: the pipeline overrides every decision
  there, so they only add noise.
* Stage 1, classifier, with the paper's rule-based composition (w = 1/(1+counter), 1 on
  ghosts): per-pixel cross-entropy on the ghosting head (logits 0-2) and the aliasing
  head (3-5), each class weighted by the inverse of its frequency over the selected
  patches' pixels that carry the loss (*--class-weights valid; `all` counts every pixel),
  normalised so the mean pixel weight is 1 (*the ratio between the largest and smallest
  weight capped at CLASS_WEIGHT_RATIO).  *The paper gives false-positive ghosting in
  aliasing regions the predicted ghosting class's weight (s3.4); --false-ghost-weight
  does, off by default: two thirds of the visibility pixels lie on geometry edges, and
  that penalty kept the head's visibility recall at 16 % (79 % without; issue 23).
  *Each frame's loss trains only that frame's pass (--cls-detach, default): the state is
  carried from frame to frame, its gradient is not.  *The output conv starts at zero.
* Stage 2, composition, classifier frozen: composition done twice per frame, the rule
  blend's colour history feeds the classifier, the network's blend (current colour and
  clipped history, as at run time) makes the output and its own history; recurrent, the
  state carried with gradients.  Losses (each averaged over its pixels over the whole
  window, then summed): L1 between the blend weight and 1/(1+counter) on geometry-aliasing
  pixels the classifier got right; nothing on misclassified aliasing or false-positive
  aliasing; L1 between output and reference in the PQ domain on the rest.
* Both stages run the frame step with net mode's visibility margin (--vis-margin,
  contract.VIS_MARGIN) and train on the normalised input basis (--basis, default).
* *A study, not the recipe: --ghost-labels useful / cost replaces the generator's
  ghosting labels by the pixels where the frame step's clipped history is further from
  the reference than the current upsample (useful_ghost_labels), the classifier stage
  then clipping as the runtime does, without ghosting class weights; `cost` also weighs
  each pixel by what the decision changes.  Known, that decision is worth +1.2 dB; learned,
  it reached 0.51-0.58 balanced accuracy on those labels and no gain (docs/training.md,
  2026-11-26).
* Optimiser: *Adam (the paper used Ranger, lr 5e-4 over 180 + 120 epochs): 1200
  classifier steps at 2e-3 (--cls-lr), 1200 composition steps at 1e-3 (--lr), because the
  budget here is minutes; cosine decay to 10 % over each stage; batches drawn from a
  generator seeded by (seed, stage, step), so a resumed run draws the same batches as an
  uninterrupted one.
* Network widths: clss.networks defaults (16, 32, 64, 128; MLP 32).
* *The rules' base (--base rules; issue 53, clss.methods.clss.networks.BASES): the frame
  step keeps clss-rules' decision (the depth test) and cap (4), and the composition MLP
  corrects the rules' weight 1/(1+n) in the logit domain, w = 1/(1 + n exp(-z)).  From an
  --init of the paper's form the MLP's last layer starts at zero (z = 0: exactly
  clss-rules), its first layer as trained; an --init that already has the rules' base goes
  on from its weights.  Meant with --cls-steps 0 (the classifier kept: its logits are MLP
  inputs).  The written file carries {"base": "rules"} (networks.CONFIG_KEY).

The loop (weights_tools/trainloop.py): progress lines every few seconds, loss.png
(matplotlib) refreshed as it goes, a checkpoint (checkpoint.pt, torch's weights_only
format) every minute and at the end of each stage; --resume continues from it.  The
result: weights.safetensors in --out (the names of clss.networks;
`clss.Upscaler(mode="net", weights=PATH)` runs it) and train.json (settings, class
weights, per-step times, losses, held-out PSNR).
"""
from __future__ import annotations

import argparse
import glob
import math
import os

import numpy as np
import torch

from weights_tools.methods import Recipe
from . import twin
from weights_tools.trainloop import Run, TrainError
from weights_tools.trainloop import add_arguments as add_run_arguments
from weights_tools.trainloop import load_sequences as _load_sequences
from clss.networks import load_weights
from clss.methods.clss.networks import BASES, base_of, read_config, save_networks
from clss.methods.clss.contract import VIS_MARGIN

CLASS_WEIGHT_RATIO = 100.0
GHOST_VISIBILITY, GHOST_NONE, ALIAS_GEOMETRY, ALIAS_NONE = 0, 2, 0, 2
STAGES = ("classifier", "composition")


# ---- data --------------------------------------------------------------------------------

REQUIRED = ("color", "depth", "motion", "jitter", "reset", "reference", "scale")
LABELS = ("label_ghost", "label_alias")


def load_sequences(data_dir, frames, labels_needed=True):
    """The DATA.md sequences of `data_dir` with at least `frames` frames, as dicts of
    arrays (reference PQ-encoded in float16 to halve the memory). Sequences without the
    generator's labels (Blender shards) are refused when `labels_needed` (the classifier
    stage trains on them); otherwise they get the "none" class everywhere, which leaves the
    composition stage an L1 loss against the reference on all their pixels."""
    def prepare(s):
        with torch.no_grad():
            s["reference"] = twin.pq_encode(torch.from_numpy(s["reference"])).numpy() \
                .astype(np.float16)
        missing = [k for k in LABELS if k not in s]
        if missing and labels_needed:
            raise TrainError(f"--data: a sequence lacks {', '.join(missing)} (Blender shards "
                             "carry no labels): the classifier stage needs them; fine-tune "
                             "the composition only with --init W --cls-steps 0")
        shape = s["reference"].shape[:3]
        s.setdefault("label_ghost", np.full(shape, GHOST_NONE, np.uint8))
        s.setdefault("label_alias", np.full(shape, ALIAS_NONE, np.uint8))
    return _load_sequences(data_dir, frames, REQUIRED, prepare, optional=LABELS)


def select_patches(seqs, patch, frames, candidates, keep, rng):
    """[(seq, t0, I0, J0)] of the top `keep` fraction of `candidates` random windows by
    their share of ghosting or aliasing pixels (paper s4); I0, J0 at output resolution."""
    s = seqs[0]["scale"]
    cand, score = [], []
    for _ in range(int(candidates)):
        k = int(rng.integers(len(seqs)))
        q = seqs[k]
        T, h, w = q["depth"].shape
        ph, pw = min(patch // s, h), min(patch // s, w)
        t0 = int(rng.integers(T - frames + 1))
        i0, j0 = int(rng.integers(h - ph + 1)), int(rng.integers(w - pw + 1))
        sl = (slice(t0, t0 + frames), slice(i0 * s, (i0 + ph) * s), slice(j0 * s, (j0 + pw) * s))
        hard = (q["label_ghost"][sl] != GHOST_NONE) | (q["label_alias"][sl] != ALIAS_NONE)
        cand.append((k, t0, i0 * s, j0 * s))
        score.append(float(hard[1:].mean()))        # frame 0 of a window is a reset
    order = np.argsort(-np.asarray(score), kind="stable")
    n = max(1, int(round(len(cand) * keep)))
    return [cand[i] for i in order[:n]], float(np.mean(np.asarray(score)[order[:n]]))


def patch_size(seqs, patch):
    s = seqs[0]["scale"]
    h = min(min(q["depth"].shape[1], q["depth"].shape[2]) for q in seqs)
    ph = min(patch // s, h)
    if ph < 4:
        raise TrainError(f"--patch {patch}: less than 4 render pixels at scale {s}")
    return ph, ph * s


def make_batch(seqs, items, rsize, frames, device):
    """Tensors [T,B,...] of the windows `items` (render patch rsize x rsize)."""
    s = seqs[0]["scale"]
    R, O = rsize, rsize * s
    cols = {k: [] for k in ("color", "depth", "motion", "jitter", "reset", "reference",
                            "label_ghost", "label_alias")}
    for k, t0, I0, J0 in items:
        q = seqs[k]
        t, i0, j0 = slice(t0, t0 + frames), I0 // s, J0 // s
        r = (t, slice(i0, i0 + R), slice(j0, j0 + R))
        o = (t, slice(I0, I0 + O), slice(J0, J0 + O))
        cols["color"].append(q["color"][r].transpose(0, 3, 1, 2))
        cols["depth"].append(q["depth"][r][:, None])
        cols["motion"].append(q["motion"][r].transpose(0, 3, 1, 2))
        cols["jitter"].append(q["jitter"][t])
        reset = q["reset"][t].copy()
        reset[0] = True
        cols["reset"].append(reset)
        cols["reference"].append(q["reference"][o].transpose(0, 3, 1, 2).astype(np.float32))
        cols["label_ghost"].append(q["label_ghost"][o].astype(np.int64))
        cols["label_alias"].append(q["label_alias"][o].astype(np.int64))
    return {k: torch.from_numpy(np.ascontiguousarray(np.stack(v, 1))).to(device)
            for k, v in cols.items()}


def class_weights(seqs, items, rsize, frames, valid_only=False):
    """Inverse-frequency weights of the 3 ghosting and the 3 aliasing classes over the
    selected windows' frames 1.. (`valid_only`: only the pixels that carry the classifier
    loss, not a reset and the motion landing inside the patch: `valid` of the frame step,
    its dilation left out), normalised so the mean pixel weight is 1, max/min capped at
    CLASS_WEIGHT_RATIO.  Counting all pixels lets the off-screen ones, all labelled
    visibility and all without loss, hide how rare visibility ghosting is where the loss
    is taken (ghost weights [3.6, 2.1, 0.4] instead of [6.3, 2.0, 0.4])."""
    s = seqs[0]["scale"]
    O = rsize * s
    jj = np.arange(O, dtype=np.float32)[None, :]
    ii = np.arange(O, dtype=np.float32)[:, None]
    counts = {"ghost": np.zeros(3), "alias": np.zeros(3)}
    for k, t0, I0, J0 in items:
        q = seqs[k]
        for t in range(t0 + 1, t0 + frames):
            o = (t, slice(I0, I0 + O), slice(J0, J0 + O))
            if not valid_only:
                counts["ghost"] += np.bincount(q["label_ghost"][o].ravel(), minlength=3)[:3]
                counts["alias"] += np.bincount(q["label_alias"][o].ravel(), minlength=3)[:3]
                continue
            if q["reset"][t]:
                continue
            m = q["motion"][t, I0 // s:I0 // s + rsize, J0 // s:J0 // s + rsize] * s
            m = np.repeat(np.repeat(m, s, 0), s, 1)
            su, sv = jj + m[..., 0], ii + m[..., 1]
            on = (su >= -0.5) & (su <= O - 0.5) & (sv >= -0.5) & (sv <= O - 0.5)
            counts["ghost"] += np.bincount(q["label_ghost"][o][on], minlength=3)[:3]
            counts["alias"] += np.bincount(q["label_alias"][o][on], minlength=3)[:3]
    out = {}
    for head, c in counts.items():
        f = c / max(c.sum(), 1)
        w = 1.0 / np.maximum(f, 1e-6)
        w = np.minimum(w, w.min() * CLASS_WEIGHT_RATIO)
        w /= max((f * w).sum(), 1e-12)
        out[head] = {"frequency": f.tolist(), "weight": w.tolist()}
    return out


# ---- losses ------------------------------------------------------------------------------

def classifier_loss(logits, lg, la, valid, wg, wa, false_ghost_weight=True, cost=None):
    """Summed weighted cross-entropy of both heads over the valid pixels, and the count.
    `false_ghost_weight`: the paper's reweighting of false-positive ghosting in aliasing
    regions (below).  `cost` [B,H,W]: a per-pixel factor of the ghosting head's term."""
    import torch.nn.functional as F
    ce_g = F.cross_entropy(logits[:, 0:3], lg, reduction="none")
    ce_a = F.cross_entropy(logits[:, 3:6], la, reduction="none")
    pix_g = wg[lg]
    with torch.no_grad():
        pred_g = logits[:, 0:3].argmax(1)
        false_ghost = (la != ALIAS_NONE) & (lg == GHOST_NONE) & (pred_g != GHOST_NONE)
    # s3.4: false-positive ghosting in aliasing regions weighs as much as real ghosting.
    if false_ghost_weight:
        pix_g = torch.where(false_ghost, wg[pred_g], pix_g)
    if cost is not None:
        pix_g = pix_g * cost
    v = valid[:, 0].float()
    return ((pix_g * ce_g + wa[la] * ce_a) * v).sum(), v.sum()


def history_worse(hist, up, ref_pq, ratio, floor):
    """(mask, eh, eu), each [B,H,W]: eh and eu the squared PQ errors (summed over the
    channels) of the history and of the current upsample against the reference; the mask
    where eh > ratio x eu + floor, i.e. where dropping the history helps."""
    eh = ((hist - ref_pq) ** 2).sum(1)
    eu = ((up - ref_pq) ** 2).sum(1)
    return eh > ratio * eu + floor, eh, eu


def useful_ghost_labels(r, lg, ref_pq, ratio, floor, cost=False):
    """Ghosting labels consistent with the history the frame step blends: visibility
    where the history as blended (clipped) is worse than the current upsample
    (history_worse), the generator's shading label elsewhere, none on the rest; with
    `cost` also each pixel's weight.  The generator's visibility (the exact previous
    geometry, 1 % depth tolerance) lies mostly on edges whose clipped history beats the
    current frame: rejecting exactly those gains 0.14 dB on held-out, rejecting these 1.2
    (visibility_oracle.py beside this file, issue 23)."""
    with torch.no_grad():
        worse, eh, eu = history_worse(r["blend_hist"], r["up"], ref_pq, ratio, floor)
        rest = torch.where(lg == GHOST_VISIBILITY, torch.full_like(lg, GHOST_NONE), lg)
        lab = torch.where(worse, torch.full_like(lg, GHOST_VISIBILITY), rest)
        if not cost:
            return lab, None
        # cost-sensitive: each pixel weighs what the decision changes, |eh - eu|, over
        # the frame's mean (a flat pixel where both are right weighs nothing)
        c = (eh - eu).abs()
        v = r["valid"][:, 0]
        return lab, c / c[v].mean().clamp(min=1e-12) if bool(v.any()) else c


def composition_parts(r, lg, la, ref_pq):
    """(weight-L1 sum, count, image-L1 sum, count) of one frame (paper s3.4)."""
    valid = r["valid"][:, 0]
    pred_a = r["logits"][:, 3:6].argmax(1).detach()
    good_geo = (la == ALIAS_GEOMETRY) & (pred_a == ALIAS_GEOMETRY) & valid
    unstable = ((la != ALIAS_NONE) & (pred_a != la)) | ((la == ALIAS_NONE) & (pred_a != ALIAS_NONE))
    rest = valid & ~good_geo & ~unstable
    target_w = (1.0 / (1.0 + r["counter"][:, 0])).detach()
    lw = (r["w"][:, 0] - target_w).abs()
    li = (r["out"] - ref_pq).abs().mean(1)
    return ((lw * good_geo).sum(), good_geo.sum(), (li * rest).sum(), rest.sum())


def run_window(step, batch, stage, wg=None, wa=None, weight_loss=1.0, detach=False,
               false_ghost_weight=True, useful=None):
    """The recurrent pass over one batch of windows -> (loss, stats). `detach`: the state
    carries no gradient from one frame to the next (each frame's loss trains only that
    frame's pass).  `useful`: (ratio, floor, cost) of useful_ghost_labels, which then
    replace the generator's ghosting labels in the classifier stage."""
    T, B = batch["depth"].shape[:2]
    hist = step.initial_history(B)
    rule_color = torch.zeros_like(hist[:, 0:3]) if stage == "composition" else None
    acc = [torch.zeros((), device=hist.device) for _ in range(4)]
    prev = None
    for t in range(T):
        r = step(batch["color"][t], batch["depth"][t], batch["motion"][t], batch["jitter"][t],
                 batch["reset"][t], hist, None, rule_color, prev)
        hist, prev = r["history"], r["prev"]
        if detach:
            hist = hist.detach()
        lg, la = batch["label_ghost"][t], batch["label_alias"][t]
        if stage == "classifier":
            if useful is not None:
                ref_pq = twin.pq_encode(batch["reference"][t], step.nits)
                lg, cost = useful_ghost_labels(r, lg, ref_pq, *useful)
                v = r["valid"][:, 0]
                acc[2] = acc[2] + ((lg == GHOST_VISIBILITY) & v).sum()
                acc[3] = acc[3] + v.sum()
            s, n = classifier_loss(r["logits"], lg, la, r["valid"], wg, wa, false_ghost_weight,
                                   cost if useful is not None else None)
            acc[0], acc[1] = acc[0] + s, acc[1] + n
        else:
            rule_color = r["rule_color"]
            parts = composition_parts(r, lg, la, batch["reference"][t])
            acc = [a + p for a, p in zip(acc, parts)]
    if stage == "classifier":
        loss = acc[0] / acc[1].clamp(min=1)
        if useful is None:
            return loss, {}
        return loss, {"useful_vis_share": float(acc[2] / acc[3].clamp(min=1))}
    lw = acc[0] / acc[1].clamp(min=1)
    li = acc[2] / acc[3].clamp(min=1)
    return weight_loss * lw + li, {"weight_l1": float(lw.detach()), "image_l1": float(li.detach())}


# ---- the run -----------------------------------------------------------------------------

def psnr_table(data_dir, tensors, max_sequences=4, warmup=2, device="cpu", base="paper"):
    """PSNR (PQ domain, frames after `warmup` following a reset) of rules and net (the
    trained `tensors`) on up to `max_sequences` held-out sequences: a sanity check, the
    evaluation command is the real measure."""
    rows = []
    paths = sorted(glob.glob(os.path.join(data_dir, "*.npz")))[:max_sequences]
    for p in paths:
        z = np.load(p, allow_pickle=False)
        row = {"sequence": os.path.basename(p)}
        for mode in ("rules", "net"):
            up = twin.TorchUpscaler(float(z["scale"]), mode, tensors if mode == "net"
                                           else None, device=device,
                                    base=base if mode == "net" else None)
            se, n, since = 0.0, 0, 0
            for t in range(len(z["depth"])):
                since = 0 if z["reset"][t] else since + 1
                out = up.step(z["color"][t], z["depth"][t], z["motion"][t],
                              tuple(z["jitter"][t]), reset=bool(z["reset"][t]))
                if since >= warmup:
                    with torch.no_grad():
                        a = twin.pq_encode(torch.from_numpy(out))
                        b = twin.pq_encode(torch.from_numpy(z["reference"][t]))
                    se += float(((a - b) ** 2).mean())
                    n += 1
            row[mode] = 10 * math.log10(1.0 / max(se / max(n, 1), 1e-12))
        rows.append(row)
    return rows


def export_checkpoint(out_dir, base="paper"):
    """weights.safetensors from --out/checkpoint.pt as it stands (an unfinished run's
    networks: e.g. the classifier done and the composition part-trained)."""
    ckpt_path = os.path.join(out_dir, "checkpoint.pt")
    if not os.path.isfile(ckpt_path):
        raise TrainError(f"--export: no checkpoint.pt in {out_dir}")
    ck = torch.load(ckpt_path, weights_only=True)
    if "models" not in ck:
        raise TrainError(f"--export: {ckpt_path} was written by an older version of the recipe")
    sd_cls, sd_comp = ck["models"]["cls"], ck["models"]["comp"]
    widths = tuple(int(sd_cls[f"{n}.weight"].shape[0])
                   for n in ("stem", "down.0", "down.1", "down.2"))
    cls = twin.Classifier(widths)
    comp = twin.Composition(int(sd_comp["mlp.0.weight"].shape[0]))
    if "basis.A" in sd_cls:
        twin.use_basis(cls, comp)
    cls.load_state_dict(sd_cls)
    comp.load_state_dict(sd_comp)
    out_path = os.path.join(out_dir, "weights.safetensors")
    save_networks(twin.tensors_from_networks(cls, comp), out_path, {"base": base})
    print(f"wrote {out_path} from the checkpoint (written at {STAGES[ck['stage']]} step "
          f"{ck['step']})")
    return 0


def train(args):
    run = Run(args, STAGES)
    device = twin.pick_device(args.device)
    seqs = load_sequences(args.data, args.frames, labels_needed=args.cls_steps > 0)
    rsize, osize = patch_size(seqs, args.patch)
    rng = np.random.default_rng([args.seed, 0])
    items, mean_score = select_patches(seqs, osize, args.frames, args.candidates, args.keep, rng)
    cw = class_weights(seqs, items, rsize, args.frames, args.class_weights == "valid")
    print(f"{len(seqs)} sequences, {len(items)} patches of {args.frames} x {osize}x{osize} "
          f"(top {args.keep:.0%} of {args.candidates}, mean ghost/alias share {mean_score:.2f}); "
          f"class weights ghost {np.round(cw['ghost']['weight'], 2).tolist()} "
          f"alias {np.round(cw['alias']['weight'], 2).tolist()}", flush=True)
    # useful labels: no class weights on the ghosting head, whose probabilities then stay
    # calibrated (the generator's visibility frequency says nothing of the useful one's)
    wg = torch.tensor([1.0, 1.0, 1.0] if args.ghost_labels != "generator" else cw["ghost"]["weight"],
                      dtype=torch.float32, device=device)
    wa = torch.tensor(cw["alias"]["weight"], dtype=torch.float32, device=device)

    init = load_weights(args.init) if args.init else None
    cls, comp = twin.networks_from_tensors(init, seed=args.seed)
    if args.base == "rules" and (init is None or base_of(read_config(args.init)) != "rules"):
        # the rules' base: the correction starts at zero, the frame step at clss-rules
        with torch.no_grad():
            comp.mlp[2].weight.zero_()
            comp.mlp[2].bias.zero_()
    if init is None:
        # the classifier's output conv starts at zero: its first logits are its biases'
        # (near uniform), not noise that Adam removes most cheaply by silencing the
        # ReLUs before it (the dead-unit failure NSRR's U-Net had, issue 20)
        with torch.no_grad():
            cls.dec[-1].weight.zero_()
    if args.basis:
        twin.use_basis(cls, comp)
    if args.comp_no_logits:
        # the composition ignores the classifier's logits: their first-layer columns held
        # at zero (the basis maps each logit to itself, so the raw columns stay zero too)
        from clss.methods.clss.networks import COMPOSITION_INPUTS, channel_slices
        lg = channel_slices(COMPOSITION_INPUTS)["logits"]
        w = comp.mlp[0].weight
        with torch.no_grad():
            w[:, lg].zero_()
        mask = torch.ones_like(w)
        mask[:, lg] = 0.0
        w.register_hook(lambda g: g * mask)
    cls, comp = cls.to(device).to(memory_format=torch.channels_last), comp.to(device)
    run.track(cls=cls, comp=comp)
    run.log.update(patches=len(items), patch_output_px=osize, class_weights=cw)
    steps = {"classifier": int(args.cls_steps), "composition": int(args.comp_steps)}

    useful = ((args.useful_ratio, args.useful_floor, args.ghost_labels == "cost")
              if args.ghost_labels in ("useful", "cost") else None)
    for stage in STAGES:
        if not run.todo(stage, steps[stage]):
            continue
        train_cls = stage == "classifier"
        cls.requires_grad_(train_cls)
        comp.requires_grad_(not train_cls)
        cls.train(train_cls)
        step = twin.FrameStep("net", (rsize, rsize), float(seqs[0]["scale"]), cls,
                              None if train_cls else comp,
                              blend="rule" if train_cls else "net",
                              clip=not train_cls or args.ghost_labels != "generator",
                              cap=args.cap, vis_margin=args.vis_margin,
                              base=args.base).to(device)

        def loss(it, stage=stage, step=step):
            g = run.step_rng(stage, it)
            pick = g.choice(len(items), size=min(args.batch, len(items)), replace=False)
            batch = make_batch(seqs, [items[i] for i in pick], rsize, args.frames, device)
            return run_window(step, batch, stage, wg, wa, args.weight_loss,
                              detach=stage == "classifier" and args.cls_detach,
                              false_ghost_weight=args.false_ghost_weight, useful=useful)
        run.fit(stage, (cls if train_cls else comp).parameters(), steps=steps[stage], loss=loss,
                lr=args.cls_lr if train_cls else args.lr)

    tensors = twin.tensors_from_networks(cls, comp)
    out_path = os.path.join(args.out, "weights.safetensors")
    save_networks(tensors, out_path, {"base": args.base})
    print(f"wrote {out_path}", flush=True)
    if args.heldout:
        rows = psnr_table(args.heldout, tensors, device=device, base=args.base)
        run.log["heldout_psnr_pq"] = rows
        print("held-out PSNR (PQ domain, dB)   rules     net")
        for r in rows:
            print(f"  {r['sequence']:28s} {r['rules']:8.2f} {r['net']:8.2f}")
        if rows:
            print(f"  {'mean':28s} {np.mean([r['rules'] for r in rows]):8.2f} "
                  f"{np.mean([r['net'] for r in rows]):8.2f}", flush=True)
    run.write_log()
    return 0


def add_arguments(t):
    """The CLSS recipe's options (`train clss ...`)."""
    t.add_argument("--data", required=True, help="a directory of DATA.md .npz sequences"
                   "; or a mix DIR[:SHARE],... (weights_tools/DATA.md)")
    add_run_arguments(t, threads=2)
    # Defaults: the shipped recipe (issue 23), about 12 minutes of steps per seed on one
    # thread of this 2-core machine. 1200 composition steps instead of 400 gave, from the
    # same classifier, +0.03 / +0.21 / -0.11 / +0.17 dB on val / held-out / foliage /
    # interior (docs/training.md).
    t.add_argument("--cls-steps", type=int, default=1200, help="classifier steps")
    t.add_argument("--comp-steps", type=int, default=1200, help="composition steps")
    t.add_argument("--class-weights", choices=("all", "valid"), default="valid",
                   help="count the class frequencies over all pixels of the selected windows "
                        "(all) or over the pixels that carry the loss (valid, the shipped "
                        "recipe: not a reset, motion inside the patch)")
    t.add_argument("--basis", action=argparse.BooleanOptionalAction, default=True,
                   help="train on the normalised input basis (twin.py: colours as "
                        "differences to the current one, depth and motion at unit scale), "
                        "folded back into the shipped weights' raw basis at export "
                        "(default: on)")
    t.add_argument("--cls-detach", action=argparse.BooleanOptionalAction, default=True,
                   help="classifier stage: no gradient through the state from frame to frame "
                        "(default: on; each frame's loss trains that frame's pass)")
    t.add_argument("--false-ghost-weight", action=argparse.BooleanOptionalAction, default=False,
                   help="classifier stage: false-positive ghosting in aliasing regions takes "
                        "the predicted class's weight, as the paper does (default: off; it "
                        "kept visibility recall at 16 %%)")
    t.add_argument("--ghost-labels", choices=("generator", "useful", "cost"), default="generator",
                   help="classifier stage's ghosting labels: the generator's (visibility from "
                        "the exact previous geometry), or useful: visibility where the "
                        "clipped history is worse than the current upsample (--useful-ratio, "
                        "--useful-floor), the stage then clipping as the runtime does")
    t.add_argument("--useful-ratio", type=float, default=2.0,
                   help="--ghost-labels useful: squared-error ratio history / upsample")
    t.add_argument("--useful-floor", type=float, default=1e-3,
                   help="--ghost-labels useful: squared PQ error the history may exceed the "
                        "upsample's by in any case")
    t.add_argument("--cls-lr", type=float, default=2e-3, help="classifier stage learning rate")
    t.add_argument("--vis-margin", type=float, default=VIS_MARGIN,
                   help="the frame step's visibility margin while training (reference.md s7; "
                        "default: the runtime's, contract.VIS_MARGIN)")
    t.add_argument("--batch", type=int, default=4, help="windows per step")
    t.add_argument("--patch", type=int, default=64, help="patch size, output pixels")
    t.add_argument("--frames", type=int, default=8, help="recurrent frames per window")
    t.add_argument("--candidates", type=int, default=4000, help="random windows scored")
    t.add_argument("--keep", type=float, default=0.25, help="fraction of candidates kept")
    t.add_argument("--lr", type=float, default=1e-3, help="composition stage learning rate")
    t.add_argument("--cap", type=float, default=None,
                   help="net mode's counter cap while training (default: the runtime's)")
    t.add_argument("--weight-loss", type=float, default=1.0,
                   help="factor of the blend-weight L1 term of the composition loss")
    t.add_argument("--device", default=None, help="torch device (default: cuda if present)")
    t.add_argument("--init", default=None, help="start from these weights (.safetensors)")
    t.add_argument("--heldout", default=None,
                   help="directory of held-out sequences: print rules/net PSNR at the end")
    t.add_argument("--base", choices=BASES, default="paper",
                   help="the blend's base (clss.methods.clss.networks.BASES): paper (the "
                        "MLP's weight, the classifier's decision) or rules (clss-rules' "
                        "decision and cap, the MLP correcting its 1/(1+n); from a paper-form "
                        "--init the correction starts at zero, i.e. at clss-rules)")
    t.add_argument("--comp-no-logits", action="store_true",
                   help="the composition stage holds the first-layer weights of the "
                        "classifier's logits at zero (the MLP then ignores them)")
    t.add_argument("--export", action="store_true",
                   help="only write --out/weights.safetensors from its checkpoint, no training")


def cmd_train(args):
    if args.export:
        return export_checkpoint(args.out, args.base)
    for name in ("cls_steps", "comp_steps"):
        if getattr(args, name) < 0:
            raise TrainError(f"--{name.replace('_', '-')}: expected >= 0")
    for name in ("batch", "patch", "frames", "candidates", "threads"):
        if getattr(args, name) < 1:
            raise TrainError(f"--{name}: expected >= 1, got {getattr(args, name)}")
    if args.init and not os.path.isfile(args.init):
        raise TrainError(f"--init: {args.init} is not a file (a .safetensors of the networks)")
    if not 0 < args.keep <= 1:
        raise TrainError(f"--keep: expected a fraction in (0, 1], got {args.keep}")
    return train(args)


RECIPE = Recipe(add_arguments, cmd_train, __doc__)
