import json
import struct

import numpy as np
import onnx
import pytest

from weights_tools import (CLASSIFIER_CHANNELS, COMPOSITION_CHANNELS, CLASSIFIER_INPUTS,
                           COMPOSITION_INPUTS, WeightsError, apply_weights, build_classifier,
                           build_composition, channel_slices, count_flops, frame_flops,
                           import_torch_state_dict, load_weights, model_weights, save_weights,
                           torch_to_onnx_name)
from weights_tools.__main__ import main

ALLOWED_OPS = {"Conv", "Relu", "LeakyRelu", "Sigmoid", "Add", "Concat", "Resize",
               "SpaceToDepth", "DepthToSpace"}


def _run(model, x):
    ort = pytest.importorskip("onnxruntime")
    s = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return s.run(None, {"x": x})[0]


def test_channel_tables_match_design():
    assert CLASSIFIER_CHANNELS == 27 and COMPOSITION_CHANNELS == 22
    cls = dict(CLASSIFIER_INPUTS)
    comp = dict(COMPOSITION_INPUTS)
    assert "depth_difference" in cls and "depth_difference" not in comp
    assert cls["warped_logits"] == 6 and comp["logits"] == 6
    sl = channel_slices(CLASSIFIER_INPUTS)
    assert sl["bicubic_color"] == slice(0, 3) and sl["warped_logits"] == slice(17, 23)
    # reference.md s4b: the measurements follow, in the kernel's order
    assert [n for n, _ in CLASSIFIER_INPUTS[-4:]] == ["prev_depth_difference", "color_change",
                                                      "depth_edge", "color_spread"]
    assert sl["color_spread"] == slice(26, 27)


@pytest.mark.parametrize("hw", [(None, None), (32, 48)])
def test_classifier_graph_runs(hw):
    m = build_classifier(height=hw[0], width=hw[1])
    onnx.checker.check_model(m, full_check=True)
    assert m.ir_version == 10 and m.opset_import[0].version <= 21
    assert {n.op_type for n in m.graph.node} <= ALLOWED_OPS
    x = np.random.default_rng(1).random((1, CLASSIFIER_CHANNELS, 32, 48), np.float32)
    y = _run(m, x)
    assert y.shape == (1, 6, 16, 24) and np.isfinite(y).all() and y.std() > 1e-3


def test_classifier_rejects_unpadded_size():
    with pytest.raises(ValueError, match="multiple of 16"):
        build_classifier(height=540, width=960)


def test_composition_graph_runs():
    m = build_composition(hidden=8)
    onnx.checker.check_model(m, full_check=True)
    assert {n.op_type for n in m.graph.node} <= ALLOWED_OPS
    x = np.random.default_rng(2).standard_normal((1, 22, 5, 7)).astype(np.float32)
    w = _run(m, x)
    assert w.shape == (1, 1, 5, 7) and ((w > 0) & (w < 1)).all()
    # Per-pixel MLP: a pixel's output depends on that pixel only.
    x2 = x.copy()
    x2[..., 0, 0] += 1
    w2 = _run(m, x2)
    assert np.array_equal(w2[..., 1:, :], w[..., 1:, :])


def test_seeded():
    a, b, c = (model_weights(build_classifier(seed=s)) for s in (3, 3, 4))
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert not np.array_equal(a["cls.stem.weight"], c["cls.stem.weight"])


def test_flops_near_paper():
    cls, comp = build_classifier(), build_composition()
    a, b = frame_flops(cls, comp, 2160, 3840)
    assert abs((a + b) / 1e9 - 71.4) / 71.4 < 0.05
    # A lone 1x1 conv: 2 * cin * cout * H * W.
    assert count_flops(comp, 10, 10) == 2 * (22 * 32 + 32 * 1) * 100
    # Widths scale the count.
    assert count_flops(build_classifier((8, 16, 32, 64)), 64, 64) < count_flops(cls, 64, 64)


def test_safetensors_roundtrip_and_fp16(tmp_path):
    cls, comp = build_classifier(), build_composition()
    p = tmp_path / "w.safetensors"
    save_weights([cls, comp], str(p))
    t = load_weights(str(p))
    ref = {**model_weights(cls), **model_weights(comp)}
    assert set(t) == set(ref) and not any(k.endswith(".scales") for k in t)
    assert all(np.array_equal(t[k], ref[k]) for k in t)
    save_weights(cls, str(tmp_path / "h.safetensors"), half=True)
    h = load_weights(str(tmp_path / "h.safetensors"))
    assert h["cls.stem.weight"].dtype == np.float16
    # Applying fp16 weights keeps the graph's fp32 initializers, values rounded.
    other = build_classifier(seed=9)
    apply_weights(other, h, strict=True)
    w = model_weights(other)["cls.stem.weight"]
    assert w.dtype == np.float32
    np.testing.assert_allclose(w, ref["cls.stem.weight"], rtol=1e-3, atol=1e-4)


def test_apply_weights_checks_shape_and_missing():
    m = build_composition(hidden=8)
    with pytest.raises(WeightsError, match="comp.fc1.weight"):
        apply_weights(m, {"comp.fc1.weight": np.zeros((9, 22, 1, 1), np.float32)})
    with pytest.raises(WeightsError, match="no weights given"):
        apply_weights(m, {}, strict=True)


def test_load_weights_rejects_garbage(tmp_path):
    p = tmp_path / "bad.safetensors"
    p.write_bytes(b"nonsense")
    with pytest.raises(WeightsError, match="bad.safetensors"):
        load_weights(str(p))


