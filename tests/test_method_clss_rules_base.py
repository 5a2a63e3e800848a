"""CLSS's rules' base (config "base": "rules", clss.methods.clss.networks.BASES; issue 53,
docs/methods/clss.md "The rules' base"): net mode with clss-rules' decision and cap, the
composition MLP correcting the rules' weight 1/(1+n) as 1/(1 + n exp(-z)).

* With the MLP's last layer at zero (z = 0) the OpenCL net step is the OpenCL rule step:
  output within 1e-6 relative, history colour and range within 1e-6, the counters equal;
  the ONNX twin's net graph equals its rule graph to the bit.
* With a non-zero correction the OpenCL step matches its ONNX twin (the oracle graph with
  base="rules") and its torch twin at the frame tests' tolerances (helpers.compare_frame).
* The config travels with the weights file (metadata entry networks.CONFIG_KEY); files
  without it run the paper's form as before.
"""
from __future__ import annotations

import numpy as np
import pytest

from clss import Upscaler
from clss.methods.clss.networks import (CONFIG_KEY, build_classifier, build_composition,
                                        read_config, save_networks)
from clss.methods.clss.oracle import OracleUpscaler
from clss.networks import apply_weights, model_weights
from helpers import RENDER, RESET_AT, compare_frame, frames

SEED = 3


def _tensors(zero_last=False, z_scale=1.0):
    """The seed-3 init; `zero_last`: the composition's last layer at zero (the untrained
    correction), else scaled by `z_scale` (a correction of a few tenths in z)."""
    t = {**model_weights(build_classifier(seed=SEED)),
         **model_weights(build_composition(seed=SEED))}
    for k in ("comp.fc2.weight", "comp.fc2.bias"):
        t[k] = np.zeros_like(t[k]) if zero_last else (t[k] * np.float32(z_scale))
    return t


def _onnx(t):
    cls, comp = build_classifier(seed=SEED), build_composition(seed=SEED)
    apply_weights(cls, t, strict=True)
    apply_weights(comp, t, strict=True)
    return cls, comp


def _run(up, seq):
    outs, hists = [], []
    for i, f in enumerate(seq):
        outs.append(up.step(f.color, f.depth, f.motion, f.jitter, reset=i == RESET_AT))
        hists.append(up.state["history"][0].copy())
    return outs, hists


def test_untrained_correction_is_the_rules():
    seq = frames()
    cls, comp = _onnx(_tensors(zero_last=True))
    net = Upscaler(2.0, mode="net", classifier=cls, composition=comp, base="rules")
    rules = Upscaler(2.0, mode="rules")
    a, ha = _run(net, seq)
    b, hb = _run(rules, seq)
    for i in range(len(seq)):
        np.testing.assert_allclose(a[i], b[i], rtol=1e-6, atol=1e-7, err_msg=f"frame {i}")
        np.testing.assert_array_equal(ha[i][3], hb[i][3], err_msg=f"frame {i} counter")
        np.testing.assert_allclose(ha[i][:10], hb[i][:10], rtol=0, atol=1e-6,
                                   err_msg=f"frame {i} history")


def test_untrained_correction_is_the_rules_in_the_oracle():
    import onnxruntime as ort
    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    seq = frames()
    cls, comp = _onnx(_tensors(zero_last=True))
    net = OracleUpscaler(RENDER, 2.0, "net", cls, comp, base="rules", session_options=so)
    rules = OracleUpscaler(RENDER, 2.0, "rule", session_options=so)
    a, ha = _run(net, seq)
    b, hb = _run(rules, seq)
    for i in range(len(seq)):
        np.testing.assert_array_equal(a[i], b[i], err_msg=f"frame {i}")
        np.testing.assert_array_equal(ha[i][:10], hb[i][:10], err_msg=f"frame {i} history")


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_rules_base_matches_oracle(precision):
    import onnxruntime as ort
    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    seq = frames()
    cls, comp = _onnx(_tensors(z_scale=0.3))
    ours = Upscaler(2.0, mode="net", classifier=cls, composition=comp, base="rules",
                    precision=precision)
    ora = OracleUpscaler(RENDER, 2.0, "net", cls, comp, base="rules", session_options=so)
    moved = 0.0
    for i, f in enumerate(seq):
        reset = i == RESET_AT
        a = ours.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        b = ora.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        compare_frame(a, b, ours.state["history"][0], ora.state["history"][0], precision,
                      "net", f"rules base {precision} frame {i}")
        w = ora.state["history"][0][3]
        moved = max(moved, float(w.max()))
    assert 1.0 <= moved <= 4.0      # the counter runs, under the rules' cap


