"""What every method's training shares (`python -m weights_tools train METHOD`): the
reading of DATA.md sequences, the learning-rate schedule, progress lines, loss.png,
atomic checkpoints, and the losses the papers use (L1, SSIM, temporal). A method's recipe
(weights_tools/train.py for CLSS) adds only its networks, its own losses and its steps.

Needs torch (the [train] extra)."""
from __future__ import annotations

import glob
import math
import os

import numpy as np
import torch
import torch.nn.functional as F

from clss.pipeline.contract import PQ_C1, PQ_C2, PQ_C3, PQ_M1, PQ_M2, PQ_NITS, PQ_PEAK_NITS

PROGRESS_S = 5.0        # seconds between progress lines
CHECKPOINT_S = 60.0     # seconds between checkpoints (and at the end of each stage)
PLOT_S = 30.0           # seconds between refreshes of loss.png


class TrainError(ValueError):
    """A user's mistake (bad directory, bad data, bad option): one line, no traceback."""


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

def load_sequences(data_dir, frames, required, prepare=None):
    """The DATA.md sequences of `data_dir` with at least `frames` frames and every key of
    `required`, as dicts of arrays with "scale" (an integer: patches are cut at the same
    place at render and output resolution) and "name". `prepare(seq)` converts a
    sequence in place (e.g. the reference to the training domain)."""
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
            s = {k: z[k] for k in required}
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
    scales = {s["scale"] for s in seqs}
    if len(scales) > 1:
        raise TrainError(f"--data: sequences at several scales {sorted(scales)}; train one scale")
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
