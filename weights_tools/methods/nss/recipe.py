"""NSS's recipe (`python -m weights_tools train nss --data DIR --out DIR`): recurrent
rollouts of --window frames (the first a reset; the model gym trains on 16) through the
torch twin, carrying the whole state (output history, the fed-back temporal parameters,
luma derivative) as the frame step does, back-propagated through the whole window.
Losses on Karis-tonemapped values without the patch margin; the first --warm frames of
each window are left out of the output's loss (the history is still empty).

--mode basic (the shipped weights of 2026-11-27): per frame L1 + --ssim (1 - SSIM) of the
output against the reference, --filtered x L1 of the kernel filter's own output (the model
gym's out_filtered: the filter learns to reconstruct on its own, not only through the
history), and --temporal x L1 between the changes of output and reference from the
previous frame (unwarped).

--mode gym (issue 53: as Arm's model gym trains NSS; docs/methods/nss.md says what is
the same and what is not): the temporal term is the gym's exp(4 |dref - dout|) - 1 of
the changes from the previous frame *warped by the motion* (bilinear, zero outside), the
spatial term L1 + --ssim (1 - SSIM) (the gym's 0.2 LPIPS: no VGG here); frame t of the
window weighs them by w_t, rising on a half cosine from 0.001 to 0.9 over the window
(early frames: stability, late: detail), and --filtered (0.1 in the gym) blends in the
filter's own L1 on every frame; the learning rate warms up over the first 5 % of the
steps; each window is flipped left-right and up-down at random (the motion's and the
jitter's signs with it: mirrored jitter patterns come for free).

--base rules (networks.BASES, issue 53 part 2): the step refines clss-rules: the rules'
output is 3 more network inputs and the base of the output, which the network's mix head
moves towards NSS's own accumulation. The rules' output is data (weights_tools/rules_base.py:
computed once per sequence by the OpenCL clss-rules step, cached beside the data). From
--init weights without it (the paper's form) e0's new input channels and the mix head
start at zero (networks.with_rules_base): the step starts exactly as clss-rules, the
network as trained.

Writes --out/checkpoint.pt (every minute; --resume continues), loss.png, train.json and
weights.safetensors (the file the OpenCL step loads).
"""
from __future__ import annotations

import os

import numpy as np

from weights_tools.methods import Recipe
from weights_tools.rules_base import rules_cached
from weights_tools.trainloop import Run, TrainError, check_patch_fits, nchw_sequences, fmt_s, load_init, load_sequences, pq_decode, ssim, temporal
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
    t.add_argument("--mode", choices=("basic", "gym"), default="basic",
                   help="the loss and schedule: basic (the 2026-11-27 weights) or gym (the "
                   "model gym's warped exponential temporal loss, time-weighted, warm-up, "
                   "flips; --filtered 0.1 is the gym's)")
    t.add_argument("--mix-l1", type=float, default=0.0,
                   help="the rules' base, --mode basic: weight of the mean clamped mix (a prior towards "
                   "clss-rules: NSS's output must buy its share)")
    t.add_argument("--only-mix", action="store_true",
                   help="the rules' base: train the mix head alone (the rest of the network "
                   "held as --init has it)")
    t.add_argument("--base", choices=("paper", "rules"), default=None,
                   help="the step's base (networks.BASES): rules = clss-rules' output, which "
                   "the network's mix head moves towards NSS's (default: --init's, else paper)")


def _prepare(seqs, torch):
    return nchw_sequences(seqs, torch, {"color": "color", "depth": "depth", "motion": "motion",
                                        "ref": "reference"})


def flip_frame(f, fx, fy):
    """One window frame's crops mirrored (fx: left-right, fy: up-down) as a mirrored
    render would give them: pixel (i, j)'s sample at j + 0.5 + jx becomes column w-1-j's
    at its centre - jx, so the jitter's and the motion's signs flip with the axis."""
    import torch
    dims = [d for d, on in ((-1, fx), (-2, fy)) if on]
    if not dims:
        return f
    sign = torch.tensor([-1.0 if fx else 1.0, -1.0 if fy else 1.0])
    out = {k: torch.flip(f[k], dims) for k in ("color", "depth", "motion", "ref", "rules") if k in f}
    out["motion"] = out["motion"] * sign.view(2, 1, 1)
    out["jitter"] = tuple(float(v) for v in np.asarray(f["jitter"]) * sign.numpy())
    return out


