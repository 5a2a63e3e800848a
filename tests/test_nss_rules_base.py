"""NSS's rules' base (clss/methods/nss/networks.py BASES "rules", issue 53 part 2): clss-rules'
frame step inside NSS's, its output 3 more network inputs and the base that the mix head
moves towards NSS's own accumulation. The OpenCL step against its whole-frame ONNX twin
(which inlines clss-rules' own twin) in fp32 and fp16 over a reset; with the mix head at
zero the step is clss-rules' bit for bit (fp32) whatever the rest of the network says;
the paper-form weights converted (networks.with_rules_base) keep their network; the torch
twin against the OpenCL step. Tolerances as tests/test_method_nss.py's."""
from __future__ import annotations

import numpy as np
import pytest

import clss
from clss import methods
from clss.methods.nss import networks as nets
from helpers import RESET_AT, frames

RENDER = (13, 17)


def _weights(seed=4, mix=True):
    cfg = nets.make_config(2.0, "mid", base="rules")
    w = nets.init_weights(cfg, seed=seed)
    w["kpn.weight"] = w["kpn.weight"] * 10
    w["tp.weight"] = w["tp.weight"] * 10
    if mix:     # a mix that varies across [0, 1] (clamped at both ends somewhere)
        g = np.random.default_rng(seed)
        w["mix.weight"] = g.normal(0, 0.3, w["mix.weight"].shape).astype(np.float32)
        w["mix.bias"] = np.float32([0.4])
    return cfg, w


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_rules_base_matches_its_onnx_twin(precision, dev):
    cfg, w = _weights()
    ours = clss.Upscaler(method="nss", scale=2, device=dev, precision=precision, weights=(cfg, w))
    twin = methods.twin("nss", RENDER, 2.0, weights=(cfg, w))
    assert {"rules_hist", "jitter"} <= {i.name for i in twin.model.graph.input}
    tol = 3e-4 if precision == "fp32" else 5e-3
    mixes = []
    for i, f in enumerate(frames(RENDER, 7, scale=2.0)):
        reset = i == RESET_AT
        a = ours.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        b = twin.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        d = np.abs(a - b).max()
        assert d <= tol * np.abs(b).max(), f"{precision} frame {i}: max |d| {d:.3g}"
        fs = ours._fs
        dh = np.abs(fs.dev.to_host(fs.hist) - twin.st["hist"][0]).max()
        assert dh <= 4 * tol * np.abs(twin.st["hist"]).max(), f"frame {i}: hist {dh:.3g}"
        mixes.append(twin.last["mix_out"])
    x = fs.dev.to_host(fs.x).astype(np.float32)
    assert x.shape[1] == nets.IN + nets.RULES_IN and x[0, nets.IN:].max() > 0
    m = np.concatenate([v.ravel() for v in mixes])
    assert (m < 0).any() and (m > 1).any() and ((m > 0) & (m < 1)).any()


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_zero_mix_is_clss_rules(precision, dev):
    """The mix head at zero: NSS's output is clss-rules' output, whatever its own
    accumulation (its network's other heads as trained, or here random)."""
    cfg, w = _weights(mix=False)
    assert not w["mix.weight"].any() and not w["mix.bias"].any()
    up = clss.Upscaler(method="nss", scale=2, device=dev, precision=precision, weights=(cfg, w))
    rules = clss.Upscaler(method="clss-rules", scale=2, device=dev, precision=precision)
    for i, f in enumerate(frames(RENDER, 6, scale=2.0)):
        a = up.step(f.color, f.depth, f.motion, f.jitter, reset=i == RESET_AT)
        b = rules.step(f.color, f.depth, f.motion, f.jitter, reset=i == RESET_AT)
        assert np.array_equal(a, b), f"{precision} frame {i}: max |d| {np.abs(a - b).max():.3g}"
    # and the twin's: the graph's zero mix is the rules' graph output
    twin = methods.twin("nss", RENDER, 2.0, weights=(cfg, w))
    rt = methods.twin("clss-rules", RENDER, 2.0)
    for i, f in enumerate(frames(RENDER, 3, scale=2.0)):
        a = twin.step(f.color, f.depth, f.motion, f.jitter)
        b = rt.step(f.color, f.depth, f.motion, f.jitter)
        assert np.array_equal(a, b), f"twin frame {i}"


