"""Can a per-pixel predictor with more inputs than the classifier learn the useful decision
(issue 23, docs/training.md 2026-11-26)? Fit on val with the oracle running, then run it in
place of net mode's decision on held-out 0-7 and the Blender sequences (torch twin).
Run from the repository root: .venv/bin/python studies/2026-11-26-useful-decision-mlp.py"""
import sys, glob, os, json
sys.path.insert(0, '.')
import numpy as np, torch; torch.set_num_threads(1); torch.manual_seed(0)
from weights_tools.evaluate import Pipeline, evaluate_sequence, load_sequence
from weights_tools.methods.clss.twin import TorchUpscaler, pq_encode, PQ_NITS
W = 'clss/weights/clss_trained.safetensors'
from clss.networks import load_weights
w = load_weights(W)
def feats(ctx):
    up, h, hc = ctx["up"], ctx["hist"], ctx["hist_clipped"]
    mx = lambda x: x.abs().amax(1, keepdim=True)
    box = (ctx["clamp_max"] - ctx["clamp_min"]).amax(1, keepdim=True)
    f = [mx(h - up), mx(hc - up), mx(h - hc), box, ctx["dd_hr"], torch.log(ctx["depth_hr"].clamp(min=1e-4)),
         1.0 / (1.0 + ctx["counter"]), ctx["logits"], ctx["measure_hr"], up]
    return torch.cat(f, 1)  # [1, F, H, W]
class Step:
    def __init__(self, up, st): self.p, self.st = Pipeline(up), st
    def __call__(self, seq, t): self.st["t"] = t; return self.p(seq, t)
def run(paths, hook_factory):
    rows = []
    for p in paths:
        seq = load_sequence(p); st = {"t": 0, "seq": seq}
        up = TorchUpscaler(seq["scale"], "net", w, device="cpu", reject_hook=hook_factory(st))
        with open(os.devnull, "w") as q:
            rec = evaluate_sequence(seq, ["net"], None, warmup=2, run={"net": Step(up, st)}, net_trained=True, flip_every=0, log=q)
        m = rec["methods"]["net"]; rows.append((m["psnr"], m["tpsnr"], m["disocclusion_psnr"]))
    return np.mean(rows, 0).round(3).tolist()
def useful(st, ctx):
    ref = pq_encode(torch.from_numpy(np.ascontiguousarray(st["seq"]["reference"][st["t"]].transpose(2, 0, 1)))[None], PQ_NITS)
    from weights_tools.methods.clss.recipe import history_worse
    bad, eh, eu = history_worse(ctx["hist_clipped"], ctx["up"], ref, 2.0, 1e-3)
    return bad[:, None], eh[:, None], eu[:, None]
# 1) collect on val with the oracle decision running (so the history is the oracle's)
X, Y, C = [], [], []
rng = np.random.default_rng(0)
def collect(st):
    def f(reject, ctx):
        bad, eh, eu = useful(st, ctx)
        v = ctx["valid"][0, 0].reshape(-1).numpy()
        if st["t"] > 0:
            F_ = feats(ctx)[0].reshape(F_dim(ctx), -1).T.numpy()[v]
            idx = rng.choice(len(F_), size=min(4000, len(F_)), replace=False)
            X.append(F_[idx]); Y.append(bad[0, 0].reshape(-1).numpy()[v][idx])
            C.append((eh - eu).abs()[0, 0].reshape(-1).numpy()[v][idx])
        return bad
    return f
F_dim = lambda ctx: feats(ctx).shape[1]
val = sorted(glob.glob('out/data/val/*.npz'))
print("val with oracle", run(val, collect), flush=True)
X, Y, C = np.concatenate(X), np.concatenate(Y), np.concatenate(C)
print("pixels", len(X), "useful share", Y.mean(), flush=True)
Xt, Yt, Ct = map(torch.from_numpy, (X.astype(np.float32), Y.astype(np.float32), (C / C.mean()).astype(np.float32)))
mu, sd = Xt.mean(0), Xt.std(0) + 1e-6
net = torch.nn.Sequential(torch.nn.Linear(X.shape[1], 64), torch.nn.ReLU(), torch.nn.Linear(64, 64), torch.nn.ReLU(), torch.nn.Linear(64, 1))
opt = torch.optim.Adam(net.parameters(), 1e-3)
for it in range(3000):
    i = torch.randint(0, len(Xt), (4096,))
    z = net((Xt[i] - mu) / sd)[:, 0]
    loss = (torch.nn.functional.binary_cross_entropy_with_logits(z, Yt[i], reduction="none") * Ct[i]).mean()
    opt.zero_grad(); loss.backward(); opt.step()
with torch.no_grad():
    pr = (net((Xt - mu) / sd)[:, 0] > 0).numpy()
ba = lambda p, y: 0.5 * ((p & y).sum() / max(y.sum(), 1) + (~p & ~y).sum() / max((~y).sum(), 1))
print("train BA", ba(pr, Y.astype(bool)), flush=True)
def learned(st):
    def f(reject, ctx):
        F_ = feats(ctx)
        B, D, H, W_ = F_.shape
        with torch.no_grad():
            z = net((F_[0].reshape(D, -1).T - mu) / sd)[:, 0].reshape(1, 1, H, W_)
        return z > 0
    return f
ho = sorted(glob.glob('out/data/heldout/seq_000[0-7].npz'))
print("heldout8 learned", run(ho, learned), flush=True)
print("foliage learned", run(['weights_tools/validation/foliage.npz'], learned), flush=True)
print("interior learned", run(['weights_tools/validation/interior.npz'], learned), flush=True)
