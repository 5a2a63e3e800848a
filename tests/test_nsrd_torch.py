"""The torch twin of NSRD (weights_tools/methods/nsrd/twin.py) against the OpenCL frame step
(clss/methods/nsrd/) over 9 frames with a reset at frame 4, at 4x and 2x (the no-mask
ablation at 2x, the learned re-modulation at 4x): output within 1e-4 * max + 3e-4 * |ref| (fp32) on every pixel, the
carried state (render-res history, output lighting, ConvLSTM h) within 2e-5."""
from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import clss  # noqa: E402
from clss.methods.nsrd import networks as nets  # noqa: E402
from clss.pipeline.contract import to_internal, validate_frame  # noqa: E402
from helpers import frames  # noqa: E402
from weights_tools.methods.nsrd.twin import NsrdNet, TorchStep  # noqa: E402

RENDER = (13, 17)


def _t(a):
    return torch.from_numpy(np.ascontiguousarray(np.asarray(a, np.float32).transpose(2, 0, 1)[None]))


@pytest.mark.parametrize("scale,kw", [(4.0, {}), (2.0, {"mask": False}),
                                      (4.0, {"remod": "learned"}), (2.0, {"warp_state": True}),
                                      (3.0, {"base": "guided", "remod": "learned", "warp_state": True})])
def test_torch_twin_matches_the_opencl_step(scale, kw, dev):
    torch.set_num_threads(1)
    cfg = nets.make_config(scale, **kw)
    w = nets.init_weights(cfg, seed=5)
    w["out.weight"] = w["out.weight"] * 10
    up = clss.Upscaler(method="nsrd", scale=scale, device=dev, weights=(cfg, w))
    ts = TorchStep(NsrdNet(cfg, w))
    st = None
    for i, f in enumerate(frames(RENDER, 9, scale=scale)):
        reset = i in (0, 4)
        g = f.gbuffers
        a = up.step(f.color, f.depth, f.motion, f.jitter, reset=reset, albedo=g["albedo"],
                    normal=g["normal"], albedo_hr=g["albedo_hr"])
        x = to_internal(validate_frame(f.color, f.depth, f.motion, f.jitter))
        with torch.no_grad():
            y, st = ts.step(torch.from_numpy(x["color"]), torch.from_numpy(x["depth"]),
                            torch.from_numpy(x["motion"]), _t(g["albedo"]), _t(g["normal"]),
                            _t(g["albedo_hr"]), [x["jitter"]], st, torch.tensor([reset]))
        b = y[0].permute(1, 2, 0).numpy()
        assert (np.abs(a - b) <= 1e-4 * np.abs(b).max() + 3e-4 * np.abs(b)).all(), f"frame {i}"
        fs = up._fs
        for name, mine in (("state", fs.state), ("hist", fs.hist), ("h", fs.lstm[0])):
            ref = st[name][0].numpy()
            d = np.abs(fs.dev.to_host(mine).reshape(ref.shape) - ref).max()
            assert d <= 2e-5, f"{name}, frame {i}: {d:.3g}"
