"""The one training loop of every method (`python -m weights_tools train METHOD`): Run
owns the seeding, resume, optimiser, learning-rate schedule, checkpoints and logging
(progress lines, loss.png, train.json); beside it the reading of DATA.md sequences and the
losses the papers use (L1, SSIM, temporal). A method's recipe
(weights_tools/methods/<name>/recipe.py) gives only its model, its data and its loss:

    run = Run(args, stages=("nsrr",))        # seeds torch; reads --out/checkpoint.pt on --resume
    net = ...                                # the model, built after the seeding
    run.track(net=net)                       # checkpointed from now on (restored on --resume)
    rng = run.batch_rng("nsrr")              # the data's generator (see batch_rng, step_rng)
    run.fit("nsrr", net.parameters(), lr=..., steps=..., loss=lambda it: (value, {parts}))
    ...write the weights...; run.write_log()

Needs torch (the [train] extra)."""
from __future__ import annotations

import glob
import json
import math
import os
import pickle
import time

import numpy as np
import torch
import torch.nn.functional as F

from clss.pipeline.contract import PQ_C1, PQ_C2, PQ_C3, PQ_M1, PQ_M2, PQ_NITS, PQ_PEAK_NITS

PROGRESS_S = 5.0        # seconds between progress lines
CHECKPOINT_S = 60.0     # seconds between checkpoints (and at the end of each stage)
PLOT_S = 30.0           # seconds between refreshes of loss.png


class TrainError(ValueError):
    """A user's mistake (bad directory, bad data, bad option): one line, no traceback."""


def load_init(path, nets, what) -> tuple[dict, dict]:
    """(config, weights) of `--init PATH` through a method's network file (`nets.load`), or
    a TrainError naming the flag: a path that is no file, a file that is not `what`."""
    if not os.path.isfile(path):
        raise TrainError(f"--init: {path} is not a file ({what}, .safetensors)")
    try:
        return nets.load(path)
    except Exception as e:      # noqa: BLE001 - safetensors' own error for a file that is no safetensors too
        raise TrainError(f"--init: {path}: not {what} ({e})") from None


# ---- the PQ transfer (clss.pipeline.contract), differentiable, for every torch twin ------
def pq_encode(x, nits=PQ_NITS):
    y = torch.clamp(x * (nits / PQ_PEAK_NITS), 0.0, 1.0)
    ym = torch.pow(y, PQ_M1)
    return torch.pow((PQ_C1 + PQ_C2 * ym) / (1.0 + PQ_C3 * ym), PQ_M2)


def pq_decode(e, nits=PQ_NITS):
    ep = torch.pow(torch.clamp(e, 0.0, 1.0), 1.0 / PQ_M2)
    y = torch.pow(torch.clamp(ep - PQ_C1, min=0.0) / (PQ_C2 - PQ_C3 * ep), 1.0 / PQ_M1)
    return y * (PQ_PEAK_NITS / nits)


# ---- data --------------------------------------------------------------------------------

def nchw_sequences(seqs, torch, images: dict) -> list[dict]:
    """Sequences as torch tensors for a recurrent recipe: each image of `images`
    ({key in the result: key in the sequence}) as [T, C, H, W] float32 (a [T, H, W] plane
    gets C = 1), with "jitter", "reset" (frame 0 always a reset), "scale" and "name"."""
    def nchw(a):
        a = np.asarray(a, np.float32)
        return torch.from_numpy(np.ascontiguousarray(a.transpose(0, 3, 1, 2) if a.ndim == 4 else a[:, None]))
    def one(s):
        r = np.asarray(s["reset"], bool).copy()
        r[0] = True
        return {**{k: nchw(s[src]) for k, src in images.items()},
                "jitter": np.asarray(s["jitter"], np.float32), "reset": r,
                "scale": s["scale"], "name": s["name"]}
    return per_sequence(seqs, one)


