"""Train the shader MLP upscaler (`python -m weights_tools train mlp`): offline, in torch,
on the torch twin of the frame step (weights_tools/methods/mlp/twin.py), with the seed's L1 loss
and its patch acceptance by gradient.

  generalist:  train mlp --data out/data/train2 --out out/mlp/gen2       (every sequence)
  per scene:   train mlp --scene seq.npz --out out/mlp/scene             (the first half of
               its frames; `--score` then scores the second half against bicubic)

Patches: accepted by gradient, the rule of clss/methods/mlp/patches.py (written once for
this recipe and the online training on the device). The loss is L1 in the
PQ domain on the folded output, over the patch's interior (where the crop gives exactly the
whole-frame result). Adam, cosine learning rate (the loop of weights_tools/trainloop.py).
Writes OUT/mlp.safetensors, loss.png, train.json and checkpoint.pt (--resume continues).
"""
from __future__ import annotations

import json
import os
import sys

import numpy as np

# the patch geometry and the acceptance rule: clss/methods/mlp/patches.py (shared with the
# online training on the device)
from clss.methods.mlp.patches import MARGIN, PATCH  # noqa: E402
from weights_tools.methods import Recipe  # noqa: E402


def add_arguments(p):
    p.add_argument("--data", default=None, help="a directory of DATA.md sequences (generalist)"
                   "; or a mix DIR[:SHARE],... (weights_tools/DATA.md)")
    p.add_argument("--scene", default=None, metavar="SEQ.npz",
                   help="per-scene weights: train on the first half of this sequence's frames")
    # imported here, not at the top: online.py imports this module and needs no torch
    from weights_tools.trainloop import add_arguments as add_run_arguments
    add_run_arguments(p, weights="mlp.safetensors")
    p.add_argument("--steps", type=int, default=3000)
    p.add_argument("--batch", type=int, default=32, help="patches per step")
    p.add_argument("--lr", type=float, default=2e-3)
    p.add_argument("--no-feature", action="store_true",
                   help="the ablation: feature inputs zeroed (method mlp-nofeature)")
    p.add_argument("--init", default=None, help="start from these weights (.safetensors)")
    p.add_argument("--jitter", action="store_true",
                   help="give fc1 the frame's jitter as two more inputs (zero-initialised "
                   "from an --init file without them; kept from one with them)")
    p.add_argument("--score", action="store_true",
                   help="with --scene: score the second half (PSNR) against bicubic")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def _prepare(seqs, feature):
    """PQ-encoded tensors per sequence, and each frame's gradient map's integral image."""
    import torch
    from clss.methods.mlp.patches import gradient_integral
    from clss.pipeline.contract import pq_encode
    from weights_tools.trainloop import per_sequence

    def one(s):
        c = torch.from_numpy(pq_encode(s["color"]).transpose(0, 3, 1, 2).copy())
        r = torch.from_numpy(pq_encode(s["reference"]).transpose(0, 3, 1, 2).copy())
        f = torch.from_numpy(np.asarray(s["depth_hr"], np.float32)[:, None].copy()) \
            if feature else None
        integ = gradient_integral(r.numpy().transpose(0, 2, 3, 1))
        j = torch.from_numpy(np.asarray(s["jitter"], np.float32).reshape(-1, 2)) \
            if "jitter" in s else torch.zeros(c.shape[0], 2)
        return {"color": c, "ref": r, "feat": f, "integ": integ, "name": s["name"], "jitter": j}
    return per_sequence(seqs, one)


