"""`python -m weights_tools train nss` on a tiny sequence: a few steps of short rollouts,
resume, and the weights it writes load into the OpenCL step (CI's smoke training of the
NSS recipe); a patch that is not a multiple of 8 is the one-line TrainError."""
from __future__ import annotations

import os

import numpy as np
import pytest

pytest.importorskip("torch")

import clss  # noqa: E402
from clss.methods.nss import networks as nets  # noqa: E402
from weights_tools.__main__ import main  # noqa: E402
from helpers import train_smoke  # noqa: E402


def test_train_nss_smoke_and_resume(tmp_path, capsys, dev):
    flags = ["--batch", "1", "--patch", "8", "--margin", "4", "--window", "3", "--threads", "1"]
    seq, out = train_smoke(tmp_path, capsys, "nss", flags, 4)
    cfg, w = nets.load(os.path.join(out, "weights.safetensors"))
    assert cfg["quality"] == "mid" and cfg["scale"] == 2
    up = clss.Upscaler(method="nss", scale=2, device=dev,
                       weights=os.path.join(out, "weights.safetensors"))
    z = np.load(seq)
    y = up.step(z["color"][0], z["depth"][0], z["motion"][0], tuple(z["jitter"][0]))
    assert y.shape == (32, 48, 3) and np.isfinite(y).all()
    assert main(["train", "nss", "--data", os.path.dirname(seq), "--out", str(tmp_path / "x"),
                 "--patch", "6", "--margin", "4", "--window", "3", "--steps", "1"]) == 1
    assert "multiple of 8" in capsys.readouterr().err


def test_train_nss_init_fine_tunes_and_names_a_bad_file(tmp_path, capsys):
    """--init starts from given weights (their config replaces --quality); a path that is
    no NSS weights file is the one-line error naming the flag."""
    flags = ["--batch", "1", "--patch", "8", "--margin", "4", "--window", "3", "--threads", "1"]
    seq, out = train_smoke(tmp_path, capsys, "nss", flags, 4)
    init = os.path.join(out, "weights.safetensors")
    data = os.path.dirname(seq)
    assert main(["train", "nss", "--data", data, "--out", str(tmp_path / "ft"), "--init", init,
                 "--quality", "high", "--steps", "1", *flags]) == 0
    cfg, _ = nets.load(str(tmp_path / "ft" / "weights.safetensors"))
    assert cfg["quality"] == "mid"              # the init's config, not --quality
    capsys.readouterr()
    for bad in (str(tmp_path / "missing.safetensors"), seq):
        assert main(["train", "nss", "--data", data, "--out", str(tmp_path / "x"), "--init", bad,
                     "--steps", "1", *flags]) == 1
        err = capsys.readouterr().err
        assert "--init" in err and "Traceback" not in err
