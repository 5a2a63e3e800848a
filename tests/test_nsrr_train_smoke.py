"""`python -m weights_tools train nsrr` on a tiny sequence: a few steps, resume, and the
weights it writes load into the OpenCL step (CI's smoke training of the NSRR recipe)."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

pytest.importorskip("torch")

import clss  # noqa: E402
from clss.methods.nsrr import networks as nets  # noqa: E402
from helpers import train_smoke  # noqa: E402


def test_train_nsrr_smoke_and_resume(tmp_path, capsys, dev):
    seq, out = train_smoke(tmp_path, capsys, "nsrr",
                           ["--batch", "2", "--patch", "16", "--margin", "2", "--candidates", "8",
                            "--widths", "fast"], 6, resume_flags=["--perceptual", "random"])
    cfg, w = nets.load(os.path.join(out, "weights.safetensors"))
    assert cfg["name"] == "fast" and json.load(open(os.path.join(out, "train.json")))["scale"] == 2
    up = clss.Upscaler(method="nsrr", scale=2, device=dev,
                       weights=os.path.join(out, "weights.safetensors"))
    z = np.load(seq)
    y = up.step(z["color"][0], z["depth"][0], z["motion"][0], tuple(z["jitter"][0]))
    assert y.shape == (32, 48, 3) and np.isfinite(y).all()
