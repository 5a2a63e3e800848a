"""NSRR's recipe (`python -m weights_tools train nsrr --data DIR --out DIR`): the paper's
loss (1 - SSIM, in the PQ domain the step runs in, plus optionally 0.1 x a perceptual
term) and an L1 term, in YCbCr as the paper's section 3.2.5, chroma weighted (--l1,
--chroma: with 1 - SSIM on RGB alone, and with L1 added, the colour had not been learnt
after 400 steps, the output was grey; docs/methods/nsrr.md) on windows of up to 5 frames (the current one and 4 previous, accumulatively
warped as the step does), patches chosen for motion and detail.

Pretrained VGG-16 weights cannot be had here (no package ships them, nothing may be
downloaded), so the perceptual term is either dropped (`--perceptual none`, the shipped
recipe) or replaced by a fixed, seeded random-feature network of the same shape idea
(`--perceptual random`: 3 conv layers 3-16-32-32 with ReLU and pooling; the squared
feature differences of each layer, weight 0.1). docs/methods/nsrr.md has what each gives.

Windows: frame t with k valid previous frames, k = 4 (or fewer where a reset is nearer);
with probability --p-short k is drawn below that, so the network also learns the frames
after a reset, where the history holds fewer frames (the step fills the rest per
--reset-fill). The features and warps of the previous frames are computed in the
window, the reconstruction only at t, the loss on the patch without its margin (the
margin feeds the warps what lies just outside).

--base rules (networks.BASES, issue 53): the residual's base is the clss-rules output,
also an input of the U-Net. The rules have no learned parameters: their output is computed
once per sequence by the shipped clss-rules frame step (OpenCL, weights_tools/rules_base.py) and
cached beside the data (DIR/rules-cache/<sequence>.<key>.npy; the key digests the rules'
sources, the scale and the sequence's content, so a change of the rules or the data
computes it again). From --init weights without it, the base's new U-Net input channels
and the output conv start at zero: the network starts exactly as the rules.

Writes --out/checkpoint.pt (every minute; --resume continues), loss.png, train.json and
weights.safetensors (the file the OpenCL step loads).
"""
from __future__ import annotations

import os

import numpy as np

from weights_tools.methods import Recipe
from weights_tools.rules_base import rules_cached
from weights_tools.trainloop import Run, TrainError, check_patch_fits, fmt_s, load_init, load_sequences, per_sequence, ssim
from weights_tools.trainloop import add_arguments as add_run_arguments

REQUIRED = ("color", "depth", "motion", "jitter", "reset", "reference", "scale")


def add_arguments(t):
    t.add_argument("--data", required=True, help="a directory of DATA.md .npz sequences (one scale)"
                   "; or a mix DIR[:SHARE],... (weights_tools/DATA.md)")
    add_run_arguments(t)
    t.add_argument("--steps", type=int, default=1500)
    t.add_argument("--batch", type=int, default=8)
    t.add_argument("--patch", type=int, default=64, help="patch size, output pixels (loss area)")
    t.add_argument("--margin", type=int, default=4, help="render pixels around the patch")
    t.add_argument("--lr", type=float, default=5e-4)
    t.add_argument("--warmup", type=int, default=100,
                   help="steps of linear learning-rate warm-up before the cosine decay")
    t.add_argument("--act", choices=("leaky", "relu"), default="leaky",
                   help="hidden activation (networks.act_of): with ReLU the U-Net's last "
                        "hidden layer died within 10 steps (docs/methods/nsrr.md)")
    t.add_argument("--last-init", choices=("zero", "small"), default="zero",
                   help="un.9 (the U-Net's output conv) starts at zero, so the residual "
                        "network starts exactly at the base; small: 0.1 x He")
    t.add_argument("--widths", default="default", help="default, fast or paper (networks.WIDTHS)")
    t.add_argument("--n-prev", type=int, default=4)
    t.add_argument("--no-residual", action="store_true",
                   help="the paper's output (the U-Net's image) instead of a correction added "
                        "to the jitter-aware bilinear colour (networks.py)")
    t.add_argument("--reset-fill", choices=("zero", "duplicate"), default="zero")
    t.add_argument("--reject", choices=("none", "depth"), default=None,
                   help="history rejection (networks.REJECTS): depth empties the warped "
                        "history where the depth says disocclusion (default none, or the "
                        "--init file's)")
    t.add_argument("--base", choices=("bilinear", "rules"), default=None,
                   help="the residual's base (networks.BASES): rules = the clss-rules output, "
                        "also a U-Net input, precomputed per sequence and cached beside the "
                        "data (default bilinear, or the --init file's)")
    t.add_argument("--p-short", type=float, default=0.2,
                   help="fraction of windows with fewer previous frames than available")
    t.add_argument("--l1", type=float, default=1.0,
                   help="weight of an L1 term (PQ); 0 = the paper's loss without VGG")
    t.add_argument("--chroma", type=float, default=4.0,
                   help="weight of the chroma channels in the YCbCr loss (1 = plain YCbCr)")
    t.add_argument("--perceptual", choices=("none", "random"), default="none")
    t.add_argument("--perceptual-weight", type=float, default=0.1)
    t.add_argument("--init", default=None, help="start from these NSRR weights (.safetensors; "
                   "their config replaces --widths, --n-prev, --act and --no-residual)")
    t.add_argument("--candidates", type=int, default=4000, help="random patches scored")
    t.add_argument("--keep", type=float, default=0.3, help="fraction of candidates kept")


