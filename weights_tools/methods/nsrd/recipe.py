"""NSRD's recipe (`python -m weights_tools train nsrd --data DIR --out DIR`): the paper's
loss (section 3.4: smooth L1 + SSIM on each frame, + the temporal loss between
consecutive outputs) on recurrent windows of --window frames, the first a reset (every
state empty), carrying the whole state (render-res history, the previous output's
lighting, the ConvLSTM) through the window as the frame step does. The loss is taken on
the display values the evaluation compares (ACES filmic + sRGB OETF, clss.io.tonemap) of
the re-modulated output, without the patch margin (the margin feeds the warps what lies
just outside the patch).

--no-demod and --no-mask train the paper's two ablations (material 1 everywhere; the
occlusion mask 1 everywhere); the flags go into the weights' config, so the OpenCL step
runs the ablation the network was trained for.

--base rules (networks.OUT_BASES, issue 53 part 2): the step refines clss-rules: the rules'
PQ colour is more network input (beside the previous output) and the output is the rules'
output moved towards NSRD's by the mix head. The rules' output is data
(weights_tools/rules_base.py: computed once per sequence by the OpenCL clss-rules step,
cached beside the data). From paper-form --init weights the new input channels and the mix
head start at zero (networks.with_rules_base; the lighting's base, the re-modulation and
the widths stay --init's): the step starts exactly as clss-rules. --mix-l1 W adds W x the
mean clamped mix to the loss (a prior towards the rules: NSRD's output must buy its share).

Writes --out/checkpoint.pt (every minute; --resume continues), loss.png, train.json and
weights.safetensors (the file the OpenCL step loads).
"""
from __future__ import annotations

import os

import numpy as np

from weights_tools.methods import Recipe
from weights_tools.trainloop import Run, TrainError, check_patch_fits, nchw_sequences, fmt_s, load_init, load_sequences, ssim, temporal
from weights_tools.trainloop import add_arguments as add_run_arguments
from weights_tools.rules_base import rules_cached

REQUIRED = ("color", "depth", "motion", "jitter", "reset", "reference", "scale", "albedo",
            "normal", "albedo_hr")


def add_arguments(t):
    t.add_argument("--data", required=True, help="a directory of DATA.md .npz sequences with "
                                                "G-buffers (one integer scale)"
                   "; or a mix DIR[:SHARE],... (weights_tools/DATA.md)")
    add_run_arguments(t)
    t.add_argument("--steps", type=int, default=1200)
    t.add_argument("--batch", type=int, default=8)
    t.add_argument("--window", type=int, default=4, help="frames per recurrent window")
    t.add_argument("--patch", type=int, default=24, help="patch size, render pixels (loss area)")
    t.add_argument("--margin", type=int, default=4, help="render pixels around the patch")
    t.add_argument("--lr", type=float, default=2e-3)
    t.add_argument("--widths", default="default", help="default or fast (networks.WIDTHS)")
    t.add_argument("--no-demod", action="store_true", help="ablation: no demodulation")
    t.add_argument("--no-mask", action="store_true", help="ablation: no occlusion mask")
    t.add_argument("--remod", choices=("blur", "learned"), default="blur",
                   help="re-modulation: the filtered material, or a learned per-pixel blend "
                        "of point and filtered (networks.REMODS)")
    t.add_argument("--base", choices=("bilinear", "guided", "rules"), default="bilinear",
                   help="what the network's lighting correction is added to: the bilinear "
                        "lighting, or the material-guided upsampling (networks.BASES); or "
                        "rules: the step refines clss-rules' output (networks.OUT_BASES), the "
                        "lighting's base --init's (guided without --init)")
    t.add_argument("--mix-l1", type=float, default=0.0,
                   help="the rules' base: weight of the mean clamped mix (a prior towards "
                        "clss-rules)")
    t.add_argument("--ssim", type=float, default=0.2, help="weight of 1 - SSIM")
    t.add_argument("--temporal", type=float, default=0.5, help="weight of the temporal loss")
    t.add_argument("--beta", type=float, default=0.02, help="smooth-L1 transition")
    t.add_argument("--warp-state", action="store_true",
                   help="warp the ConvLSTM's h and c by the motion (networks.make_config)")
    t.add_argument("--init", default=None, help="start from these NSRD weights "
                                                "(.safetensors; a fine-tune)")
    t.add_argument("--max-minutes", type=float, default=0.0,
                   help="stop (and write the weights) after this many minutes; the cosine "
                        "schedule is still the one of --steps")