def make_batch(seqs, batch, window, R, rng, flips=False):
    """[window] per-frame batches: render crops R x R, output crops 2R, jitters, resets;
    `flips`: each window mirrored left-right and up-down at random (flip_frame)."""
    import torch
    keys = ("color", "depth", "motion")
    hr = ("ref", "rules") if "rules" in seqs[0] else ("ref",)    # output resolution
    fr = [{k: [] for k in keys + hr + ("jitter", "reset")} for _ in range(window)]
    for _ in range(batch):
        s = seqs[int(rng.integers(len(seqs)))]
        T, _, h, w = s["color"].shape
        t0 = int(rng.integers(0, T - window + 1))
        y0, x0 = int(rng.integers(0, h - R + 1)), int(rng.integers(0, w - R + 1))
        fx, fy = (bool(v) for v in rng.integers(0, 2, 2)) if flips else (False, False)
        for j in range(window):
            t = t0 + j
            f = flip_frame({**{k: s[k][t, :, y0:y0 + R, x0:x0 + R] for k in keys},
                            **{k: s[k][t, :, 2 * y0:2 * (y0 + R), 2 * x0:2 * (x0 + R)] for k in hr},
                            "jitter": s["jitter"][t]}, fx, fy)
            for k in keys + hr + ("jitter",):
                fr[j][k].append(f[k])
            fr[j]["reset"].append(bool(j == 0 or s["reset"][t]))
    for f in fr:
        for k in keys + hr:
            f[k] = torch.stack(f[k])
        f["reset"] = torch.tensor(f["reset"])
    return fr


def window_loss(step, fr, m, args):
    from .twin import karis
    st, total, prev, n = None, 0.0, None, 0
    for i, f in enumerate(fr):
        out, st = step.step(f["color"], f["depth"], f["motion"], f["jitter"], st, f["reset"],
                            rules=f.get("rules"))
        a = karis(out)[:, :, m:-m, m:-m]
        b = karis(f["ref"].clamp_min(0.0))[:, :, m:-m, m:-m]
        if i < args.warm:
            prev = (a, b)
            continue
        fl = karis(st["filtered"])[:, :, m:-m, m:-m]
        total = (total + (a - b).abs().mean() + args.ssim * (1.0 - ssim(a, b))
                 + args.filtered * (fl - b).abs().mean())
        if "mix" in st and args.mix_l1:
            total = total + args.mix_l1 * st["mix"][:, :, m:-m, m:-m].mean()
        if prev is not None:
            total = total + args.temporal * temporal(a, prev[0], b, prev[1])
        prev = (a, b)
        n += 1
    return total / max(n, 1)


def warp_back(x, motion):
    """x [N,C,H,W] (the previous frame at output resolution) fetched at each output
    pixel's previous position (render motion x 2, nearest-upsampled), bilinear, zero
    outside: the model gym's dense warp, for its temporal loss."""
    import torch
    import torch.nn.functional as F
    from .twin import _sample
    N, _, H, W = x.shape
    mu = F.interpolate(motion, size=(H, W), mode="nearest")
    xs = torch.arange(W, dtype=x.dtype).view(1, 1, 1, W) + 2.0 * mu[:, 0:1]
    ys = torch.arange(H, dtype=x.dtype).view(1, 1, H, 1) + 2.0 * mu[:, 1:2]
    return _sample(x, xs, ys)


def gym_weights(n):
    """w_t of frames 1..n of a window (frame 0 is the reset): the model gym's half
    cosine from 0.001 to 0.9, the spatial term's share (1 - w_t the temporal's)."""
    t = np.arange(1, n + 1) / max(n, 1)
    return 0.9 + (0.001 - 0.9) * (1.0 + np.cos(np.pi * t)) * 0.5


