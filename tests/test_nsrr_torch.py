"""The torch twin of NSRR (weights_tools/methods/nsrr/twin.py) against the OpenCL frame step
(clss/methods/nsrr/) over 9 frames with a reset at frame 4, in the zero and duplicate
reset fills: output within 1e-4 * max + 3e-4 * |ref| (fp32) on every pixel, history
within 1e-4. The rules' base ("base": "rules") too: the twin takes the rules' output as
data, from `rules_outputs` (the recipe's precompute: the OpenCL clss-rules step), and must
give what the OpenCL step computes with the rules inside it."""
from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import clss
from clss.methods.nsrr import networks as nets
from clss.pipeline.contract import to_internal, validate_frame
from helpers import frames, mover
from weights_tools.methods.nsrr.twin import NsrrNet, TorchStep, pq_decode, rgbd_of, rules_outputs

RENDER = (13, 17)


@pytest.mark.parametrize("fill,scale,act,reject,base", [("zero", 4.0, "leaky", "none", "bilinear"),
                                                        ("duplicate", 2.0, "relu", "none", "bilinear"),
                                                        ("zero", 2.0, "leaky", "depth", "bilinear"),
                                                        ("zero", 2.0, "leaky", "depth", "rules"),
                                                        ("zero", 4.0, "leaky", "depth", "rules")])
def test_torch_twin_matches_the_opencl_step(fill, scale, act, reject, base, dev):
    """reject "depth" runs on a moving square (helpers.mover), whose trail it empties."""
    torch.set_num_threads(1)
    cfg = nets.make_config("default", act=act, reject=reject, base=base)
    w = nets.init_weights(cfg, seed=5)
    # make the reweighting and the history matter: a non-trivial last layer
    w["un.9.weight"] = w["un.9.weight"] * 10
    up = clss.Upscaler(method="nsrr", scale=scale, device=dev, weights=(cfg, w), reset_fill=fill)
    ts = TorchStep(NsrrNet(cfg, w), scale, reset_fill=fill)
    hist, pdepth = None, None
    seq = frames(RENDER, 9, scale=scale) if reject == "none" else mover(RENDER, 9)
    rules = None
    if base == "rules":
        arrays = {k: np.stack([getattr(f, k) for f in seq]) for k in ("color", "depth", "motion", "jitter")}
        arrays["reset"] = np.isin(np.arange(len(seq)), (0, 4))
        rules = torch.from_numpy(rules_outputs(arrays, scale, device=dev))
    for i, f in enumerate(seq):
        reset = i in (0, 4)
        a = up.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        x = to_internal(validate_frame(f.color, f.depth, f.motion, f.jitter))
        with torch.no_grad():
            y, hist = ts.step(rgbd_of(torch.from_numpy(x["color"]), torch.from_numpy(x["depth"])),
                              torch.from_numpy(x["motion"]), [x["jitter"]], hist,
                              torch.tensor([reset]), pdepth,
                              None if rules is None else rules[i:i + 1])
        pdepth = torch.from_numpy(x["depth"])
        b = pq_decode(y.clamp(0, 1))[0].permute(1, 2, 0).numpy()
        # the PQ decode near its peak is ill-conditioned in float32 (x 6.3 exponent after a
        # cancellation): two float32 evaluations differ by up to 1.5e-4 relative there
        assert (np.abs(a - b) <= 1e-4 * np.abs(b).max() + 3e-4 * np.abs(b)).all(), f"frame {i}"
        fs = up._fs
        hd = fs.dev.to_host(fs.hist).reshape(-1, fs.Hp, fs.Wp)[:, :fs.H, :fs.W]
        assert np.abs(hd - hist[0].numpy()).max() <= 1e-4, f"history, frame {i}"
