"""Is the history used now? PSNR (eval's tone-mapped display values) of frames 4+ with
4, 2 and 0 previous frames, and with the U-Net's correction off (base only)."""
import sys, glob, numpy as np, clss
from clss import metrics
from clss.methods.nsrr import networks as nets
cfg, w = nets.load(sys.argv[1])
w0 = dict(w); w0["un.9.weight"] = w["un.9.weight"] * 0; w0["un.9.bias"] = w["un.9.bias"] * 0
res = {}
for p in sorted(glob.glob(sys.argv[2]))[:int(sys.argv[3])]:
    z = np.load(p); s = float(z["scale"])
    for name, ww, hist in (("history 4", w, 4), ("history 2", w, 2), ("history 0", w, 0), ("base only", w0, 4)):
        up = clss.Upscaler(method="nsrr", scale=s, weights=(cfg, ww), history=hist)
        ps = []
        for t in range(len(z["color"])):
            y = up.step(z["color"][t], z["depth"][t], z["motion"][t], tuple(z["jitter"][t]), reset=bool(z["reset"][t]))
            if t >= 4: ps.append(metrics.psnr(y, z["reference"][t]))
        res.setdefault(name, []).append(np.mean(ps))
    print(p, {k: round(float(v[-1]), 3) for k, v in res.items()}, flush=True)
print("mean", {k: round(float(np.mean(v)), 3) for k, v in res.items()})