def gym_window_loss(step, fr, m, args):
    """The model gym's loss over one window (see the module's docstring): per frame t >= 1
    lerp(temporal_t, spatial_t, w_t), the mean over the window, blended with the
    filter's L1 over every frame by --filtered. The first --warm frames (>= 1) are the
    temporal term's reference only."""
    import torch
    from .twin import karis
    st, outs, refs, filt = None, [], [], []
    for f in fr:
        out, st = step.step(f["color"], f["depth"], f["motion"], f["jitter"], st, f["reset"],
                            rules=f.get("rules"))
        outs.append(karis(out))
        refs.append(karis(f["ref"].clamp_min(0.0)))
        filt.append((karis(st["filtered"]) - refs[-1])[:, :, m:-m, m:-m].abs().mean())
    warm = max(args.warm, 1)
    w = gym_weights(len(fr) - 1)
    st_loss = 0.0
    for i in range(warm, len(fr)):
        keep = (~fr[i]["reset"]).to(outs[i].dtype).view(-1, 1, 1, 1)   # a cut: no change
        d_out = outs[i] - warp_back(outs[i - 1], fr[i]["motion"])
        d_ref = refs[i] - warp_back(refs[i - 1], fr[i]["motion"])
        gap = torch.exp(4.0 * (d_ref - d_out).abs()) - 1.0
        temporal_t = (gap * keep)[:, :, m:-m, m:-m].mean()
        a, b = outs[i][:, :, m:-m, m:-m], refs[i][:, :, m:-m, m:-m]
        spatial_t = (a - b).abs().mean() + args.ssim * (1.0 - ssim(a, b))
        st_loss = st_loss + (1.0 - w[i - 1]) * temporal_t + w[i - 1] * spatial_t
    st_loss = st_loss / max(len(fr) - warm, 1)
    return (1.0 - args.filtered) * st_loss + args.filtered * torch.stack(filt).mean()


def per_sequence_rules(raw, data, torch):
    """The clss-rules output of each sequence as [T,3,H,W] linear (the rules' base's input),
    one tensor per distinct sequence (a mix repeats them)."""
    pq = rules_cached(raw, data, torch)
    done = {}
    return [done[id(r)] if id(r) in done else done.setdefault(id(r), pq_decode(r)) for r in pq]


def cmd_train(args):
    import torch
    from clss.methods.nss import networks as nets
    from .twin import NssNet, TorchStep
    run = Run(args, ("nss",))
    raw = load_sequences(args.data, args.window, REQUIRED)
    seqs = _prepare(raw, torch)
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
        if args.base == "paper" and nets.rules_base(cfg):
            raise TrainError("--base paper: --init has the rules' base (its e0 reads the rules)")
    else:
        cfg = nets.make_config(2, args.quality)
        w0 = nets.init_weights(cfg, args.seed)
    if args.base == "rules":
        cfg, w0 = nets.with_rules_base(cfg, w0)
    if nets.rules_base(cfg):
        # the rules' output, linear (the cache holds its PQ colour), beside the reference
        for s, r in zip(seqs, per_sequence_rules(raw, args.data, torch)):
            s["rules"] = r
    net = NssNet(cfg, w0)
    step = TorchStep(net)
    run.track(net=net)
    rng = run.batch_rng("nss")
    print(f"nss x2: {len(seqs)} sequences, rollouts of {args.window} frames, patches "
          f"{args.patch}+2x{args.margin} render px, quality {cfg['quality']}, base {cfg.get('base', 'paper')} "
          f"({nets.parameter_count(cfg)} parameters, {nets.macs_per_pixel(cfg) / 1e3:.1f} kMAC "
          f"per render pixel), {args.steps} steps of {args.batch}; loss L1 + {args.ssim:g} "
          + (f"(1-SSIM) + {args.filtered:g} filtered L1 + {args.temporal:g} temporal on Karis "
             "values" if args.mode == "basic" else
             f"(1-SSIM) spatial lerped with the warped exp temporal over the window, "
             f"{args.filtered:g} filtered L1 (mode gym)"),
          flush=True)
    m = args.margin * 2
    gym = args.mode == "gym"
    fn = gym_window_loss if gym else window_loss
    params = net.parameters()
    if args.only_mix:
        if not nets.rules_base(cfg):
            raise TrainError("--only-mix: the paper's form has no mix head (--base rules)")
        for p in net.parameters():
            p.requires_grad_(False)
        params = list(net.convs["mix"].parameters())
        for p in params:
            p.requires_grad_(True)
    run.fit("nss", params, lr=args.lr, steps=args.steps, clip=1.0,
            warmup=int(0.05 * args.steps) if gym else 0,
            loss=lambda it: (fn(step, make_batch(seqs, args.batch, args.window, R, rng,
                                                 flips=gym), m, args), {}),
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