def display(x):
    """clss.io.tonemap in torch (ACES filmic, then the sRGB OETF): the metric's domain."""
    import torch
    x = x.clamp_min(0.0)
    y = ((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)).clamp(0.0, 1.0)
    return torch.where(y <= 0.0031308, 12.92 * y,
                       1.055 * y.clamp_min(0.0031308).pow(1 / 2.4) - 0.055)


def _prepare(seqs, torch):
    return nchw_sequences(seqs, torch, {"color": "color", "depth": "depth", "motion": "motion", "albedo": "albedo",
                           "normal": "normal", "albedo_hr": "albedo_hr", "ref": "reference"})


HR = ("albedo_hr", "ref", "rules")      # output-resolution images (rules: the rules' base)


def make_batch(seqs, batch, window, R, rng):
    """[window] lists of per-frame batches (render crops R x R, output crops R*s), the
    resets [window] bool tensors (True at the window's first frame and at cuts)."""
    import torch
    keys = ("color", "depth", "motion", "albedo", "normal")
    hr = tuple(k for k in HR if k in seqs[0])
    fr = [{k: [] for k in keys + hr + ("jitter", "reset")} for _ in range(window)]
    for _ in range(batch):
        s = seqs[int(rng.integers(len(seqs)))]
        T, _, h, w = s["color"].shape
        sc = s["scale"]
        t0 = int(rng.integers(0, T - window + 1))
        y0 = int(rng.integers(0, h - R + 1))
        x0 = int(rng.integers(0, w - R + 1))
        for j in range(window):
            t = t0 + j
            for k in keys:
                fr[j][k].append(s[k][t, :, y0:y0 + R, x0:x0 + R])
            for k in hr:
                fr[j][k].append(s[k][t, :, sc * y0:sc * (y0 + R), sc * x0:sc * (x0 + R)])
            fr[j]["jitter"].append(s["jitter"][t])
            fr[j]["reset"].append(bool(j == 0 or s["reset"][t]))
    for f in fr:
        for k in keys + hr:
            f[k] = torch.stack(f[k])
        f["reset"] = torch.tensor(f["reset"])
    return fr


def window_loss(step, fr, m, args):
    """The window through the step; the loss of every frame (smooth L1 + SSIM) and of
    every consecutive pair (temporal), on the display values inside the margin."""
    import torch.nn.functional as F
    st, total, prev = None, 0.0, None
    for f in fr:
        out, st = step.step(f["color"], f["depth"], f["motion"], f["albedo"], f["normal"],
                            f["albedo_hr"], f["jitter"], st, f["reset"], lo=1e-5,
                            rules=f.get("rules"))
        if "mix" in st and args.mix_l1:
            total = total + args.mix_l1 * st["mix"][:, :, m:-m, m:-m].mean()
        a = display(out)[:, :, m:-m, m:-m]
        b = display(f["ref"])[:, :, m:-m, m:-m]
        total = total + F.smooth_l1_loss(a, b, beta=args.beta) + args.ssim * (1.0 - ssim(a, b))
        if prev is not None:
            total = total + args.temporal * temporal(a, prev[0], b, prev[1])
        prev = (a, b)
    return total / len(fr)


