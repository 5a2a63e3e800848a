"""The torch twin of NSS (weights_tools/methods/nss/twin.py) against the OpenCL frame step
(clss/methods/nss/) over 7 frames with a reset at frame 4, both kernel presets: output
within 3e-4 * max|ref| (fp32; the neighbourhood clamp's variance cancels, see
tests/test_method_nss.py), the carried derivative state within 1e-5."""
from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import clss  # noqa: E402
from clss.methods.nss import networks as nets  # noqa: E402
from clss.pipeline.contract import to_internal, validate_frame  # noqa: E402
from helpers import frames  # noqa: E402
from weights_tools.methods.nss.twin import NssNet, TorchStep  # noqa: E402

RENDER = (13, 17)


@pytest.mark.parametrize("quality", ["mid", "high"])
def test_torch_twin_matches_the_opencl_step(quality, dev):
    torch.set_num_threads(1)
    cfg = nets.make_config(2, quality)
    w = nets.init_weights(cfg, seed=5)
    w["kpn.weight"] = w["kpn.weight"] * 10
    w["tp.weight"] = w["tp.weight"] * 10
    up = clss.Upscaler(method="nss", scale=2, device=dev, weights=(cfg, w))
    ts = TorchStep(NssNet(cfg, w))
    st = None
    for i, f in enumerate(frames(RENDER, 7, scale=2.0)):
        reset = i in (0, 4)
        a = up.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        x = to_internal(validate_frame(f.color, f.depth, f.motion, f.jitter))
        with torch.no_grad():
            y, st = ts.step(torch.from_numpy(x["color"]), torch.from_numpy(x["depth"]),
                            torch.from_numpy(x["motion"]), [x["jitter"]], st,
                            torch.tensor([reset]))
        b = y[0].permute(1, 2, 0).numpy()
        d = np.abs(a - b).max()
        assert d <= 3e-4 * np.abs(b).max(), f"frame {i}: {d:.3g}"
        ref = st["deriv"][0].numpy()
        dd = np.abs(up._fs.dev.to_host(up._fs.deriv) - ref).max()
        assert dd <= 1e-5, f"deriv, frame {i}: {dd:.3g}"
