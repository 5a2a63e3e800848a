"""NSS's recipe (`python -m weights_tools train nss --data DIR --out DIR`): recurrent
rollouts of --window frames (the first a reset; the model gym trains on ~16) through the
torch twin, carrying the whole state (output history, temporal parameters, luma
derivative) as the frame step does. The loss, after the model gym's, on Karis-tonemapped
values without the patch margin: L1 + --ssim (1 - SSIM) of the output against the
reference, --filtered x L1 of the kernel filter's own output (the model gym's
out_filtered: the filter learns to reconstruct on its own, not only through the history),
and --temporal x the temporal loss between consecutive outputs (the change of the output
against the change of the reference: flicker the reference does not have); the first
--warm frames of each window are left out of the loss (the history is still empty).

Writes --out/checkpoint.pt (every minute; --resume continues), loss.png, train.json and
weights.safetensors (the file the OpenCL step loads).
"""
from __future__ import annotations

import os

import numpy as np

from weights_tools.methods import Recipe
from weights_tools.trainloop import Run, TrainError, check_patch_fits, nchw_sequences, fmt_s, load_init, load_sequences, ssim, temporal
from weights_tools.trainloop import add_arguments as add_run_arguments

REQUIRED = ("color", "depth", "motion", "jitter", "reset", "reference", "scale")


def add_arguments(t):
    t.add_argument("--data", required=True, help="a directory of DATA.md .npz sequences at 2x"
                   "; or a mix DIR[:SHARE],... (weights_tools/DATA.md)")
    add_run_arguments(t)
    t.add_argument("--steps", type=int, default=2000)
    t.add_argument("--batch", type=int, default=4)
    t.add_argument("--window", type=int, default=16, help="frames per recurrent rollout")
    t.add_argument("--warm", type=int, default=1, help="first frames of a window left out of the loss")
    t.add_argument("--patch", type=int, default=24, help="patch size, render pixels (loss area)")
    t.add_argument("--margin", type=int, default=4, help="render pixels around the patch "
                                                          "(patch + 2 margin: a multiple of 8)")
    t.add_argument("--lr", type=float, default=1e-3)
    t.add_argument("--quality", choices=("low", "mid", "high"), default="mid",
                   help="kernel preset: 4x4 taps (low, mid) or 6x6 (high)")
    t.add_argument("--ssim", type=float, default=0.2, help="weight of 1 - SSIM")
    t.add_argument("--filtered", type=float, default=0.2, help="weight of the filter's own L1")
    t.add_argument("--temporal", type=float, default=0.5, help="weight of the temporal loss")
    t.add_argument("--init", default=None, help="start from these NSS weights (.safetensors; a "
                   "fine-tune; their config replaces --quality)")
    t.add_argument("--max-minutes", type=float, default=0.0,
                   help="stop (and write the weights) after this many minutes")


def _prepare(seqs, torch):
    return nchw_sequences(seqs, torch, {"color": "color", "depth": "depth", "motion": "motion",
                                        "ref": "reference"})


def make_batch(seqs, batch, window, R, rng):
    """[window] per-frame batches: render crops R x R, output crops 2R, jitters, resets."""
    import torch
    keys = ("color", "depth", "motion")
    fr = [{k: [] for k in keys + ("ref", "jitter", "reset")} for _ in range(window)]
    for _ in range(batch):
        s = seqs[int(rng.integers(len(seqs)))]
        T, _, h, w = s["color"].shape
        t0 = int(rng.integers(0, T - window + 1))
        y0, x0 = int(rng.integers(0, h - R + 1)), int(rng.integers(0, w - R + 1))
        for j in range(window):
            t = t0 + j
            for k in keys:
                fr[j][k].append(s[k][t, :, y0:y0 + R, x0:x0 + R])
            fr[j]["ref"].append(s["ref"][t, :, 2 * y0:2 * (y0 + R), 2 * x0:2 * (x0 + R)])
            fr[j]["jitter"].append(s["jitter"][t])
            fr[j]["reset"].append(bool(j == 0 or s["reset"][t]))
    for f in fr:
        for k in keys + ("ref",):
            f[k] = torch.stack(f[k])
        f["reset"] = torch.tensor(f["reset"])
    return fr


def window_loss(step, fr, m, args):
    from .twin import karis
    st, total, prev, n = None, 0.0, None, 0
    for i, f in enumerate(fr):
        out, st = step.step(f["color"], f["depth"], f["motion"], f["jitter"], st, f["reset"])
        a = karis(out)[:, :, m:-m, m:-m]
        b = karis(f["ref"].clamp_min(0.0))[:, :, m:-m, m:-m]
        if i < args.warm:
            prev = (a, b)
            continue
        fl = karis(st["filtered"])[:, :, m:-m, m:-m]
        total = (total + (a - b).abs().mean() + args.ssim * (1.0 - ssim(a, b))
                 + args.filtered * (fl - b).abs().mean())
        if prev is not None:
            total = total + args.temporal * temporal(a, prev[0], b, prev[1])
        prev = (a, b)
        n += 1
    return total / max(n, 1)


def cmd_train(args):
    import torch
    from clss.methods.nss import networks as nets
    from .twin import NssNet, TorchStep
    run = Run(args, ("nss",))
    seqs = _prepare(load_sequences(args.data, args.window, REQUIRED), torch)
    if seqs[0]["scale"] != 2:
        raise TrainError(f"--data: NSS trains at 2x, the sequences are at {seqs[0]['scale']}x")
    R = args.patch + 2 * args.margin
    if R % nets.MULTIPLE:
        raise TrainError(f"--patch {args.patch} + 2 x --margin {args.margin} must be a multiple "
                         f"of {nets.MULTIPLE} (the network's three stride-2 levels)")
    check_patch_fits(seqs, "color", R, args)
    if not 0 <= args.warm < args.window:
        raise TrainError(f"--warm {args.warm}: expected 0 <= warm < --window {args.window}")
    if args.init:
        cfg, w0 = load_init(args.init, nets, "NSS weights")
    else:
        cfg = nets.make_config(2, args.quality)
        w0 = nets.init_weights(cfg, args.seed)
    net = NssNet(cfg, w0)
    step = TorchStep(net)
    run.track(net=net)
    rng = run.batch_rng("nss")
    print(f"nss x2: {len(seqs)} sequences, rollouts of {args.window} frames, patches "
          f"{args.patch}+2x{args.margin} render px, quality {cfg['quality']} "
          f"({nets.parameter_count(cfg)} parameters, {nets.macs_per_pixel(cfg) / 1e3:.1f} kMAC "
          f"per render pixel), {args.steps} steps of {args.batch}; loss L1 + {args.ssim:g} "
          f"(1-SSIM) + {args.filtered:g} filtered L1 + {args.temporal:g} temporal on Karis values",
          flush=True)
    m = args.margin * 2
    run.fit("nss", net.parameters(), lr=args.lr, steps=args.steps, clip=1.0,
            loss=lambda it: (window_loss(step, make_batch(seqs, args.batch, args.window, R, rng),
                                         m, args), {}),
            max_seconds=args.max_minutes * 60 if args.max_minutes > 0 else None)
    path = os.path.join(args.out, "weights.safetensors")
    nets.save(path, cfg, net.numpy_weights())
    losses = run.log["losses"]["nss"]
    run.log.update(scale=2, config=cfg, steps_done=len(losses),
                   final_loss=float(np.mean(losses[-50:])))
    run.write_log()
    print(f"wrote {path} ({fmt_s(run.log['seconds'])})")
    return 0


RECIPE = Recipe(add_arguments, cmd_train, __doc__)