def cmd_train(args):
    import torch
    from clss.methods.nsrd import networks as nets
    from .twin import NsrdNet, TorchStep
    run = Run(args, ("nsrd",))
    raw = load_sequences(args.data, args.window, REQUIRED)
    seqs = _prepare(raw, torch)
    sc = seqs[0]["scale"]
    R = args.patch + 2 * args.margin
    if R % 2:
        raise TrainError(f"--patch {args.patch} + 2 x --margin {args.margin} must be even "
                         "(the network's down/up level)")
    check_patch_fits(seqs, "color", R, args)
    rules = args.base == "rules"
    try:
        cfg = nets.make_config(sc, args.widths, demod=not args.no_demod, mask=not args.no_mask,
                               remod=args.remod, warp_state=args.warp_state,
                               base="guided" if rules else args.base,
                               out_base="rules" if rules else "paper")
    except ValueError as e:
        raise TrainError(str(e)) from None
    w0 = nets.init_weights(cfg, args.seed)
    if args.init and rules:
        # the rules' base on --init's network (paper form converted: the new pf channels and
        # the mix head at zero; a rules' base file as it is)
        c0, w1 = load_init(args.init, nets, "NSRD weights")
        if int(c0["scale"]) != int(sc):
            raise TrainError(f"--init: {args.init} is for scale {c0['scale']}, the data {sc}")
        cfg, w0 = nets.with_rules_base(c0, w1)
    elif args.init:
        c0, w1 = load_init(args.init, nets, "NSRD weights")
        s0, s1 = nets.layer_shapes(c0), nets.layer_shapes(cfg)
        if any(s0[k] != s1[k] for k in s1 if k != "out") or s0["out"][1:] != s1["out"][1:]:
            raise TrainError(f"--init: {args.init} has other layer shapes than this config")
        # the last conv may gain the learned re-modulation's channels: the lighting's are
        # copied, the new ones keep their init (alpha = 0.5 where the network is unsure)
        for k in ("out.weight", "out.bias"):
            n = min(w1[k].shape[0], w0[k].shape[0])
            w1[k] = np.concatenate([w1[k][:n], w0[k][n:]], 0)
        w0 = w1
    if nets.rules_base(cfg):
        # the rules' PQ colour (the cache's, at the twin's nits), beside the reference
        for s, r in zip(seqs, rules_cached(raw, args.data, torch)):
            s["rules"] = r
    net = NsrdNet(cfg, w0)
    step = TorchStep(net)
    run.track(net=net)
    rng = run.batch_rng("nsrd")
    print(f"nsrd x{sc}: {len(seqs)} sequences, windows of {args.window} frames, patches "
          f"{args.patch}+2x{args.margin} render px, widths {cfg['name']} "
          f"({nets.macs_per_pixel(cfg) / 1e3:.0f} kMAC per render pixel), demod {cfg['demod']}, "
          f"mask {cfg['mask']}, remod {cfg['remod']}, base {cfg.get('base', 'bilinear')}, "
          f"out_base {cfg.get('out_base', 'paper')}, {args.steps} steps of {args.batch}; loss smooth L1 + "
          f"{args.ssim:g} (1-SSIM) + {args.temporal:g} temporal on display values", flush=True)
    m = args.margin * sc
    run.fit("nsrd", net.parameters(), lr=args.lr, steps=args.steps, clip=1.0,
            loss=lambda it: (window_loss(step, make_batch(seqs, args.batch, args.window, R, rng),
                                         m, args), {}),
            max_seconds=args.max_minutes * 60 if args.max_minutes > 0 else None)
    path = os.path.join(args.out, "weights.safetensors")
    nets.save(path, cfg, net.numpy_weights())
    losses = run.log["losses"]["nsrd"]
    run.log.update(scale=sc, config=cfg, steps_done=len(losses),
                   final_loss=float(np.mean(losses[-50:])))
    run.write_log()
    print(f"wrote {path} ({fmt_s(run.log['seconds'])})")
    return 0


RECIPE = Recipe(add_arguments, cmd_train, __doc__)