class RandomFeatures:
    """A fixed, seeded random conv net as the perceptual term's feature extractor."""

    def __init__(self, seed=1234):
        import torch
        g = torch.Generator().manual_seed(seed)
        self.w = []
        for ci, co in ((3, 16), (16, 32), (32, 32)):
            self.w.append(torch.randn(co, ci, 3, 3, generator=g) * (2.0 / (ci * 9)) ** 0.5)

    def loss(self, a, b):
        import torch.nn.functional as F
        total = 0.0
        for i, w in enumerate(self.w):
            a, b = F.relu(F.conv2d(a, w, padding=1)), F.relu(F.conv2d(b, w, padding=1))
            total = total + ((a - b) ** 2).mean()
            if i < len(self.w) - 1:
                a, b = F.avg_pool2d(a, 2), F.avg_pool2d(b, 2)
        return total


# BT.709 RGB -> (Y, Cb, Cr), chroma centred on 0.5
_YCC = np.array([[0.2126, 0.7152, 0.0722], [-0.1146, -0.3854, 0.5], [0.5, -0.4542, -0.0458]],
                np.float32)


def ycbcr(x, chroma=1.0):
    """[N,3,H,W] (PQ RGB) -> YCbCr with the chroma scaled by `chroma` about 0.5: the loss
    domain (the paper's section 3.2.5 runs the network's output and loss in YCbCr; here the
    network stays in RGB and only the loss moves, the same function class)."""
    import torch
    m = torch.from_numpy(_YCC).to(x)
    y = torch.einsum("ij,njhw->nihw", m, x)
    k = torch.tensor([1.0, chroma, chroma], dtype=x.dtype, device=x.device).view(1, 3, 1, 1)
    off = torch.tensor([0.0, 0.5, 0.5], dtype=x.dtype, device=x.device).view(1, 3, 1, 1)
    return y * k + off


class AliveProbe:
    """Is the U-Net alive? Watches un.8 (the last hidden layer, whose units feed the
    output conv): `take()` -> (fraction of its units positive on >= 1 % of the pixels,
    fraction of positive activations), over the steps since the last take. The first
    shipped training had 0.2 % positive: the output was the residual base alone."""

    def __init__(self, net):
        self.units, self.pos, self.n, self.last = 0.0, 0.0, 0, (float("nan"), float("nan"))
        self._cur = None
        net.un[8].register_forward_hook(self._hook)

    def _hook(self, mod, inp, out):
        self._cur = out.detach()

    def record(self):
        if self._cur is None:
            return
        p = (self._cur > 0).float()
        self.units += float((p.mean((0, 2, 3)) >= 0.01).float().mean())
        self.pos += float(p.mean())
        self.n += 1
        self._cur = None

    def take(self):
        if self.n:
            self.last = (self.units / self.n, self.pos / self.n)
        self.units, self.pos, self.n = 0.0, 0.0, 0
        return self.last


def _prepare(seqs, torch):
    from .twin import pq_encode

    def one(s):
        c = torch.from_numpy(np.ascontiguousarray(s["color"].astype(np.float32).transpose(0, 3, 1, 2)))
        d = torch.from_numpy(np.ascontiguousarray(s["depth"].astype(np.float32)[:, None]))
        r = torch.from_numpy(np.ascontiguousarray(s["reference"].astype(np.float32).transpose(0, 3, 1, 2)))
        resets = np.asarray(s["reset"], bool).copy()
        resets[0] = True
        last = np.zeros(len(resets), int)     # the last reset at or before each frame
        for t in range(len(resets)):
            last[t] = t if resets[t] else last[t - 1]
        return {"rgbd": torch.cat([pq_encode(c), d], 1),
                "motion": torch.from_numpy(np.ascontiguousarray(
                    s["motion"].astype(np.float32).transpose(0, 3, 1, 2))),
                "jitter": np.asarray(s["jitter"], np.float32), "last": last,
                "ref": pq_encode(r), "scale": s["scale"], "name": s["name"]}
    return per_sequence(seqs, one)


