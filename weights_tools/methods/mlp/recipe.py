"""Train the shader MLP upscaler (`python -m weights_tools train mlp`): offline, in torch,
on the torch twin of the frame step (weights_tools/mlp_torch.py), with the seed's L1 loss
and its patch acceptance by gradient.

  generalist:  train mlp --data out/data/train2 --out out/mlp/gen2       (every sequence)
  per scene:   train mlp --scene seq.npz --out out/mlp/scene             (the first half of
               its frames; `--score` then scores the second half against bicubic)

Patches: accepted by gradient, the rule of clss/methods/mlp/patches.py (written once for
this recipe and the online training on the device). The loss is L1 in the
PQ domain on the folded output, over the patch's interior (where the crop gives exactly the
whole-frame result). Adam, cosine learning rate. Writes OUT/mlp.safetensors and loss.png.
"""
from __future__ import annotations

import json
import os
import sys
import time

import numpy as np

# the patch geometry and the acceptance rule: clss/methods/mlp/patches.py (shared with the
# online training on the device)
from clss.methods.mlp.patches import MARGIN, PATCH  # noqa: E402
from weights_tools.methods import Recipe  # noqa: E402


def add_arguments(p):
    p.add_argument("--data", default=None, help="directory of DATA.md sequences (generalist)")
    p.add_argument("--scene", default=None, metavar="SEQ.npz",
                   help="per-scene weights: train on the first half of this sequence's frames")
    p.add_argument("--out", required=True, help="output directory (mlp.safetensors, loss.png)")
    p.add_argument("--steps", type=int, default=3000)
    p.add_argument("--batch", type=int, default=32, help="patches per step")
    p.add_argument("--lr", type=float, default=2e-3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-feature", action="store_true",
                   help="the ablation: feature inputs zeroed (method mlp-nofeature)")
    p.add_argument("--init", default=None, help="start from these weights (.safetensors)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--score", action="store_true",
                   help="with --scene: score the second half (PSNR) against bicubic")
    p.add_argument("--quiet", action="store_true")


def _prepare(seqs, feature):
    """PQ-encoded tensors per sequence, and each frame's gradient map's integral image."""
    import torch
    from clss.methods.mlp.patches import gradient_integral
    from clss.pipeline.contract import pq_encode
    out = []
    for s in seqs:
        c = torch.from_numpy(pq_encode(s["color"]).transpose(0, 3, 1, 2).copy())
        r = torch.from_numpy(pq_encode(s["reference"]).transpose(0, 3, 1, 2).copy())
        f = torch.from_numpy(np.asarray(s["depth_hr"], np.float32)[:, None].copy()) \
            if feature else None
        integ = gradient_integral(r.numpy().transpose(0, 2, 3, 1))
        out.append({"color": c, "ref": r, "feat": f, "integ": integ, "name": s["name"]})
    return out


class Sampler:
    """Patches accepted by gradient (clss.methods.mlp.patches), as torch crops."""

    def __init__(self, data, frames, scale, seed):
        from clss.methods.mlp.patches import Sampler as Rule
        self.data, self.s = data, scale
        self.rule = Rule([tuple(d["color"].shape[2:]) for d in data], frames,
                         lambda k, t: data[k]["integ"][t], scale, seed)

    @property
    def tried(self):
        return self.rule.tried

    @property
    def accepted(self):
        return self.rule.accepted

    def batch(self, n):
        import torch
        cs, fs, rs = [], [], []
        s, size = self.s, PATCH + 2 * MARGIN
        while len(cs) < n:
            k, t, i0, j0 = self.rule.draw()
            d = self.data[k]
            cs.append(d["color"][t, :, i0:i0 + size, j0:j0 + size])
            if d["feat"] is not None:
                fs.append(d["feat"][t, :, s * i0:s * (i0 + size), s * j0:s * (j0 + size)])
            y0, x0 = s * (i0 + MARGIN), s * (j0 + MARGIN)
            rs.append(d["ref"][t, :, y0:y0 + s * PATCH, x0:x0 + s * PATCH])
        return torch.stack(cs), (torch.stack(fs) if fs else None), torch.stack(rs)