class Sampler:
    """Patches accepted by gradient (clss.methods.mlp.patches), as torch crops, drawn with
    the generator `rng`."""

    def __init__(self, data, frames, scale, rng):
        from clss.methods.mlp.patches import Sampler as Rule
        self.data, self.s = data, scale
        self.rule = Rule([tuple(d["color"].shape[2:]) for d in data], frames,
                         lambda k, t: data[k]["integ"][t], scale, rng=rng)

    @property
    def tried(self):
        return self.rule.tried

    @property
    def accepted(self):
        return self.rule.accepted

    def batch(self, n):
        import torch
        cs, fs, rs, js = [], [], [], []
        s, size = self.s, PATCH + 2 * MARGIN
        while len(cs) < n:
            k, t, i0, j0 = self.rule.draw()
            d = self.data[k]
            cs.append(d["color"][t, :, i0:i0 + size, j0:j0 + size])
            if d["feat"] is not None:
                fs.append(d["feat"][t, :, s * i0:s * (i0 + size), s * j0:s * (j0 + size)])
            y0, x0 = s * (i0 + MARGIN), s * (j0 + MARGIN)
            rs.append(d["ref"][t, :, y0:y0 + s * PATCH, x0:x0 + s * PATCH])
            js.append(d["jitter"][t])
        return torch.stack(cs), (torch.stack(fs) if fs else None), torch.stack(rs), \
            torch.stack(js)


def train(run, data_seqs, frames, scale, *, feature=True, steps=3000, batch=32, lr=2e-3,
          seed=0, init=None, jitter=False):
    """The recipe on `run` (a trainloop.Run): the network, the patches and the L1 loss.
    Returns the trained tensors. `frames[k]` = (first, end) frame range of sequence k;
    jitter: the network takes each frame's jitter (transform.JITTER_KEY)."""
    from clss.methods.mlp import transform as tf
    from weights_tools.trainloop import l1
    from .twin import MlpNet
    data = _prepare(data_seqs, feature)
    net = MlpNet(scale, feature, tf.load_weights(init)[0] if init else None, jitter=jitter)
    if init is None:       # trainable from the start: small random output layer
        g = np.random.default_rng(seed)
        t = tf.init_weights(seed)
        t["fc3.weight"] = (g.standard_normal((25, 50)) * 0.01).astype(np.float32)
        net.load_tensors(t)
    run.track(net=net)
    sampler = Sampler(data, frames, scale, run.batch_rng("mlp"))
    s, m = scale, MARGIN

    def loss(it):
        c, f, r, j = sampler.batch(batch)
        out = net(c, f, j)[..., s * m:s * (m + PATCH), s * m:s * (m + PATCH)]
        return l1(out, r), {}

    run.fit("mlp", net.parameters(), lr=lr, steps=steps, loss=loss,
            progress=lambda: f"  accepted {sampler.accepted}/{sampler.tried}")
    return net.tensors()


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
    from clss.methods.mlp import transform as tf
    from weights_tools.trainloop import Run, TrainError, fmt_s, load_sequences
    feature = not a.no_feature
    need = ["color", "reference", "depth", "scale"] + (["depth_hr"] if feature else []) \
        + (["jitter"] if a.jitter else [])
    opt = () if a.jitter else ("jitter",)      # zeros where a sequence has none
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
            seqs = load_sequences(tmp, 2, need, optional=opt)
            shutil.rmtree(tmp)
            T = seqs[0]["color"].shape[0]
            frames = [(0, T // 2)]
        else:
            seqs = load_sequences(a.data, 1, need, optional=opt)
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
    run = Run(a, ("mlp",), quiet=a.quiet)
    tensors = train(run, seqs, frames, scale, feature=feature, steps=a.steps, batch=a.batch,
                    lr=a.lr, seed=a.seed, init=a.init, jitter=a.jitter)
    path = os.path.join(a.out, "mlp.safetensors")
    meta = {"recipe": "weights_tools/methods/mlp/recipe.py", "scale": scale, "feature": feature,
            "jitter": tf.has_jitter(tensors),
            "steps": a.steps, "batch": a.batch, "lr": a.lr, "seed": a.seed,
            "data": (os.path.basename(os.path.normpath(a.scene or a.data)) if "," not in
                     str(a.data) else a.data),     # a mix: its directories and shares
            "final_l1": round(float(np.mean(run.log["losses"]["mlp"][-100:])), 6)}
    tf.save_weights(tensors, path, meta)
    run.write_log()
    print(f"wrote {path} ({fmt_s(run.log['seconds'])}; {json.dumps(meta)})")
    if a.score and a.scene:
        score_second_half(a.scene, path, feature)
    return 0


RECIPE = Recipe(add_arguments, cmd_train, __doc__)