def choose_patches(seqs, n, keep, pr, margin, rng):
    """Candidates (seq, t, y0, x0) in render pixels, scored by motion and detail; the
    best `keep` fraction."""
    cands, mot, det = [], [], []
    for _ in range(n):
        i = int(rng.integers(len(seqs)))
        s = seqs[i]
        T, _, h, w = s["rgbd"].shape
        sc = s["scale"]
        t = int(rng.integers(T))
        y0 = int(rng.integers(margin, max(margin + 1, h - pr - margin + 1)))
        x0 = int(rng.integers(margin, max(margin + 1, w - pr - margin + 1)))
        m = s["motion"][t, :, y0:y0 + pr, x0:x0 + pr]
        r = s["ref"][t, :, sc * y0:sc * (y0 + pr), sc * x0:sc * (x0 + pr)]
        cands.append((i, t, y0, x0))
        mot.append(float(m.abs().mean()))
        det.append(float((r[:, 1:] - r[:, :-1]).abs().mean() + (r[:, :, 1:] - r[:, :, :-1]).abs().mean()))
    mot, det = np.array(mot), np.array(det)
    score = mot / (np.median(mot) + 1e-6) + det / (np.median(det) + 1e-6)
    order = np.argsort(-score)[:max(1, int(len(cands) * keep))]
    return [cands[j] for j in order]


def make_batch(seqs, picks, batch, pr, margin, n_prev, p_short, rng, torch):
    """Window tensors: rgbd/motion [n_prev+1, B, ...] of the frames t-n_prev..t (clamped at
    0), jitters, resets [n_prev+1, B] (True at each item's first valid frame), ref [B,3,..]."""
    items = [picks[int(rng.integers(len(picks)))] for _ in range(batch)]
    R = pr + 2 * margin
    rgbd, mot, jit, rst, ref, rules = [], [], [], [], [], []
    for j in range(n_prev + 1):
        rgbd.append([]), mot.append([]), jit.append([]), rst.append([])
    for (i, t, y0, x0) in items:
        s = seqs[i]
        sc = s["scale"]
        k = min(n_prev, t - int(s["last"][t]))
        if k > 0 and rng.random() < p_short:
            k = int(rng.integers(0, k))
        ys, xs = y0 - margin, x0 - margin
        for j in range(n_prev + 1):
            f = max(t - n_prev + j, t - k)
            rgbd[j].append(s["rgbd"][f, :, ys:ys + R, xs:xs + R])
            mot[j].append(s["motion"][f, :, ys:ys + R, xs:xs + R])
            jit[j].append(s["jitter"][f])
            rst[j].append(f == t - k)
        ref.append(s["ref"][t, :, sc * y0:sc * (y0 + pr), sc * x0:sc * (x0 + pr)])
        if "rules" in s:        # the rules' output at t over the whole crop (margin included)
            rules.append(s["rules"][t, :, sc * ys:sc * (ys + R), sc * xs:sc * (xs + R)])
    return ([torch.stack(r) for r in rgbd], [torch.stack(m) for m in mot], jit,
            [torch.tensor(r) for r in rst], torch.stack(ref),
            torch.stack(rules) if rules else None)


def forward(step, rgbd, mot, jit, rst, rules=None):
    """The window through the step: features and warps of every frame, the output of the
    last (PQ, [B,3,H,W] of the whole crop); rules: the rules' output at the last frame
    ("base": "rules")."""
    hist, pdepth = None, None
    for j in range(len(rgbd) - 1):
        stack = step.reproject(step.net.features(rgbd[j]), mot[j], jit[j], hist, rst[j], pdepth)
        hist, pdepth = stack[:, :step.net.n_prev * 12], rgbd[j][:, 3:4]
    stack = step.reproject(step.net.features(rgbd[-1]), mot[-1], jit[-1], hist, rst[-1], pdepth)
    return step.output(stack, step.base(rgbd[-1], jit[-1], rules))


