"""NSS's rules' base (docs/methods/nss.md, "The rules' base"): how much of NSS's own output
the gate lets through, and whether that share beats the rules, per sequence.

    .venv/bin/python studies/2026-11-29-nss-rules-mix.py WEIGHTS.safetensors SEQ.npz [SEQ.npz ...]

Runs the OpenCL `nss` step with WEIGHTS (config "base": "rules") and `clss-rules` side by
side over each sequence (reset at its resets), and prints per sequence, over the frames
after the warm-up (4 after a reset): the mean clamped mix (0 = clss-rules' output, 1 = NSS's
accumulation; the step's `mix` buffer, render resolution) and the mean squared error against
the reference of both outputs on Karis-tonemapped values (x / (1 + max channel)).
"""
from __future__ import annotations

import sys

import numpy as np

import clss

WARMUP = 4


def karis(x):
    x = np.clip(x, 0.0, None)
    return x / (1.0 + x.max(-1, keepdims=True))


def main(weights, paths):
    for path in paths:
        z = np.load(path)
        up = clss.Upscaler(method="nss", scale=2, weights=weights)
        rules = clss.Upscaler(method="clss-rules", scale=2)
        mix, err, since = [], {"nss": [], "rules": []}, 0
        for t in range(len(z["color"])):
            reset = bool(z["reset"][t]) or t == 0
            since = 0 if reset else since + 1
            args = (z["color"][t], z["depth"][t], z["motion"][t], tuple(z["jitter"][t]))
            a = up.step(*args, reset=reset)
            b = rules.step(*args, reset=reset)
            if since < WARMUP:
                continue
            fs = up._fs
            m = fs.dev.to_host(fs.mix).astype(np.float32)[0, 0, :fs.h, :fs.w]
            mix.append(np.clip(m, 0.0, 1.0).mean())
            ref = karis(z["reference"][t])
            err["nss"].append(np.mean((karis(a) - ref) ** 2))
            err["rules"].append(np.mean((karis(b) - ref) ** 2))
        print(f"{path.split('/')[-1]}: mean mix {np.mean(mix):.3f}, Karis MSE nss "
              f"{np.mean(err['nss']):.3g} rules {np.mean(err['rules']):.3g}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