def test_rules_base_torch_twin_matches_upscaler():
    torch = pytest.importorskip("torch")
    from weights_tools.methods.clss import twin as clss_twin
    torch.set_num_threads(2)
    t = _tensors(z_scale=0.3)
    cls, comp = _onnx(t)
    ours = Upscaler(2.0, mode="net", classifier=cls, composition=comp, base="rules")
    tw = clss_twin.TorchUpscaler(2.0, "net", weights=t, device="cpu", base="rules")
    rules = Upscaler(2.0, mode="rules")
    differs = 0.0
    for i, f in enumerate(frames()):
        reset = i == RESET_AT
        a = tw.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        b = ours.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        c = rules.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        compare_frame(a, b, tw.state["history"][0], ours.state["history"][0], "fp32", "net",
                      f"twin rules base frame {i}")
        differs = max(differs, float(np.abs(b - c).max()))
    assert differs > 1e-3       # the correction is exercised (not the rules' output)


def test_config_travels_with_the_weights(tmp_path):
    t = _tensors(zero_last=True)
    plain, based = tmp_path / "plain.safetensors", tmp_path / "rules.safetensors"
    save_networks(t, plain)
    save_networks(t, based, {"base": "rules"})
    assert read_config(plain) == {} and read_config(based) == {"base": "rules"}
    from safetensors import safe_open
    with safe_open(str(based), "np") as f:
        assert CONFIG_KEY in f.metadata()
    seq = frames()[:3]
    up = Upscaler(2.0, mode="net", weights=str(based))
    assert up.base == "rules" and up.cap is None
    rules = Upscaler(2.0, mode="rules")
    a, _ = _run(up, seq)
    b, _ = _run(rules, seq)
    np.testing.assert_allclose(a[-1], b[-1], rtol=1e-6, atol=1e-7)
    assert Upscaler(2.0, mode="net", weights=str(plain)).base == "paper"
    # the shipped file of before the key: the paper's form
    assert Upscaler(2.0, mode="net", weights=str(plain), base="rules").base == "rules"
    with pytest.raises(ValueError, match="base"):
        Upscaler(2.0, mode="net", weights=str(plain), base="bilinear")
    with pytest.raises(ValueError, match="base"):
        Upscaler(2.0, mode="rules", base="rules")


def test_train_rules_base_smoke(tmp_path):
    """`train clss --base rules` from a paper-form --init: the correction starts at zero,
    the written file carries the config, the logits' first-layer weights stay at zero with
    --comp-no-logits, the result runs in clss.Upscaler."""
    pytest.importorskip("torch")
    from test_train_smoke import write_tiny_sequence
    from clss.networks import load_weights, save_weights
    from weights_tools.__main__ import main
    data = tmp_path / "data"
    data.mkdir()
    write_tiny_sequence(str(data / "a.npz"), seed=0)
    init = tmp_path / "paper.safetensors"
    save_weights(_tensors(), str(init))
    out = tmp_path / "run"
    args = ["train", "clss", "--data", str(data), "--out", str(out), "--init", str(init),
            "--base", "rules", "--cls-steps", "0", "--comp-steps", "2", "--batch", "2",
            "--patch", "16", "--frames", "4", "--candidates", "12", "--keep", "1",
            "--weight-loss", "0", "--comp-no-logits", "--threads", "1"]
    assert main(args) == 0
    w = out / "weights.safetensors"
    assert read_config(w) == {"base": "rules"}
    t, t0 = load_weights(str(w)), load_weights(str(init))
    assert np.abs(t["comp.fc2.weight"]).max() < 0.01       # from zero, 2 steps of 1e-3
    assert not np.array_equal(t["comp.fc2.weight"], t0["comp.fc2.weight"])
    assert (t["comp.fc1.weight"][:, 16:22] == 0).all()
    for k in t:         # the classifier kept (to the basis fold's rounding)
        if k.startswith("cls."):
            np.testing.assert_allclose(t[k], t0[k], rtol=1e-4, atol=1e-5, err_msg=k)
    up = Upscaler(2.0, mode="net", weights=str(w))
    assert up.base == "rules"
    f = frames()[0]
    assert np.isfinite(up.step(f.color, f.depth, f.motion, f.jitter)).all()
