"""The shader MLP upscaler (clss/methods/mlp/, docs/methods/mlp.md): the OpenCL frame step
against its whole-frame ONNX twin in fp32 and fp16 at 2x and 3x, with trained-like
(random, non-zero) weights; its kernels' conformance cases; the method's interface
(registry, scales, weights files, the named error without depth_hr); the jitter input
(fc1's bias per frame) against the twin; the torch twin's parity with the OpenCL step; a
smoke training run of the recipe.

Tolerances on the frame (PQ code values, so that HDR highlights count as displayed):
fp32 1e-4 absolute (measured about 1e-5: the kernel's pow against onnxruntime's), fp16
(half storage of the inputs and blocks, half-rounded weights) 2e-3 absolute."""
from __future__ import annotations

import numpy as np
import pytest

import clss
from clss import methods
from clss.methods.mlp import transform as tf
from clss.pipeline import contract
from clss.pipeline.contract import pq_encode
from helpers import assert_case, frames, mlp_weights

RENDER = (13, 17)
TOL = {"fp32": 1e-4, "fp16": 2e-3}


def _frame(scale, seed=1):
    g = np.random.default_rng(seed)
    h, w = RENDER
    # HDR colour with edges, depth with a step: the transform sees both signs and scales
    color = (g.random((h, w, 3)) ** 3 * 4).astype(np.float32)
    color[:, w // 2:] *= 0.1
    dhr = np.where(np.arange(scale * w)[None, :] < scale * w // 3, 0.8, 0.1) \
        + 0.05 * g.random((scale * h, scale * w))
    return color, dhr.astype(np.float32)


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("scale", [2, 3])
@pytest.mark.parametrize("name", ["mlp", "mlp-nofeature"])
def test_frame_step_matches_onnx_twin(name, scale, precision, dev):
    wts = mlp_weights()
    color, dhr = _frame(scale)
    up = clss.Upscaler(method=name, scale=scale, device=dev, precision=precision, weights=wts)
    twin = methods.twin(name, RENDER, scale, weights=wts, precision=precision)
    a = up.step(color, None, None, (0.0, 0.0), depth_hr=dhr)
    b = twin.step(color, depth_hr=dhr)
    assert a.shape == b.shape == (scale * RENDER[0], scale * RENDER[1], 3)
    d = np.abs(pq_encode(a) - pq_encode(b))
    assert d.max() <= TOL[precision], f"max PQ difference {d.max():.3g}"


def _jitter_weights(seed=13):
    """mlp_weights with the jitter input (transform.JITTER_KEY), strong enough to move
    the output."""
    wts = mlp_weights(seed)
    wts[tf.JITTER_KEY] = (np.random.default_rng(seed).standard_normal((50, 2)) * 0.5) \
        .astype(np.float32)
    return wts


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("scale", [2, 3])
def test_jitter_input_matches_onnx_twin(scale, precision, dev):
    # the jitter term goes into fc1's bias per frame: a new jitter, the same one again,
    # and back, each against the twin that feeds the jitter to a MatMul
    wts = _jitter_weights()
    color, dhr = _frame(scale, seed=3)
    up = clss.Upscaler(method="mlp", scale=scale, device=dev, precision=precision, weights=wts)
    twin = methods.twin("mlp", RENDER, scale, weights=wts, precision=precision)
    outs = []
    for j in [(0.25, -0.3), (-0.4, 0.1), (-0.4, 0.1), (0.25, -0.3)]:
        a = up.step(color, None, None, j, depth_hr=dhr)
        d = np.abs(pq_encode(a) - pq_encode(twin.step(color, jitter=j, depth_hr=dhr)))
        assert d.max() <= TOL[precision], f"jitter {j}: max PQ difference {d.max():.3g}"
        outs.append(a)
    assert np.array_equal(outs[0], outs[3]) and np.abs(outs[0] - outs[1]).max() > 1e-2
    y = up.step_device(dev.to_device(color), jitter=(-0.4, 0.1), depth_hr=dev.to_device(dhr))
    assert np.array_equal(dev.to_host(y), outs[1])
    # a file without the input ignores the jitter, as before
    plain = clss.Upscaler(method="mlp", scale=scale, device=dev, precision=precision,
                          weights=mlp_weights())
    assert np.array_equal(plain.step(color, None, None, (0.25, -0.3), depth_hr=dhr),
                          plain.step(color, None, None, (0.0, 0.0), depth_hr=dhr))


def test_exposure_and_step_device(dev):
    wts = mlp_weights(5)
    color, dhr = _frame(2, seed=2)
    up = clss.Upscaler(method="mlp", scale=2, device=dev, weights=wts, exposure=4.0)
    twin = methods.twin("mlp", RENDER, 2, weights=wts, exposure=4.0)
    a = up.step(color, None, None, (0, 0), depth_hr=dhr)
    assert np.abs(pq_encode(a) - pq_encode(twin.step(color, depth_hr=dhr))).max() <= 1e-4
    y = up.step_device(dev.to_device(color), depth_hr=dev.to_device(dhr))
    assert np.array_equal(dev.to_host(y), a)


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_kernel_conformance_cases(precision, dev):
    from clss.verify.cases import mlp_upscale
    for case in mlp_upscale.cases("quick"):
        assert_case(case, dev, precision)


def test_interface(dev, tmp_path):
    assert "mlp" in methods.names() and "mlp" not in methods.PLANNED
    spec = methods.spec("mlp")
    assert spec.gbuffers == ("depth_hr",) and not spec.temporal and spec.twin
    assert methods.spec("mlp-nofeature").gbuffers == ()
    f = frames(RENDER, 1)[0]
    up = clss.Upscaler(method="mlp", scale=2, device=dev)
    assert up.step(f.color, f.depth, f.motion, f.jitter, **f.gbuffers).shape == (26, 34, 3)
    gb = {k: v for k, v in f.gbuffers.items() if k != "depth_hr"}
    with pytest.raises(contract.MissingInputError, match="depth_hr"):
        up.step(f.color, f.depth, f.motion, f.jitter, **gb)
    with pytest.raises(ValueError, match="integer scales 2 and 3"):
        clss.Upscaler(method="mlp", scale=2.5, device=dev)
    with pytest.raises(ValueError, match="scale"):
        clss.Upscaler(method="mlp", scale=4, device=dev)
    # weights files: save, load, the same output; a wrong file is one line naming it
    wts = mlp_weights(9)
    p = tmp_path / "w.safetensors"
    tf.save_weights(wts, p, {"what": "test"})
    a = clss.Upscaler(method="mlp", device=dev, weights=str(p)).step(f.color, **f.gbuffers)
    b = clss.Upscaler(method="mlp", device=dev, weights=wts).step(f.color, **f.gbuffers)
    assert np.array_equal(a, b)
    bad = _jitter_weights()
    bad[tf.JITTER_KEY] = bad[tf.JITTER_KEY][:, :1]
    with pytest.raises(ValueError, match="fcj.weight has shape"):
        tf.check_weights(bad, "x.safetensors")
    bad = dict(wts)
    bad["fc2.weight"] = bad["fc2.weight"][:, :49]
    with pytest.raises(ValueError, match="fc2.weight has shape"):
        tf.check_weights(bad, "x.safetensors")
    with pytest.raises(ValueError, match="not a file"):
        clss.Upscaler(method="mlp", device=dev, weights=str(tmp_path / "none.safetensors"))


def test_untrained_init_is_a_box_upscale(dev):
    # the seeded init's zero output layer returns each block's mean: flat stays flat
    color = np.full((*RENDER, 3), 0.7, np.float32)
    up = clss.Upscaler(method="mlp-nofeature", scale=3, device=dev, weights="untrained")
    y = up.step(color)
    assert np.allclose(y, 0.7, rtol=1e-4)   # the PQ round trip


# ---- the torch twin and the recipe ----------------------------------------------------------

@pytest.mark.parametrize("scale", [2, 3])
@pytest.mark.parametrize("feature", [True, False])
def test_torch_twin_matches_opencl(scale, feature, dev):
    pytest.importorskip("torch")
    from weights_tools.methods.mlp.twin import MlpNet, upscale
    wts = mlp_weights(11)
    color, dhr = _frame(scale, seed=4)
    name = "mlp" if feature else "mlp-nofeature"
    a = clss.Upscaler(method=name, scale=scale, device=dev, weights=wts).step(color, depth_hr=dhr)
    b = upscale(MlpNet(scale, feature, wts), color, dhr)
    d = np.abs(pq_encode(a) - pq_encode(b))
    assert d.max() <= 1e-4, f"max PQ difference {d.max():.3g}"


@pytest.mark.parametrize("scale", [2, 3])
def test_torch_twin_jitter_input_matches_opencl(scale, dev):
    pytest.importorskip("torch")
    from weights_tools.methods.mlp.twin import MlpNet, upscale
    wts = _jitter_weights(17)
    color, dhr = _frame(scale, seed=6)
    net = MlpNet(scale, True, wts)
    assert tf.JITTER_KEY in net.tensors()
    up = clss.Upscaler(method="mlp", scale=scale, device=dev, weights=wts)
    for j in [(0.3, -0.2), (-0.45, 0.35)]:
        d = np.abs(pq_encode(up.step(color, None, None, j, depth_hr=dhr))
                   - pq_encode(upscale(net, color, dhr, j)))
        assert d.max() <= 1e-4, f"jitter {j}: max PQ difference {d.max():.3g}"
    # --jitter from a file without the input starts as that file's network
    plain = mlp_weights(11)
    a = upscale(MlpNet(scale, True, plain, jitter=True), color, dhr, (0.3, -0.2))
    assert np.array_equal(a, upscale(MlpNet(scale, True, plain), color, dhr))


def _tiny_sequence(path, scale=2, T=4, h=24, w=26, seed=0):
    g = np.random.default_rng(seed)
    ref = (g.random((T, scale * h, scale * w, 3)) ** 2).astype(np.float32)
    color = ref[:, ::scale, ::scale].copy()
    dhr = g.random((T, scale * h, scale * w)).astype(np.float32)
    jitter = (g.random((T, 2)) - 0.5).astype(np.float32)
    np.savez(path, color=color, depth=dhr[:, ::scale, ::scale].copy(), reference=ref,
             depth_hr=dhr, scale=np.float32(scale), jitter=jitter)


def test_smoke_training_offline(tmp_path, dev, capsys):
    pytest.importorskip("torch")
    from weights_tools.__main__ import main
    data = tmp_path / "data"
    data.mkdir()
    _tiny_sequence(data / "a.npz")
    out = tmp_path / "run"
    assert main(["train", "mlp", "--data", str(data), "--out", str(out), "--steps", "3",
                 "--batch", "2", "--quiet"]) == 0
    w = out / "mlp.safetensors"
    tensors, trained = tf.load_weights(str(w))
    assert trained and (out / "loss.png").is_file()
    # per scene: the first half of one sequence; the weights run in the engine
    assert main(["train", "mlp", "--scene", str(data / "a.npz"), "--out", str(tmp_path / "s"),
                 "--steps", "2", "--batch", "2", "--quiet", "--init", str(w)]) == 0
    f = np.load(data / "a.npz")
    y = clss.Upscaler(method="mlp", device=dev, weights=str(tmp_path / "s" / "mlp.safetensors")) \
        .step(f["color"][0], depth_hr=f["depth_hr"][0])
    assert y.shape == (48, 52, 3) and np.isfinite(y).all()
    # --jitter: the file gains the jitter input, which the engine reads
    assert main(["train", "mlp", "--data", str(data), "--out", str(tmp_path / "j"), "--steps", "2",
                 "--batch", "2", "--quiet", "--init", str(w), "--jitter"]) == 0
    tj, _ = tf.load_weights(str(tmp_path / "j" / "mlp.safetensors"))
    assert tf.has_jitter(tj) and np.abs(tj[tf.JITTER_KEY]).max() > 0
    up = clss.Upscaler(method="mlp", device=dev, weights=str(tmp_path / "j" / "mlp.safetensors"))
    assert not np.array_equal(up.step(f["color"][0], None, None, (0.3, 0.1), depth_hr=f["depth_hr"][0]),
                              up.step(f["color"][0], None, None, (-0.3, 0.1), depth_hr=f["depth_hr"][0]))
    assert main(["train", "mlp", "--out", str(out)]) == 2
    assert "give --data DIR" in capsys.readouterr().err


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_pixel_vector_fast_path_matches_reference(precision, dev):
    # the fast path (8 render pixels per work-item, PQ hoisted) against the scalar kernel,
    # on a width with a partial last vector and an interior that takes the vector loads
    from clss.methods.mlp import mlp_upscale as ops
    g = np.random.default_rng(8)
    for s, feature in ((2, True), (3, False)):
        h, w = 6, 27
        color = dev.to_device(g.uniform(0, 4, (h, w, 3)).astype(np.float32), precision)
        feat = dev.to_device(g.uniform(0, 1, (s * h, s * w)).astype(np.float32), precision)
        wts = ops.pack_weights(dev, precision, tf.packed(mlp_weights(s)))
        d = tf.kernel_defines(s, feature)
        a = dev.to_host(ops.blocks(dev, precision, color, feat, wts, d, vec=1))
        b = dev.to_host(ops.blocks(dev, precision, color, feat, wts, d, vec=8))
        tol = 1e-5 if precision == "fp32" else 2e-3
        assert np.abs(a - b).max() <= tol, f"x{s}: max difference {np.abs(a - b).max():.3g}"


def test_bench_case_tiny(dev):
    import sys
    import os
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from bench.methods.mlp import cases as mlp_cases
    cases = mlp_cases("tiny")
    assert [c.name for c in cases] == ["frame step mlp x2", "frame step mlp x3"]
    st = cases[0].build(dev, "fp32", {})
    out = dev.to_host(st.run()[0])
    import onnxruntime as ort
    sess = ort.InferenceSession(st.twin.SerializeToString(), providers=["CPUExecutionProvider"])
    ref = sess.run(None, st.feeds)[0]
    assert np.abs(pq_encode(out) - pq_encode(ref)).max() <= 1e-4
