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


def test_train_nsrr_fine_tunes_from_init(tmp_path, capsys):
    """--init: a fine-tune starts from a file's weights and config (issue 31's retraining
    on the Blender mix starts from the shipped weights); a missing file is one line."""
    from weights_tools.__main__ import main
    seq, out = train_smoke(tmp_path, capsys, "nsrr",
                           ["--batch", "2", "--patch", "16", "--margin", "2", "--candidates", "8",
                            "--widths", "fast"], 6)
    first = os.path.join(out, "weights.safetensors")
    out2 = str(tmp_path / "ft")
    args = ["train", "nsrr", "--data", os.path.dirname(seq), "--out", out2, "--batch", "2",
            "--patch", "16", "--margin", "2", "--candidates", "8", "--steps", "1"]
    assert main(args + ["--init", first]) == 0
    (c0, w0), (c1, w1) = nets.load(first), nets.load(os.path.join(out2, "weights.safetensors"))
    assert c1 == c0 and c1["name"] == "fast"            # the file's config, not --widths'
    assert 0 < max(float(np.abs(w1[k] - w0[k]).max()) for k in w0) < 0.1
    capsys.readouterr()
    assert main(args + ["--init", str(tmp_path / "none.safetensors")]) != 0
    err = capsys.readouterr().err
    assert "--init:" in err and "Traceback" not in err
    # --reject on a fine-tune: the file's tensors as they are (0 steps), the config gains
    # the rejection (the shipped x2's last stage); its output conv is not re-initialised
    out3 = str(tmp_path / "reject")
    args[args.index("--out") + 1] = out3
    args[args.index("--steps") + 1] = "0"
    assert main(args + ["--init", first, "--reject", "depth"]) == 0
    c3, w3 = nets.load(os.path.join(out3, "weights.safetensors"))
    assert c3 == {**c0, "reject": "depth"}
    assert all(np.array_equal(w3[k], w0[k]) for k in w0)


def test_train_nsrr_names_a_mix_sequence_too_small_for_the_patch(tmp_path, capsys):
    """Every sequence of a mix must hold a patch, not only the first: a smaller one is named
    in one line (make train-smoke's small Blender shards once crashed torch.stack)."""
    from weights_tools.__main__ import main
    from helpers import tiny_sequence_npz
    big, small = tmp_path / "big", tmp_path / "small"
    big.mkdir(), small.mkdir()
    tiny_sequence_npz(str(big / "a.npz"), 4)
    z = dict(np.load(big / "a.npz"))
    for k in ("color", "depth", "motion"):          # 16x24 -> 10x24 render, 20x48 output
        z[k] = z[k][:, :10]
    z["reference"] = z["reference"][:, :20]
    np.savez(small / "b.npz", **z)
    rc = main(["train", "nsrr", "--data", f"{big},{small}:0.5", "--out", str(tmp_path / "run"),
               "--batch", "2", "--patch", "16", "--margin", "2", "--candidates", "8",
               "--widths", "fast", "--steps", "1"])
    err = capsys.readouterr().err
    assert rc != 0 and "Traceback" not in err
    assert "does not fit the 10x24 frames of b" in err, err


def test_train_nsrr_rules_base_from_init(tmp_path, capsys, dev):
    """--base rules on a fine-tune (issue 53): the rules' output is computed once per
    sequence and cached beside the data (a second run reads it), the base's U-Net input
    channels and the output conv start at zero, so at 0 steps the OpenCL step's output is
    clss-rules'; one step then moves the new channels."""
    from weights_tools.__main__ import main
    seq, out = train_smoke(tmp_path, capsys, "nsrr",
                           ["--batch", "2", "--patch", "16", "--margin", "2", "--candidates", "8",
                            "--widths", "fast", "--reject", "depth"], 6)
    first = os.path.join(out, "weights.safetensors")
    args = ["train", "nsrr", "--data", os.path.dirname(seq), "--batch", "2", "--patch", "16",
            "--margin", "2", "--candidates", "8", "--init", first, "--base", "rules"]
    out0, out1 = str(tmp_path / "r0"), str(tmp_path / "r1")
    assert main(args + ["--out", out0, "--steps", "0"]) == 0
    assert "0 sequences from the cache, 1 computed" in capsys.readouterr().out
    cache = os.listdir(os.path.join(os.path.dirname(seq), "rules-cache"))
    assert len(cache) == 1 and cache[0].startswith("a.")
    assert main(args + ["--out", out1, "--steps", "1"]) == 0
    assert "1 sequences from the cache, 0 computed" in capsys.readouterr().out
    (c0, w0), (c, w), (c1, w1) = (nets.load(first), nets.load(os.path.join(out0, "weights.safetensors")),
                                  nets.load(os.path.join(out1, "weights.safetensors")))
    assert c == {**c0, "base": "rules"} and c1 == c
    k = w0["un.0.weight"].shape[1]
    assert w["un.0.weight"].shape[1] == k + 3 and not w["un.0.weight"][:, k:].any()
    assert np.array_equal(w["un.0.weight"][:, :k], w0["un.0.weight"])
    assert not w["un.9.weight"].any() and not w["un.9.bias"].any()
    assert w1["un.0.weight"][:, k:].any() or w1["un.9.weight"].any()
    z = np.load(seq)
    up = clss.Upscaler(method="nsrr", scale=2, device=dev, weights=os.path.join(out0, "weights.safetensors"))
    rules = clss.Upscaler(method="clss-rules", scale=2, device=dev)
    for t in range(3):
        f = (z["color"][t], z["depth"][t], z["motion"][t], tuple(z["jitter"][t]))
        a, b = up.step(*f), rules.step(*f)
        assert np.abs(a - b).max() <= 1e-5 * np.abs(b).max(), t