def cmd_train(args):
    import torch
    from clss.methods.nsrr import networks as nets
    from .twin import NsrrNet, TorchStep
    run = Run(args, ("nsrr",))
    raw = load_sequences(args.data, 1, REQUIRED)
    seqs = _prepare(raw, torch)
    sc = seqs[0]["scale"]
    if args.patch % sc:
        raise TrainError(f"--patch {args.patch} is not a multiple of the scale {sc}")
    pr = args.patch // sc
    check_patch_fits(seqs, "rgbd", pr + 2 * args.margin, args)
    if args.init:
        cfg, w0 = load_init(args.init, nets, "NSRR weights")
    else:
        cfg = nets.make_config(args.widths, args.n_prev, residual=not args.no_residual,
                               act=args.act)
        w0 = nets.init_weights(cfg, args.seed)
        if args.last_init == "zero" and cfg["residual"]:
            w0["un.9.weight"][:] = 0.0
    if args.base is not None and args.base != nets.base_of(cfg):
        cfg, w0 = rebase(nets, cfg, w0, args.base)
    if args.reject is not None:        # a network fine-tuned to a rejection carries it
        cfg = {k: v for k, v in cfg.items() if k != "reject"}
        if args.reject != "none":
            cfg["reject"] = args.reject
    if nets.rules_base(cfg):
        for s, r in zip(seqs, rules_cached(raw, args.data, torch)):
            s["rules"] = r
    net = NsrrNet(cfg, w0)
    probe = AliveProbe(net)
    step = TorchStep(net, sc, reset_fill=args.reset_fill)
    perc = RandomFeatures() if args.perceptual == "random" else None
    run.track(net=net)
    rng = run.batch_rng("nsrr")
    picks = choose_patches(seqs, args.candidates, args.keep, pr, args.margin,
                           np.random.default_rng(args.seed))
    print(f"nsrr x{sc}: {len(seqs)} sequences, {len(picks)} patches of {args.patch} px kept, "
          f"widths {cfg['name']}, reject {cfg.get('reject', 'none')}, base {nets.base_of(cfg)}, {args.steps} steps of {args.batch}, loss 1-SSIM"
          + (f" + {args.l1:g} L1" if args.l1 else "") + f", YCbCr (chroma x{args.chroma:g})"
          + (f" + {args.perceptual_weight} random-feature perceptual" if perc else ""), flush=True)
    m = args.margin * sc

    def loss(it):
        rgbd, mot, jit, rst, ref, rules = make_batch(seqs, picks, args.batch, pr, args.margin,
                                                     cfg["n_prev"], args.p_short, rng, torch)
        y = forward(step, rgbd, mot, jit, rst, rules)[:, :, m:m + args.patch, m:m + args.patch]
        ya, yb = ycbcr(y.clamp(0, 1), args.chroma), ycbcr(ref, args.chroma)
        value = 1.0 - ssim(ya, yb)
        if args.l1:
            value = value + args.l1 * (ya - yb).abs().mean()
        if perc is not None:
            value = value + args.perceptual_weight * perc.loss(y, ref)
        probe.record()
        parts = {}
        if cfg["residual"]:
            # the PQ PSNR gain of the output over the residual base on this batch
            with torch.no_grad():
                base = step.base(rgbd[-1], jit[-1], rules)[:, :, m:m + args.patch, m:m + args.patch]
                mse = lambda a: float(((a.clamp(0, 1) - ref) ** 2).mean())  # noqa: E731
                parts["vs_base_db"] = 10 * float(np.log10(mse(base) / max(mse(y.detach()), 1e-12)))
        return value, parts

    def alive():
        units, pos = probe.take()
        return f"  un.8 alive {units:.2f} (positive {pos:.2f})"

    run.fit("nsrr", net.parameters(), lr=args.lr, steps=args.steps, warmup=args.warmup,
            loss=loss, progress=alive)
    path = os.path.join(args.out, "weights.safetensors")
    nets.save(path, cfg, net.numpy_weights())
    losses = run.log["losses"]["nsrr"]
    run.log.update(scale=sc, config=cfg, final_loss=float(np.mean(losses[-50:])),
                   un8_alive=probe.last[0], un8_positive=probe.last[1])
    run.write_log()
    print(f"wrote {path} ({fmt_s(run.log['seconds'])})")
    return 0


def rebase(nets, cfg, w, base):
    """(cfg, weights) with the residual's base changed to `base`: to "rules", un.0 gains
    the base's BASE_CHANNELS input channels (after the stack's) with zero weights and the
    output conv un.9 is zeroed, so the network starts exactly at its new base (the other
    layers keep their weights); back to "bilinear", those channels are dropped."""
    if not cfg.get("residual", False):
        raise TrainError(f"--base {base}: the network has no residual (--no-residual or the "
                         "--init file's config)")
    cfg = {k: v for k, v in cfg.items() if k != "base"}
    w = {k: np.array(v, np.float32, copy=True) for k, v in w.items()}
    k = nets.BASE_CHANNELS
    if base == "rules":
        cfg["base"] = base
        u0 = w["un.0.weight"]
        w["un.0.weight"] = np.concatenate([u0, np.zeros((u0.shape[0], k) + u0.shape[2:], np.float32)], 1)
        w["un.9.weight"][:] = 0.0
        w["un.9.bias"][:] = 0.0
    else:
        w["un.0.weight"] = w["un.0.weight"][:, :-k]
    nets.check_weights(cfg, w)
    return cfg, w


RECIPE = Recipe(add_arguments, cmd_train, __doc__)
