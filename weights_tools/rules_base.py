"""The rules' base on the training side (issue 53 part 2): the methods that refine clss-rules
("base": "rules": NSRR's residual, NSS's mix; NSRD's "out_base": "rules") train their
torch twins on the clss-rules output as data. The rules have no learned parameters, so their output is computed once per
sequence by the shipped clss-rules frame step (OpenCL, `rules_outputs`) and cached beside
the data (`rules_cached`: DIR/rules-cache/<sequence>.<key>.npy; the key digests the rules'
sources, the scale and the sequence's content, so a change of the rules or the data
computes it again). The cache holds the rules' PQ colour (1.0 linear = PQ_NITS);
trainloop.pq_decode gives it back linear.
"""
from __future__ import annotations

import os

import numpy as np

from clss.pipeline.contract import PQ_NITS
from weights_tools.trainloop import parse_mix, per_sequence


# What the rules' output depends on: clss-rules' frame step, its kernels and constants
# (a change of any of them changes the cache key of the precomputed outputs).
RULES_SOURCES = ("clss/methods/clss/frame.cl", "clss/methods/clss/frame.py",
                 "clss/methods/clss/contract.py", "clss/methods/clss/upscaler.py",
                 "clss/pipeline/contract.py", "kernels/common.h", "kernels/pq.h")


def rules_key(scale, nits=PQ_NITS) -> str:
    """A digest of the rules' sources (RULES_SOURCES), the scale and the PQ scale."""
    import hashlib
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    h = hashlib.sha256(f"clss-rules x{float(scale):g} nits {float(nits):g}".encode())
    for rel in RULES_SOURCES:
        with open(os.path.join(root, rel), "rb") as fh:
            h.update(rel.encode() + b"\0" + fh.read())
    return h.hexdigest()[:16]


def rules_outputs(seq, scale, nits=PQ_NITS, device=None) -> np.ndarray:
    """The clss-rules method's PQ output of every frame of `seq` (DATA.md arrays: color,
    depth, motion, jitter, reset) as [T, 3, H, W] float32: the shipped rule-mode frame step
    (OpenCL, fp32) run over the sequence, reset at its resets, its history's PQ colour
    (what NSRR's step feeds its network with "base": "rules")."""
    import clss
    # fp32 whatever the device (the default "auto" would pick fp16 on a GPU; the cache key
    # holds no precision)
    up = clss.Upscaler(method="clss-rules", scale=float(scale), device=device, nits=nits,
                       precision="fp32")
    out = []
    resets = np.asarray(seq["reset"], bool)
    for t in range(len(resets)):
        up.step(seq["color"][t], seq["depth"][t], seq["motion"][t], tuple(seq["jitter"][t]),
                reset=bool(resets[t]) or t == 0)
        out.append(up.state["history"][0, :3])
    return np.stack(out).astype(np.float32)


def _digest(seq) -> str:
    import hashlib
    h = hashlib.sha256()
    for k in ("color", "depth", "motion", "jitter", "reset"):
        a = np.ascontiguousarray(seq[k])
        h.update(f"{k} {a.dtype} {a.shape}".encode() + a.tobytes())
    return h.hexdigest()[:16]


def rules_cached(seqs, data, torch, log=print):
    """[T,3,H,W] torch tensors of the clss-rules output (PQ) of every sequence (a mix's
    repeats share one), from DIR/rules-cache/ beside the sequence's file, computed with
    rules_outputs and written there where missing (module doc)."""
    dirs = [d for d, _ in parse_mix(data)]
    made = [0, 0]

    def one(s):
        home = next((d for d in dirs if os.path.exists(os.path.join(d, s["name"]))), dirs[0])
        stem = os.path.splitext(s["name"])[0]
        path = os.path.join(home, "rules-cache",
                            f"{stem}.{rules_key(s['scale'])}{_digest(s)}.npy")
        if os.path.exists(path):
            made[0] += 1
            return torch.from_numpy(np.load(path))
        out = rules_outputs(s, s["scale"])
        os.makedirs(os.path.dirname(path), exist_ok=True)
        tmp = path + ".tmp.npy"
        np.save(tmp, out)
        os.replace(tmp, path)
        made[1] += 1
        return torch.from_numpy(out)
    out = per_sequence(seqs, one)
    log(f"rules' base: {made[0]} sequences from the cache, {made[1]} computed", flush=True)
    return out
