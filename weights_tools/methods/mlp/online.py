"""The online learning curve of the shader MLP (clss/methods/mlp/online.py): a renderer
that keeps drawing the first half of a sequence (frames 0..T/2-1, looped) with a reference
every frame trains the network on the device while it upscales; the second half (never
trained on) is scored after 0, 1, 2, 4, ..., `frames` training frames, against bicubic and,
if given, the per-scene offline weights (`train mlp --scene SEQ --score`).

    python -m weights_tools.methods.mlp.online SEQ.npz --out DIR [--frames 64]
        [--start shipped|scratch|FILE] [--steps K] [--batch P] [--lr LR] [--offline FILE]

Writes DIR/online.json and DIR/online.png (second-half PSNR and training loss against
frame number).
"""
from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m weights_tools.methods.mlp.online")
    p.add_argument("seq")
    p.add_argument("--out", required=True)
    p.add_argument("--frames", type=int, default=64)
    p.add_argument("--start", default="shipped", help="shipped, scratch or a .safetensors")
    p.add_argument("--steps", type=int, default=1)
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--offline", default=None, help="per-scene offline weights to compare with")
    p.add_argument("--no-feature", action="store_true")
    a = p.parse_args(argv)
    import clss
    from clss.device import get_device
    from .recipe import score_second_half
    os.makedirs(a.out, exist_ok=True)
    seq = np.load(a.seq)
    T = seq["color"].shape[0]
    s = int(round(float(seq["scale"])))
    feature = not a.no_feature
    name = "mlp" if feature else "mlp-nofeature"
    dev = get_device(None)
    # fp32, as the learning was measured (the default "auto" would store fp16 on a GPU)
    up = clss.Upscaler(method=name, scale=s, device=dev, precision="fp32", online=True,
                       online_steps=a.steps, online_batch=a.batch, online_lr=a.lr,
                       weights=None if a.start == "shipped" else a.start)
    quiet = open(os.devnull, "w")

    def score():
        return score_second_half(a.seq, up.learnt_tensors(), feature, log=quiet.write)[name]

    checkpoints = {0} | {2 ** k for k in range(10) if 2 ** k <= a.frames} | {a.frames}
    curve, losses, t_train = [], [], 0.0
    base = score_second_half(a.seq, up.learnt_tensors(), feature, log=quiet.write)
    curve.append((0, base[name]))
    print(f"{os.path.basename(a.seq)} x{s} start {a.start}: bicubic {base['bicubic']:.2f} dB, "
          f"frame 0 {base[name]:.2f} dB", flush=True)
    for k in range(1, a.frames + 1):
        t = (k - 1) % (T // 2)
        kw = {"depth_hr": seq["depth_hr"][t]} if feature else {}
        t0 = time.perf_counter()
        losses.append(up.train_step(seq["color"][t], seq["reference"][t], **kw))
        t_train += time.perf_counter() - t0
        if k in checkpoints:
            curve.append((k, score()))
            print(f"  after {k} frames: {curve[-1][1]:.2f} dB (L1 {losses[-1]:.5f})", flush=True)
    res = {"seq": a.seq, "scale": s, "start": a.start, "steps": a.steps, "batch": a.batch,
           "lr": a.lr, "bicubic": base["bicubic"], "curve": curve, "loss": losses,
           "train_s_per_frame": t_train / a.frames}
    if a.offline:
        res["offline"] = score_second_half(a.seq, a.offline, feature, log=quiet.write)[name]
        res["gap_db"] = res["offline"] - curve[-1][1]
        print(f"  per-scene offline {res['offline']:.2f} dB; online is {res['gap_db']:+.2f} dB "
              f"below", flush=True)
    with open(os.path.join(a.out, "online.json"), "w") as f:
        json.dump(res, f, indent=1)
    _plot(res, os.path.join(a.out, "online.png"))
    return 0


def _plot(res, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    x, y = zip(*res["curve"])
    ax[0].plot(x, y, "o-", label=f"online from {res['start']}")
    ax[0].axhline(res["bicubic"], color="gray", ls=":", label="bicubic")
    if "offline" in res:
        ax[0].axhline(res["offline"], color="k", ls="--", label="per-scene offline")
    ax[0].set_xlabel("training frames")
    ax[0].set_ylabel("PSNR, second half (dB)")
    ax[0].legend(fontsize=8)
    ax[1].plot(range(1, len(res["loss"]) + 1), res["loss"])
    ax[1].set_xlabel("frame")
    ax[1].set_ylabel("L1 (PQ), the frame's patches")
    fig.suptitle(f"{os.path.basename(res['seq'])} x{res['scale']}: online, "
                 f"{res['steps']} step(s) x {res['batch']} patches per frame")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