def check_patch_fits(seqs, key, size, args):
    """A TrainError naming the first sequence (of a whole mix, not only its first directory)
    whose `key` frames [T, C, H, W] are smaller than `size` render pixels, the patch
    --patch / --margin asks for."""
    for s in seqs:
        h, w = s[key].shape[2:]
        if size > min(h, w):
            raise TrainError(f"--patch {args.patch} with --margin {args.margin} does not fit "
                             f"the {h}x{w} frames of {s['name']}")


def per_sequence(seqs, fn):
    """[fn(s) for s in seqs], with fn run once per distinct sequence: a mix (load_sequences)
    lists a sequence several times, and its conversions share one copy too."""
    done = {}
    return [done[id(s)] if id(s) in done else done.setdefault(id(s), fn(s)) for s in seqs]


def parse_mix(data):
    """--data as the recipes take it: one directory, or a mix "DIR[:SHARE],DIR[:SHARE],..."
    (e.g. out/data/train,out/data/blender/train:0.3). A SHARE is the fraction of the draws
    that come from that directory's sequences; the directories without one share the rest
    equally. Returns [(directory, share)]."""
    parts = [p for p in str(data).split(",") if p]
    if not parts:
        raise TrainError("--data: no directory given")
    out = []
    for p in parts:
        d, sep, share = p.rpartition(":")
        if not sep or os.path.isdir(p):
            out.append((p, None))
            continue
        try:
            v = float(share)
        except ValueError:
            raise TrainError(f"--data: {p!r}: the share after ':' must be a number") from None
        if not 0.0 < v < 1.0:
            raise TrainError(f"--data: {p!r}: a share is between 0 and 1 (exclusive), got {v:g}")
        out.append((d, v))
    given = sum(v for _, v in out if v is not None)
    free = [d for d, v in out if v is None]
    if given >= 1.0 + 1e-9 or (not free and abs(given - 1.0) > 1e-6):
        raise TrainError(f"--data: the shares add up to {given:g}; they leave the directories "
                         "without one a positive share, or add up to 1")
    return [(d, v if v is not None else (1.0 - given) / len(free)) for d, v in out]


def load_sequences(data, frames, required, prepare=None, optional=()):
    """The DATA.md sequences of `data` (a directory, or a mix: parse_mix) with at least
    `frames` frames and every key of `required`, as dicts of arrays with "scale" (an
    integer: patches are cut at the same place at render and output resolution) and "name".
    `prepare(seq)` converts a sequence in place (e.g. the reference to the training
    domain); the keys of `optional` are loaded where a sequence has them. The recipes draw
    a sequence uniformly from the list, so a mix repeats each directory's sequences (the
    same arrays, not copies) in proportion to its share, to within one in MIX_SLOTS."""
    mix = parse_mix(data)
    loaded = [(_load_dir(d, frames, required, prepare, optional), v) for d, v in mix]
    out = loaded[0][0] if len(mix) == 1 else [
        seqs[i % len(seqs)] for seqs, v in loaded for i in range(max(1, round(v * MIX_SLOTS)))]
    scales = {s["scale"] for s in out}
    if len(scales) > 1:
        raise TrainError(f"--data: sequences at several scales {sorted(scales)}; train one scale")
    return out


MIX_SLOTS = 1000


def _load_dir(data_dir, frames, required, prepare, optional):
    if not os.path.isdir(data_dir):
        raise TrainError(f"--data: {data_dir} is not a directory")
    paths = sorted(glob.glob(os.path.join(data_dir, "*.npz")))
    if not paths:
        raise TrainError(f"--data: no .npz sequences in {data_dir} "
                         "(write some with `python -m weights_tools gen`)")
    seqs, skipped = [], 0
    for p in paths:
        try:
            z = np.load(p, allow_pickle=False)
            missing = [k for k in required if k not in z.files]
            if missing:
                raise TrainError(f"--data: {p} lacks {', '.join(missing)} (see weights_tools/DATA.md)")
            s = {k: z[k] for k in tuple(required) + tuple(optional) if k in z.files}
        except (OSError, ValueError) as e:
            if isinstance(e, TrainError):
                raise
            raise TrainError(f"--data: {p} is not a readable .npz sequence ({e})") from None
        T, h, w = s["depth"].shape
        scale = float(s["scale"])
        H, W = s["reference"].shape[1:3]
        if abs(scale - round(scale)) > 1e-6 or (H, W) != (h * round(scale), w * round(scale)):
            raise TrainError(f"--data: {p} has scale {scale:g} ({h}x{w} -> {H}x{W}); training "
                             "cuts patches at an integer scale only")
        if T < frames:
            skipped += 1
            continue
        if prepare is not None:
            prepare(s)
        s["scale"], s["name"] = int(round(scale)), os.path.basename(p)
        seqs.append(s)
    if not seqs:
        raise TrainError(f"--data: no sequence in {data_dir} has {frames} frames (--frames)")
    if skipped:
        print(f"skipped {skipped} sequences shorter than {frames} frames")
    return seqs


