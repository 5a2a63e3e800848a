"""NSRD's base without its network, 2026-11-28: how the current lighting upsampled to the
output pixels, times a material, scores against the reference (PSNR dB, every other frame
from the 5th), for the base (bilinear; guided: the 4x4 tent taps weighted by material
similarity, networks.BASES) and the material (filtered: the 3x3 binomial before the eps
rule; point: albedo_hr itself). docs/methods/nsrd.md, "The material-guided base".

    python studies/2026-11-28-nsrd-guided-base.py out/data/blender/validation/*.npz

numpy only, in float64; the shipped kernels' arithmetic is networks.guide_taps' (float32).
"""
import sys

import numpy as np

from clss import metrics
from clss.methods.nsrd import networks as nets
from clss.pipeline.contract import pq_decode, pq_encode


def mat(a):
    return np.where(a >= nets.DEMOD_EPS, a, 1.0)


def filt(a):
    p = np.pad(a, ((1, 1), (1, 1), (0, 0)), mode="edge")
    k = nets.MATERIAL_FILTER
    r = sum(k[i] * p[:, i:i + a.shape[1]] for i in range(3))
    return sum(k[i] * r[i:i + a.shape[0]] for i in range(3))


def base(d, t, guided, point, sig=0.3, rad=2):
    s = int(d["scale"])
    c, a, ahr = d["color"][t], d["albedo"][t], d["albedo_hr"][t]
    h, w = c.shape[:2]
    H, W = h * s, w * s
    ml = mat(a)
    L = pq_encode(c / ml)
    jx, jy = d["jitter"][t]
    bu = np.clip((np.arange(W) + 0.5) / s - 0.5 - jx, 0, w - 1)
    bv = np.clip((np.arange(H) + 0.5) / s - 0.5 - jy, 0, h - 1)
    b0, c0 = np.floor(bu).astype(int), np.floor(bv).astype(int)
    mp = mat(ahr)
    m = mp if point else mat(filt(ahr))
    acc, wsum = np.zeros((H, W, 3)), np.zeros((H, W, 1))
    if not guided:
        rad = 1
    for dy in range(-rad + 1, rad + 1):
        for dx in range(-rad + 1, rad + 1):
            yy, xx = np.clip(c0 + dy, 0, h - 1), np.clip(b0 + dx, 0, w - 1)
            wy = np.maximum(0, 1 - np.abs(bv - (c0 + dy)) / rad)
            wx = np.maximum(0, 1 - np.abs(bu - (b0 + dx)) / rad)
            wt = wy[:, None] * wx[None, :]
            if guided:
                wt = wt * (np.exp(-((ml[yy][:, xx] - mp) ** 2).sum(-1) / sig ** 2) + nets.GUIDE_FLOOR)
            acc += wt[..., None] * L[yy][:, xx]
            wsum += wt[..., None]
    return pq_decode(acc / wsum) * m


VARIANTS = {"bilinear, filtered": dict(guided=False, point=False),
            "bilinear, point": dict(guided=False, point=True),
            "guided 0.1, point": dict(guided=True, point=True, sig=0.1),
            "guided 0.2, point": dict(guided=True, point=True, sig=0.2),
            "guided 0.3, point": dict(guided=True, point=True, sig=0.3),
            "guided 0.5, point": dict(guided=True, point=True, sig=0.5)}

if __name__ == "__main__":
    rows = {k: [] for k in VARIANTS}
    for p in sys.argv[1:]:
        d = dict(np.load(p))
        for k, kw in VARIANTS.items():
            rows[k].append(np.mean([metrics.psnr(base(d, t, **kw), d["reference"][t])
                                    for t in range(4, len(d["color"]), 2)]))
    for k, v in rows.items():
        print(f"{k:22s} " + " ".join(f"{x:.2f}" for x in v) + f"   mean {np.mean(v):.2f}")
