"""The shader MLP's jitter input, 2026-11-28 (transform.JITTER_KEY; docs/methods/mlp.md, "The
jitter input"): the 2x generalist fine-tuned on the Blender mix with and without the
jitter input, scored through the torch twin on the validation splits.

    python studies/2026-11-28-mlp-jitter-input.py (jit|ctrl) STEPS OUT

From the shipped x2 file of 2026-11-27 (before the jitter input), `train mlp`'s recipe
(patches accepted by gradient, L1 in PQ, Adam at 5e-4 with a cosine decay, batch 32, one
torch thread) on `out/data/train,out/data/blender/train:0.75`; `jit` adds the zero-started
jitter input, `ctrl` trains the same steps without it. Prints the mean PSNR dB (linear,
clss.metrics.psnr, every frame) over out/data/blender/validation and out/data/val and writes
OUT/score.json. Measured (one thread each, 4-10 minutes):

| run | Blender validation | generated validation |
|---|---:|---:|
| the shipped file, no training | 27.87 | 25.68 |
| ctrl, 2400 steps | 27.92 | 25.69 |
| jit, 2400 steps | 28.47 | 26.06 |
| jit, 4800 steps (the recipe's MLP_JITTER_STEPS) | 28.56 | 26.08 |
"""
import json
import os
import sys

import numpy as np
import torch

from clss.evaluate import load_sequence
from clss.methods.mlp import transform as tf
from clss.metrics import psnr
from clss.pipeline.contract import pq_decode, pq_encode
from weights_tools.methods.mlp import recipe
from weights_tools.methods.mlp.twin import MlpNet
from weights_tools.trainloop import load_sequences

MIX = "out/data/train,out/data/blender/train:0.75"
INIT = "clss/weights/mlp_generalist_x2.safetensors"    # the 2026-11-27 file at the time


def score(net, d):
    res = {}
    for fn in sorted(f for f in os.listdir(d) if f.endswith(".npz")):
        q = load_sequence(os.path.join(d, fn))
        ps = []
        for t in range(q["color"].shape[0]):
            x = torch.from_numpy(pq_encode(q["color"][t]).transpose(2, 0, 1)[None].copy())
            f = torch.from_numpy(np.asarray(q["gbuffers"]["depth_hr"][t], np.float32)[None, None].copy())
            j = torch.from_numpy(np.asarray(q["jitter"][t], np.float32)[None])
            with torch.no_grad():
                y = net(x, f, j)[0].clamp(0, 1).numpy().transpose(1, 2, 0)
            ps.append(psnr(pq_decode(y), q["reference"][t]))
        res[fn] = float(np.mean(ps))
    return res


def main(mode, steps, out):
    torch.set_num_threads(1)
    os.makedirs(out, exist_ok=True)
    net = MlpNet(2, True, tf.load_weights(INIT)[0], jitter=mode == "jit")
    seqs = load_sequences(MIX, 1, ["color", "reference", "depth", "scale", "depth_hr", "jitter"])
    data = recipe._prepare(seqs, True)
    sampler = recipe.Sampler(data, [(0, s["color"].shape[0]) for s in seqs], 2,
                             np.random.default_rng(0))
    opt = torch.optim.Adam(net.parameters(), lr=5e-4)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps, 5e-5)
    s, m, P = 2, recipe.MARGIN, recipe.PATCH
    for it in range(steps):
        c, f, r, j = sampler.batch(32)
        loss = (net(c, f, j)[..., s * m:s * (m + P), s * m:s * (m + P)] - r).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    r = {"blender_val": score(net, "out/data/blender/validation"), "gen_val": score(net, "out/data/val")}
    for k, v in r.items():
        print(mode, steps, k, f"{np.mean(list(v.values())):.2f}")
    json.dump(r, open(os.path.join(out, "score.json"), "w"), indent=1)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), sys.argv[3])
