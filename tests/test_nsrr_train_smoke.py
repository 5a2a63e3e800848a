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
from weights_tools.__main__ import main  # noqa: E402
from helpers import tiny_sequence_npz  # noqa: E402


def _tiny(path, n=6):
    tiny_sequence_npz(path, n)


def test_train_nsrr_smoke_and_resume(tmp_path, capsys, dev):
    data = tmp_path / "data"
    data.mkdir()
    _tiny(str(data / "a.npz"))
    out = str(tmp_path / "run")
    args = ["train", "nsrr", "--data", str(data), "--out", out, "--batch", "2", "--patch", "16",
            "--margin", "2", "--candidates", "8", "--widths", "fast"]
    assert main(args + ["--steps", "2"]) == 0
    assert main(args + ["--steps", "3", "--resume", "--perceptual", "random"]) == 0
    text = capsys.readouterr().out
    assert "step 3/3" in text and "wrote" in text
    for f in ("loss.png", "train.json", "checkpoint.pt", "weights.safetensors"):
        assert os.path.isfile(os.path.join(out, f)), f
    cfg, w = nets.load(os.path.join(out, "weights.safetensors"))
    assert cfg["name"] == "fast" and json.load(open(os.path.join(out, "train.json")))["scale"] == 2
    up = clss.Upscaler(method="nsrr", scale=2, device=dev,
                       weights=os.path.join(out, "weights.safetensors"))
    z = np.load(str(data / "a.npz"))
    y = up.step(z["color"][0], z["depth"][0], z["motion"][0], tuple(z["jitter"][0]))
    assert y.shape == (32, 48, 3) and np.isfinite(y).all()