def train(data_seqs, frames, scale, *, feature=True, steps=3000, batch=32, lr=2e-3, seed=0,
          init=None, log=print, quiet=False, plot_path=None):
    """Returns (tensors, history). `frames[k]` = (first, end) frame range of sequence k."""
    import torch
    from clss.methods.mlp import transform as tf
    from .twin import MlpNet
    from weights_tools.trainloop import PROGRESS_S, fmt_s, l1, lr_cosine, plot_losses
    torch.manual_seed(seed)
    data = _prepare(data_seqs, feature)
    net = MlpNet(scale, feature, tf.load_weights(init)[0] if init else None)
    if init is None:       # trainable from the start: small random output layer
        g = np.random.default_rng(seed)
        t = tf.init_weights(seed)
        t["fc3.weight"] = (g.standard_normal((25, 50)) * 0.01).astype(np.float32)
        net.load_tensors(t)
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    sampler = Sampler(data, frames, scale, seed)
    s, m = scale, MARGIN
    hist, t0, last = [], time.time(), 0.0
    for step in range(steps):
        for grp in opt.param_groups:
            grp["lr"] = lr_cosine(lr, step, steps)
        c, f, r = sampler.batch(batch)
        out = net(c, f)[..., s * m:s * (m + PATCH), s * m:s * (m + PATCH)]
        loss = l1(out, r)
        opt.zero_grad()
        loss.backward()
        opt.step()
        hist.append(loss.item())
        now = time.time()
        if not quiet and (now - last >= PROGRESS_S or step == steps - 1):
            last = now
            log(f"step {step + 1}/{steps}  L1 {np.mean(hist[-50:]):.5f}  accepted "
                f"{sampler.accepted}/{sampler.tried}  {fmt_s(now - t0)}")
    if plot_path:
        plot_losses({"L1 (PQ)": hist}, plot_path, ["L1 (PQ)"])
    return net.tensors(), hist


def score_second_half(path, weights, feature=True, log=print):
    """PSNR (the evaluation's, on display values) of the second half of a sequence's
    frames: bicubic and mlp with `weights` (the per-scene target)."""
    from clss.device import get_device
    from clss.evaluate import evaluate_sequence, load_sequence
    seq = load_sequence(path)
    T = seq["color"].shape[0]
    half = {k: (v[T // 2:] if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == T
                else v) for k, v in seq.items()}
    half["gbuffers"] = {k: v[T // 2:] for k, v in seq.get("gbuffers", {}).items()}
    half["reset"] = np.asarray(half["reset"]).copy()
    half["reset"][0] = True
    name = "mlp" if feature else "mlp-nofeature"
    rec = evaluate_sequence(half, ["bicubic", name], get_device(None), warmup=0,
                            net_kwargs={"weights": weights}, flip_every=0, log=open(os.devnull, "w"))
    res = {k: rec["methods"][k]["psnr"] for k in ("bicubic", name)}
    log(f"{os.path.basename(path)} frames {T // 2}-{T - 1}: bicubic {res['bicubic']:.2f} dB, "
        f"{name} {res[name]:.2f} dB ({res[name] - res['bicubic']:+.2f})")
    return res


def cmd_train(a):
    import torch
    from clss.methods.mlp import transform as tf
    from weights_tools.trainloop import TrainError, load_sequences
    torch.set_num_threads(max(1, a.threads))
    feature = not a.no_feature
    need = ["color", "reference", "depth", "scale"] + (["depth_hr"] if feature else [])
    try:
        if (a.data is None) == (a.scene is None):
            raise TrainError("give --data DIR (generalist) or --scene SEQ.npz (per scene)")
        if a.scene is not None:
            if not os.path.isfile(a.scene):
                raise TrainError(f"--scene: {a.scene} is not a file")
            import shutil
            import tempfile
            tmp = tempfile.mkdtemp()
            shutil.copy(a.scene, tmp)
            seqs = load_sequences(tmp, 2, need)
            shutil.rmtree(tmp)
            T = seqs[0]["color"].shape[0]
            frames = [(0, T // 2)]
        else:
            seqs = load_sequences(a.data, 1, need)
            frames = [(0, s["color"].shape[0]) for s in seqs]
        scale = seqs[0]["scale"]
        if scale not in tf.SCALES:
            raise TrainError(f"--data: scale {scale}; the mlp method runs at 2 and 3")
        if any(min(s["color"].shape[1:3]) < PATCH + 2 * MARGIN for s in seqs):
            raise TrainError(f"--data: frames smaller than {PATCH + 2 * MARGIN} render pixels")
        if a.steps < 1 or a.batch < 1:
            raise TrainError("--steps and --batch: at least 1")
    except TrainError as e:
        print(f"error: train mlp: {e}", file=sys.stderr)
        return 2
    os.makedirs(a.out, exist_ok=True)
    t0 = time.time()
    tensors, hist = train(seqs, frames, scale, feature=feature, steps=a.steps, batch=a.batch,
                          lr=a.lr, seed=a.seed, init=a.init, quiet=a.quiet,
                          plot_path=os.path.join(a.out, "loss.png"))
    path = os.path.join(a.out, "mlp.safetensors")
    meta = {"recipe": "weights_tools/mlp_train.py", "scale": scale, "feature": feature,
            "steps": a.steps, "batch": a.batch, "lr": a.lr, "seed": a.seed,
            "data": os.path.basename(os.path.normpath(a.scene or a.data)),
            "final_l1": round(float(np.mean(hist[-100:])), 6)}
    tf.save_weights(tensors, path, meta)
    print(f"wrote {path} ({time.time() - t0:.0f} s; {json.dumps(meta)})")
    if a.score and a.scene:
        score_second_half(a.scene, path, feature)
    return 0


RECIPE = Recipe(add_arguments, cmd_train, __doc__)