# ---- schedule, progress, pictures, checkpoints ----------------------------------------------

def lr_cosine(base, step, total):
    """Cosine decay from `base` to 10 % of it over `total` steps."""
    return base * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * min(step / max(total, 1), 1.0))))


def fmt_s(s):
    s = int(max(s, 0))
    return f"{s // 3600}h{s // 60 % 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


def plot_losses(history, path, stages):
    """loss.png: one panel per stage, the raw loss and its running mean."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(stages), figsize=(5 * len(stages), 3.5), squeeze=False)
    for ax, stage in zip(axes[0], stages):
        ys = np.asarray(history.get(stage, []), np.float64)
        if len(ys):
            ax.plot(ys, lw=0.5, alpha=0.4, color="C0")
            k = max(1, len(ys) // 50)
            sm = np.convolve(ys, np.ones(k) / k, mode="valid")
            ax.plot(np.arange(len(sm)) + k - 1, sm, color="C1", label=f"mean of {k}")
            ax.legend()
        ax.set_title(f"{stage} loss")
        ax.set_xlabel("step")
    fig.tight_layout()
    tmp = path + ".tmp.png"
    fig.savefig(tmp, dpi=80)
    plt.close(fig)
    os.replace(tmp, path)


def save_checkpoint(path, state):
    """torch.save through a temporary file: an interruption never leaves half a file."""
    tmp = path + ".tmp"
    torch.save(state, tmp)
    os.replace(tmp, path)


# ---- the run: seeding, resume, optimiser, schedule, checkpoints, logging ----------------------

def add_arguments(p, threads=1, weights="weights.safetensors"):
    """The options every recipe has, because Run reads them: --out, --seed, --threads,
    --resume (`weights`: the file the recipe writes in --out, for the help)."""
    p.add_argument("--out", required=True, help=f"directory for checkpoint.pt, loss.png, "
                                                f"train.json and {weights}")
    p.add_argument("--seed", type=int, default=0,
                   help="seeds the initial weights (torch) and the batches (numpy)")
    p.add_argument("--threads", type=int, default=threads,
                   help=f"torch CPU threads (default {threads}; the thread count changes the "
                        "float results)")
    p.add_argument("--resume", action="store_true",
                   help="continue from --out/checkpoint.pt (a run without one starts afresh); "
                        "--steps may change")


class Run:
    """One training run in `args.out` (checkpoint.pt, loss.png, train.json), in `stages`,
    each one optimiser's steps.

    Seeding: torch's global generator from --seed when the run is made, before the recipe
    builds its networks; the batches from numpy generators that batch_rng and step_rng
    derive from --seed.  Resume (--resume): the checkpoint holds every tracked model, the
    optimiser of the stage it was written in, the stage and its next step, and the log;
    --steps may change on resume (a finished stage with more steps goes on).  Optimiser:
    Adam, the learning rate decayed by lr_cosine after an optional linear warm-up, set before
    every step.  Logging: a progress line every PROGRESS_S (and on the first and last step),
    loss.png every PLOT_S, a checkpoint every CHECKPOINT_S and at the end of a stage, and
    train.json (write_log): settings, losses per stage, each step's `parts`, seconds per
    step, total seconds, and what the recipe adds to `log`."""

    def __init__(self, args, stages, quiet=False):
        self.out, self.seed, self.stages = args.out, int(args.seed), tuple(stages)
        self.quiet = quiet
        torch.set_num_threads(max(1, int(args.threads)))
        torch.manual_seed(self.seed)
        os.makedirs(self.out, exist_ok=True)
        self.path = os.path.join(self.out, "checkpoint.pt")
        self.log = {"settings": {k: v for k, v in vars(args).items() if k != "fn"},
                    "losses": {s: [] for s in self.stages}, "parts": [], "step_s": {},
                    "seconds": 0.0}
        self.models = {}
        self.at = (0, 0)            # (stage index, step) the run goes on from
        self.stopped = False        # fit's max_seconds ran out: the later stages do not run
        self._opt_state = None
        self._ck = None
        if args.resume:
            if os.path.isfile(self.path):
                try:
                    self._ck = torch.load(self.path, weights_only=True)
                except (pickle.UnpicklingError, RuntimeError, EOFError) as e:
                    raise TrainError(f"--resume: {self.path} is not a checkpoint "
                                     f"({str(e).splitlines()[0]})") from None
                if not isinstance(self._ck, dict) or "models" not in self._ck:
                    raise TrainError(f"--resume: {self.path} was written by an older version "
                                     "of the recipe (retrain, or check out that version)")
            else:
                print(f"--resume: no checkpoint in {self.out}, starting afresh", flush=True)

    def track(self, **models):
        """The modules checkpointed under these names; on --resume their state (and where
        the run stood) is restored from the checkpoint here."""
        self.models = models
        ck = self._ck
        if ck is None:
            return
        missing = sorted(set(models) - set(ck["models"]))
        if missing:
            raise TrainError(f"--resume: {self.path} holds no {', '.join(missing)}")
        for name, m in models.items():
            m.load_state_dict(ck["models"][name])
        settings = self.log["settings"]
        self.log = json.loads(ck["log"])
        self.log["settings"] = settings
        self.at, self._opt_state = (int(ck["stage"]), int(ck["step"])), ck["opt"]
        print(f"resumed from {self.path}: {self.stages[self.at[0]]} step {self.at[1]}",
              flush=True)

    def first_step(self, stage):
        """The step `stage` starts from: the checkpoint's in its stage, else 0 (a stage
        before the checkpoint's: done)."""
        si = self.stages.index(stage)
        return self.at[1] if si == self.at[0] else (0 if si > self.at[0] else math.inf)

    def todo(self, stage, steps):
        """Whether `stage` has steps left (of `steps`)."""
        return not self.stopped and self.first_step(stage) < steps

    def batch_rng(self, stage):
        """A generator that draws one stage's batches in turn: default_rng(seed) from step 0,
        default_rng([seed, step]) from a resumed step (so a resumed run draws other batches
        than an uninterrupted one would)."""
        first = self.first_step(stage)
        return np.random.default_rng(self.seed if not first else [self.seed, int(first)])

    def step_rng(self, stage, step):
        """A generator for one step's batch, default_rng([seed, stage + 1, step]): a resumed
        run draws the same batches as an uninterrupted one."""
        return np.random.default_rng([self.seed, self.stages.index(stage) + 1, step])

    def fit(self, stage, params, *, lr, steps, loss, warmup=0, clip=None, progress=None,
            max_seconds=None):
        """Adam on `params` for `stage`'s steps (from where the run stands). `loss(step)` ->
        (the loss tensor, {name: float} parts logged with it); `clip`: the gradient norm's
        bound; `progress()` -> text added to the progress lines; `max_seconds`: stop after
        this many seconds of the run (all its resumes), checkpointed, `stopped` set."""
        if not self.todo(stage, steps):
            return
        si, first = self.stages.index(stage), self.first_step(stage)
        params = list(params)
        opt = torch.optim.Adam(params, lr=lr)
        if self._opt_state is not None and si == self.at[0]:
            opt.load_state_dict(self._opt_state)
        losses = self.log["losses"].setdefault(stage, [])
        spent = self.log.get("seconds", 0.0)
        t_start = t_print = t_ckpt = t_plot = time.time()
        for it in range(first, steps):
            rate = lr_cosine(lr, it, steps)
            if it < warmup:
                rate *= (it + 1) / warmup
            for g in opt.param_groups:
                g["lr"] = rate
            value, parts = loss(it)
            opt.zero_grad(set_to_none=True)
            value.backward()
            if clip is not None:
                torch.nn.utils.clip_grad_norm_(params, clip)
            opt.step()
            lv = float(value.detach())
            if not math.isfinite(lv):
                raise RuntimeError(f"{stage} step {it}: loss is {lv}")
            losses.append(lv)
            if parts:
                self.log["parts"].append(parts)
            now = time.time()
            self.log["seconds"] = spent + now - t_start
            last = it + 1 == steps
            self.stopped = bool(max_seconds) and self.log["seconds"] > max_seconds and not last
            done = it + 1 - first
            if now - t_print >= PROGRESS_S or last or self.stopped or done == 1:
                per_s = done / max(now - t_start, 1e-9)
                self.log["step_s"][stage] = 1.0 / per_s
                if not self.quiet:
                    extra = "".join(f"  {k} {v:.4f}" for k, v in parts.items())
                    extra += progress() if progress is not None else ""
                    print(f"[{stage}] step {it + 1}/{steps}  loss {lv:.4f} (last 20: "
                          f"{np.mean(losses[-20:]):.4f}){extra}  {per_s:.2f} it/s  "
                          f"elapsed {fmt_s(self.log['seconds'])}  "
                          f"ETA {fmt_s((steps - it - 1) / per_s)}", flush=True)
                t_print = now
            if now - t_plot >= PLOT_S or last or self.stopped:
                plot_losses(self.log["losses"], os.path.join(self.out, "loss.png"), self.stages)
                t_plot = now
            if now - t_ckpt >= CHECKPOINT_S or last or self.stopped:
                self._checkpoint(si, it + 1, opt)
                t_ckpt = now
            if self.stopped:
                print(f"stopped after {fmt_s(self.log['seconds'])} at {stage} step {it + 1}",
                      flush=True)
                break

    def _checkpoint(self, si, step, opt):
        save_checkpoint(self.path, {"stage": si, "step": step, "opt": opt.state_dict(),
                                    "models": {n: m.state_dict() for n, m in self.models.items()},
                                    "log": json.dumps(self.log)})

    def write_log(self):
        """train.json: the log (settings, losses, parts, seconds, and the recipe's keys)."""
        with open(os.path.join(self.out, "train.json"), "w") as f:
            json.dump(self.log, f, indent=1)


