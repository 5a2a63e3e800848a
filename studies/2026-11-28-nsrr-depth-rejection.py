"""NSRR's depth rejection, 2026-11-28 (networks.REJECTS; docs/methods/nsrr.md, "The depth
rejection"): the torch twin of the frame step run over whole sequences with one weights
file and the rejection's threshold tau swept (-1: off).

    python studies/2026-11-28-nsrr-depth-rejection.py WEIGHTS TAUS SEQ.npz ...
    python studies/2026-11-28-nsrr-depth-rejection.py WEIGHTS TAUS --demo

Per tau: PSNR dB (tone-mapped, frames 4 on) of each sequence and their mean. --demo renders
`make demo`'s sample scene (clss.demo.scene, 30 frames, 480x270 -> 2x) and prints the mean signed
error per channel (tone-mapped) over the pixels that tau 0.1 calls disoccluded, frames 4 on:
the sphere's ghost is its blue there; and the same with no history at all.
"""
import sys

import numpy as np
import torch

from clss import metrics
from clss.methods.nsrr import networks as nets
from weights_tools.methods.nsrr import twin


def tm(x):
    return np.clip(x / (1 + x), 0, 1) ** (1 / 2.2)


def run(net, d, history=None):
    """Yields (t, output [H,W,3] linear, disoccluded [H,W] bool or None) for every frame."""
    st = twin.TorchStep(net, float(d["scale"]), history=history)
    hist, pd = None, None
    for t in range(len(d["color"])):
        c = torch.from_numpy(np.ascontiguousarray(d["color"][t].astype(np.float32).transpose(2, 0, 1)[None]))
        dep = torch.from_numpy(np.ascontiguousarray(d["depth"][t].astype(np.float32)[None, None]))
        mo = torch.from_numpy(np.ascontiguousarray(d["motion"][t].astype(np.float32).transpose(2, 0, 1)[None]))
        rgbd = twin.rgbd_of(c, dep)
        reset = bool(d["reset"][t]) or t == 0
        with torch.no_grad():
            y, hist = st.step(rgbd, mo, [d["jitter"][t]], hist, torch.tensor([reset]), pd)
            dis = None
            if pd is not None and not reset:
                m = twin.upsample_motion(mo, *y.shape[2:])
                dis = twin.depth_keep(dep, pd, m, [d["jitter"][t]], 0.1)[0, 0].numpy() == 0
        pd = rgbd[:, 3:4]
        yield t, twin.pq_decode(y.clamp(0, 1))[0].permute(1, 2, 0).numpy(), dis


def demo_sequence():
    from clss.demo import scene
    fr = scene.render_sequence(30, workers=2, gbuffers=False)
    return {"color": np.stack([f.color for f in fr]), "depth": np.stack([f.depth for f in fr]),
            "motion": np.stack([f.motion for f in fr]), "reset": np.array([f.reset for f in fr]),
            "jitter": np.array([f.jitter for f in fr], np.float32),
            "reference": np.stack([f.reference for f in fr]), "scale": np.float32(2)}


def main(argv):
    torch.set_num_threads(2)
    cfg, w = nets.load(argv[0])
    net = twin.NsrrNet(cfg, w)
    taus = [float(t) for t in argv[1].split(",")]
    demo = argv[2:] == ["--demo"]
    seqs = [demo_sequence()] if demo else [dict(np.load(p)) for p in argv[2:]]
    for tau in taus + (["no history"] if demo else []):
        history = 0 if tau == "no history" else None
        net.cfg["reject"] = "depth" if history is None and tau >= 0 else "none"
        if history is None:
            nets.REJECT_TAU = tau
        psnr, err = [], []
        for d in seqs:
            ps = []
            for t, out, dis in run(net, d, history):
                if t >= 4:
                    ps.append(metrics.psnr(out, d["reference"][t].astype(np.float32)))
                    if dis is not None:
                        err.append((tm(out) - tm(d["reference"][t].astype(np.float32)))[dis])
            psnr.append(np.mean(ps))
        line = f"tau {tau}: " + " ".join(f"{p:.2f}" for p in psnr) + f"  mean {np.mean(psnr):.3f}"
        if demo:
            e = np.concatenate(err)
            line += f"  disoccluded: signed error RGB {np.round(e.mean(0), 4)}, rms {np.sqrt((e ** 2).mean()):.4f}"
        print(line, flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