def _write_st(path, tensors, bf16=()):
    """A safetensors file written by hand, as torch would (bf16 included)."""
    header, blobs, off = {}, [], 0
    for k, v in tensors.items():
        if k in bf16:
            raw = (np.asarray(v, np.float32).view(np.uint32) >> 16).astype(np.uint16).tobytes()
            dt = "BF16"
        else:
            raw, dt = np.asarray(v, np.float32).tobytes(), "F32"
        header[k] = {"dtype": dt, "shape": list(v.shape), "data_offsets": [off, off + len(raw)]}
        blobs.append(raw)
        off += len(raw)
    h = json.dumps(header).encode()
    path.write_bytes(struct.pack("<Q", len(h)) + h + b"".join(blobs))


def test_torch_name_map():
    assert torch_to_onnx_name("enc.0.conv1.weight") == "cls.enc0.reduce.weight"
    assert torch_to_onnx_name("module.enc.3.conv3.bias") == "cls.enc3.expand.bias"
    assert torch_to_onnx_name("down.0.weight") == "cls.down1.weight"
    assert torch_to_onnx_name("down.2.bias") == "cls.down3.bias"
    assert torch_to_onnx_name("dec.4.weight") == "cls.dec.out.weight"
    assert torch_to_onnx_name("mlp.2.bias") == "comp.fc2.bias"
    assert torch_to_onnx_name("enc.0.bn.running_mean") is None


def test_import_torch_state_dict(tmp_path):
    cls, comp = build_classifier((4, 8, 8, 8)), build_composition(hidden=4)
    rng = np.random.default_rng(5)
    ours = {**model_weights(cls), **model_weights(comp)}
    inverse = {}
    for i in range(4):
        for a, b in (("conv1", "reduce"), ("conv2", "mid"), ("conv3", "expand")):
            inverse[f"cls.enc{i}.{b}"] = f"enc.{i}.{a}"
    inverse.update({"cls.stem": "stem", "cls.down1": "down.0", "cls.down2": "down.1",
                    "cls.down3": "down.2", "cls.dec.fuse": "dec.0", "cls.dec.conv": "dec.2",
                    "cls.dec.out": "dec.4", "comp.fc1": "mlp.0", "comp.fc2": "mlp.2"})
    state, expect = {}, {}
    for name, arr in ours.items():
        layer, kind = name.rsplit(".", 1)
        v = rng.standard_normal(arr.shape).astype(np.float32)
        expect[name] = v
        if name.startswith("comp.") and kind == "weight":
            v = v[:, :, 0, 0]  # nn.Linear layout
        state[inverse[layer] + "." + kind] = v
    state["enc.0.bn.running_mean"] = np.zeros(4, np.float32)   # ignored
    p = tmp_path / "torch.safetensors"
    _write_st(p, state, bf16={"stem.weight"})
    pairs = import_torch_state_dict(str(p), cls)
    assert ("down.0.weight", "cls.down1.weight") in pairs
    import_torch_state_dict(str(p), comp)
    got = {**model_weights(cls), **model_weights(comp)}
    for k, v in expect.items():
        tol = 1e-2 if k == "cls.stem.weight" else 0   # bf16 rounding
        np.testing.assert_allclose(got[k], v, rtol=tol, atol=tol, err_msg=k)
    # A state dict that lacks a layer is refused in strict mode.
    del state["dec.4.weight"]
    _write_st(p, state)
    with pytest.raises(WeightsError, match="cls.dec.out.weight"):
        import_torch_state_dict(str(p), build_classifier((4, 8, 8, 8)))


def test_cli_build_and_inspect(tmp_path, capsys):
    assert main(["build", "--out", str(tmp_path), "--seed", "1", "--widths", "8,8,16,16",
                 "--mlp-hidden", "8", "--height", "32", "--width", "32"]) == 0
    out = capsys.readouterr().out
    assert "2160p" in out and "1080p" in out and "540p" in out
    for f in ("classifier.onnx", "composition.onnx", "weights.safetensors"):
        assert (tmp_path / f).exists()
    m = onnx.load(str(tmp_path / "classifier.onnx"))
    assert m.graph.input[0].type.tensor_type.shape.dim[2].dim_value == 32
    assert main(["inspect", str(tmp_path / "weights.safetensors")]) == 0
    assert "cls.stem.weight" in capsys.readouterr().out
    assert main(["inspect", str(tmp_path / "composition.onnx")]) == 0
    assert "Sigmoid" in capsys.readouterr().out


def test_load_networks_default_and_untrained(monkeypatch, tmp_path):
    """weights=None: the shipped trained weights; absent, an error unless the caller
    allows the untrained init; "untrained": the seeded init on request."""
    from clss.methods.clss import upscaler
    from clss.methods.clss.networks import build_classifier
    from clss.networks import model_weights
    from clss.pipeline import method
    seeded = model_weights(build_classifier())
    cls, _, trained = upscaler.load_networks("untrained")
    assert not trained
    assert all(np.array_equal(model_weights(cls)[k], v) for k, v in seeded.items())
    monkeypatch.setattr(method, "WEIGHTS_DIR", str(tmp_path))       # a package without weights
    with pytest.raises(ValueError, match="clss: no trained weights .* allow_untrained=True"):
        upscaler.load_networks(None)
    assert upscaler.load_networks(None, allow_untrained=True)[2] is False
    shipped = tmp_path / upscaler.SHIPPED_NAME
    t = dict(seeded)
    t["cls.stem.bias"] = t["cls.stem.bias"] + 1
    save_weights(t, str(shipped))
    cls, _, trained = upscaler.load_networks(None)
    assert trained and np.array_equal(model_weights(cls)["cls.stem.bias"], t["cls.stem.bias"])