# ---- losses ---------------------------------------------------------------------------------

def l1(a, b, mask=None):
    """Mean absolute difference (over `mask`'s pixels when given, broadcast over channels)."""
    d = (a - b).abs()
    if mask is None:
        return d.mean()
    m = mask.expand_as(d).to(d.dtype)
    return (d * m).sum() / m.sum().clamp_min(1.0)


def ssim(a, b, window=7, c1=0.01 ** 2, c2=0.03 ** 2):
    """Mean SSIM of two N x C x H x W batches in [0, 1] with a uniform window (the
    differentiable form; clss.metrics' scikit-image SSIM is the evaluation's)."""
    pad = window // 2
    mu_a = F.avg_pool2d(a, window, 1, pad, count_include_pad=False)
    mu_b = F.avg_pool2d(b, window, 1, pad, count_include_pad=False)
    var_a = F.avg_pool2d(a * a, window, 1, pad, count_include_pad=False) - mu_a ** 2
    var_b = F.avg_pool2d(b * b, window, 1, pad, count_include_pad=False) - mu_b ** 2
    cov = F.avg_pool2d(a * b, window, 1, pad, count_include_pad=False) - mu_a * mu_b
    s = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a ** 2 + mu_b ** 2 + c1) * (var_a + var_b + c2))
    return s.mean()


def temporal(out, prev_out, ref, prev_ref):
    """L1 between the frame-to-frame changes of the output and of the reference: flicker
    the reference does not have (the training-side counterpart of eval's tPSNR)."""
    return ((out - prev_out) - (ref - prev_ref)).abs().mean()