def test_paper_weights_convert_to_the_rules_base():
    cfg = nets.make_config(2.0, "mid")
    w = nets.init_weights(cfg, seed=2)
    cfg2, w2 = nets.with_rules_base(cfg, w)
    assert nets.rules_base(cfg2) and not nets.rules_base(cfg) and cfg2["base"] == "rules"
    assert np.array_equal(w2["e0.weight"][:, :nets.IN], w["e0.weight"])
    assert not w2["e0.weight"][:, nets.IN:].any() and not w2["mix.weight"].any()
    assert nets.parameter_count(cfg2) == nets.parameter_count(cfg) + 32 * 3 * 9 + 16 * 9 + 1
    assert nets.with_rules_base(cfg2, w2)[0] == cfg2
    with pytest.raises(ValueError, match="base"):
        nets.make_config(2.0, "mid", base="bilinear")


def test_torch_twin_matches_the_opencl_step(dev):
    """The torch twin takes the rules' output as data (linear / exposure, [N,3,H,W]): here
    the OpenCL clss-rules step's own, as the recipe's cache holds it."""
    torch = pytest.importorskip("torch")
    from clss.pipeline.contract import to_internal, validate_frame
    from weights_tools.methods.nss.twin import NssNet, TorchStep
    torch.set_num_threads(1)
    cfg, w = _weights(seed=5)
    up = clss.Upscaler(method="nss", scale=2, device=dev, weights=(cfg, w))
    rules = clss.Upscaler(method="clss-rules", scale=2, device=dev)
    ts = TorchStep(NssNet(cfg, w))
    st = None
    for i, f in enumerate(frames(RENDER, 7, scale=2.0)):
        reset = i in (0, 4)
        a = up.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        r = rules.step(f.color, f.depth, f.motion, f.jitter, reset=reset)
        x = to_internal(validate_frame(f.color, f.depth, f.motion, f.jitter))
        with torch.no_grad():
            y, st = ts.step(torch.from_numpy(x["color"]), torch.from_numpy(x["depth"]),
                            torch.from_numpy(x["motion"]), [x["jitter"]], st,
                            torch.tensor([reset]),
                            rules=torch.from_numpy(np.ascontiguousarray(r.transpose(2, 0, 1)))[None])
        b = y[0].permute(1, 2, 0).numpy()
        d = np.abs(a - b).max()
        assert d <= 3e-4 * np.abs(b).max(), f"frame {i}: {d:.3g}"


def test_train_rules_base_smoke_from_paper_weights(tmp_path, capsys, dev):
    """`train nss --base rules --init <paper-form weights>`: the rules' output computed and
    cached beside the data, a few steps, resumed; the file carries the base, its e0 the
    paper weights' (the new channels trained from zero) and the OpenCL step loads it."""
    pytest.importorskip("torch")
    import os
    from helpers import train_smoke
    cfg0 = nets.make_config(2.0, "mid")
    w0 = nets.init_weights(cfg0, seed=1)
    init = str(tmp_path / "paper.safetensors")
    nets.save(init, cfg0, w0)
    flags = ["--batch", "1", "--patch", "8", "--margin", "4", "--window", "3", "--threads", "1",
             "--base", "rules", "--init", init, "--mix-l1", "0.01"]
    seq, out = train_smoke(tmp_path, capsys, "nss", flags, 4)
    assert os.listdir(os.path.join(os.path.dirname(seq), "rules-cache"))
    cfg, w = nets.load(os.path.join(out, "weights.safetensors"))
    assert nets.rules_base(cfg) and w["e0.weight"].shape[1] == nets.IN + nets.RULES_IN
    assert w["mix.weight"].any()            # the mix head moved off zero
    z = np.load(seq)
    up = clss.Upscaler(method="nss", scale=2, device=dev, weights=os.path.join(out, "weights.safetensors"))
    y = up.step(z["color"][0], z["depth"][0], z["motion"][0], tuple(z["jitter"][0]))
    assert np.isfinite(y).all()


def test_train_only_mix_holds_the_rest(tmp_path, capsys):
    """--only-mix trains the mix head alone: every other tensor is --init's."""
    pytest.importorskip("torch")
    import os
    from helpers import tiny_sequence_npz
    from weights_tools.__main__ import main
    cfg, w = nets.with_rules_base(nets.make_config(2.0, "mid"), nets.init_weights(nets.make_config(2.0, "mid"), 1))
    init = str(tmp_path / "rules.safetensors")
    nets.save(init, cfg, w)
    (tmp_path / "data").mkdir()
    tiny_sequence_npz(str(tmp_path / "data" / "a.npz"), 4)
    out = str(tmp_path / "run")
    assert main(["train", "nss", "--data", str(tmp_path / "data"), "--out", out, "--init", init,
                 "--only-mix", "--steps", "2", "--batch", "1", "--patch", "8", "--margin", "4",
                 "--window", "3", "--threads", "1"]) == 0
    _, w2 = nets.load(os.path.join(out, "weights.safetensors"))
    assert w2["mix.weight"].any()
    assert all(np.array_equal(w2[k], w[k]) for k in w if not k.startswith("mix."))
