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


def test_train_nss_gym_mode_smoke(tmp_path, capsys, dev):
    """--mode gym (the model gym's loss, warm-up and flips) trains, resumes and writes
    weights the OpenCL step loads."""
    flags = ["--batch", "2", "--patch", "8", "--margin", "4", "--window", "4", "--threads", "1",
             "--mode", "gym", "--filtered", "0.1"]
    seq, out = train_smoke(tmp_path, capsys, "nss", flags, 5)
    up = clss.Upscaler(method="nss", scale=2, device=dev,
                       weights=os.path.join(out, "weights.safetensors"))
    z = np.load(seq)
    assert np.isfinite(up.step(z["color"][0], z["depth"][0], z["motion"][0],
                               tuple(z["jitter"][0]))).all()


def test_gym_loss_parts():
    """The model gym's pieces: the spatial share rises over the window on a half cosine;
    the warp fetches the previous frame where the motion says (2 output px per render px),
    zero outside; a window flipped left-right is the mirrored render (jitter and motion
    negated along x), and flipping twice gives the window back."""
    import torch
    from weights_tools.methods.nss import recipe
    w = recipe.gym_weights(15)
    assert np.all(np.diff(w) > 0) and abs(w[-1] - 0.9) < 1e-9 and 0.001 <= w[0] < 0.02
    x = torch.arange(4 * 6, dtype=torch.float32).view(1, 1, 4, 6)
    mo = torch.zeros(1, 2, 2, 3)
    assert torch.allclose(recipe.warp_back(x, mo), x, atol=1e-5)
    mo[:, 0] = 0.5                                   # previous = p + 1 output px along x
    got = recipe.warp_back(x, mo)
    assert torch.allclose(got[..., :-1], x[..., 1:], atol=1e-5) and not got[..., -1].any()
    f = {"color": torch.rand(3, 4, 6), "depth": torch.rand(1, 4, 6),
         "motion": torch.rand(2, 4, 6), "ref": torch.rand(3, 8, 12), "jitter": (0.125, -0.25)}
    g = recipe.flip_frame(f, True, False)
    assert g["jitter"] == (-0.125, -0.25)
    assert torch.equal(g["motion"][0], -torch.flip(f["motion"][0], [-1]))
    assert torch.equal(g["motion"][1], torch.flip(f["motion"][1], [-1]))
    back = recipe.flip_frame(recipe.flip_frame(f, True, True), True, True)
    assert all(torch.equal(back[k], f[k]) for k in ("color", "depth", "motion", "ref"))
    assert back["jitter"] == f["jitter"]
