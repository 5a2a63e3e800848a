"""`python -m weights_tools train nsrd` on a tiny sequence with G-buffers: a few steps,
resume, and the weights it writes load into the OpenCL step (CI's smoke training of the
NSRD recipe); the ablation flags reach the weights' config."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

pytest.importorskip("torch")

import clss  # noqa: E402
from clss.methods.nsrd import networks as nets  # noqa: E402
from weights_tools.__main__ import main  # noqa: E402
from helpers import train_smoke  # noqa: E402

GB = ("albedo", "normal", "albedo_hr")


def test_train_nsrd_smoke_and_resume(tmp_path, capsys, dev):
    flags = ["--batch", "2", "--patch", "8", "--margin", "2", "--window", "3", "--widths", "fast",
             "--threads", "1"]
    seq, out = train_smoke(tmp_path, capsys, "nsrd", flags, 5, GB)
    cfg, w = nets.load(os.path.join(out, "weights.safetensors"))
    assert cfg["name"] == "fast" and cfg["scale"] == 2 and cfg["demod"] and cfg["mask"]
    assert json.load(open(os.path.join(out, "train.json")))["scale"] == 2
    up = clss.Upscaler(method="nsrd", scale=2, device=dev,
                       weights=os.path.join(out, "weights.safetensors"))
    z = np.load(seq)
    y = up.step(z["color"][0], z["depth"][0], z["motion"][0], tuple(z["jitter"][0]),
                **{k: z[k][0] for k in GB})
    assert y.shape == (32, 48, 3) and np.isfinite(y).all()
    out2 = str(tmp_path / "ablation")
    assert main(["train", "nsrd", "--data", os.path.dirname(seq), "--out", out2, *flags,
                 "--steps", "1", "--no-demod", "--no-mask"]) == 0
    cfg, _ = nets.load(os.path.join(out2, "weights.safetensors"))
    assert not cfg["demod"] and not cfg["mask"]
    # the guided base (networks.BASES), fine-tuned from the run above as make train-nsrd does
    out3 = str(tmp_path / "guided")
    assert main(["train", "nsrd", "--data", os.path.dirname(seq), "--out", out3, *flags,
                 "--steps", "1", "--base", "guided", "--remod", "learned",
                 "--init", os.path.join(out, "weights.safetensors")]) == 0
    cfg, _ = nets.load(os.path.join(out3, "weights.safetensors"))
    assert cfg["base"] == "guided" and cfg["remod"] == "learned"
    up = clss.Upscaler(method="nsrd", scale=2, device=dev,
                       weights=os.path.join(out3, "weights.safetensors"))
    y = up.step(z["color"][0], z["depth"][0], z["motion"][0], tuple(z["jitter"][0]),
                **{k: z[k][0] for k in GB})
    assert y.shape == (32, 48, 3) and np.isfinite(y).all()
