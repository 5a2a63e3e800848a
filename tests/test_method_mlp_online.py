"""Online training of the shader MLP upscaler on the device (clss/methods/mlp/online.py,
clss/methods/mlp/mlp_train.cl): the gradients of forward + loss + backward against torch autograd on
the same batch (the torch twin, weights_tools/methods/mlp/twin.py), one and two Adam steps
against torch.optim.Adam, and a smoke online run through the Python API and the CLI.

Tolerances (fp32): each gradient element within 1e-4 of the torch value relative to
|torch| + 1e-2 * max|torch| of its tensor (a floor for the elements that are sums of
cancelling terms; measured 5e-5 on the worst element, 3e-7 against the tensor's max);
weights after Adam within 1e-6 absolute (a step moves them by 1e-3)."""
from __future__ import annotations

import numpy as np
import pytest

import clss
from clss.methods.mlp import patches as pt
from clss.methods.mlp import transform as tf
from clss.methods.mlp.online import OnlineTrainer
from helpers import mlp_weights

torch = pytest.importorskip("torch")


def _frame(s, h=30, w=34, seed=1):
    g = np.random.default_rng(seed)
    color = (g.random((h, w, 3)) ** 3 * 4).astype(np.float32)
    ref = (g.random((s * h, s * w, 3)) ** 3 * 4).astype(np.float32)
    dhr = g.random((s * h, s * w)).astype(np.float32)
    return color, ref, dhr


def _torch_grads(net, col, feat, ref, s, feature, jitter=None):
    m = pt.MARGIN
    j = None if jitter is None else torch.tensor(np.float32(jitter)).expand(col.shape[0], 2)
    out = net(torch.from_numpy(col), torch.from_numpy(feat[:, None]) if feature else None, j)
    out = out[..., s * m:s * (m + pt.PATCH), s * m:s * (m + pt.PATCH)]
    loss = (out - torch.from_numpy(ref)).abs().mean()
    net.zero_grad()
    loss.backward()
    return loss.item(), {n: (getattr(net, n).weight.grad.numpy().copy(),
                             getattr(net, n).bias.grad.numpy().copy()) for n in tf.LAYER_NAMES}


def _unpack(flat):
    out, off = {}, 0
    for k, n in enumerate(tf.LAYER_NAMES):
        ci, co = tf.WIDTHS[k], tf.WIDTHS[k + 1]
        out[n] = (flat[off:off + co * ci].reshape(co, ci), flat[off + co * ci:off + co * ci + co])
        off += co * ci + co
    return out


@pytest.mark.parametrize("scale,feature", [(2, True), (3, True), (2, False)])
def test_gradients_match_torch_autograd(scale, feature, dev):
    from weights_tools.methods.mlp.twin import MlpNet
    torch.set_num_threads(1)
    wts = mlp_weights()
    color, ref, dhr = _frame(scale)
    tr = OnlineTrainer(dev, scale, feature, dev.to_device(tf.packed(wts)), batch=3, seed=2)
    defs = tf.kernel_defines(scale, feature)
    col, feat, rf = tr.cut(tr.prepare(color, dhr, ref))
    tr.load(col, feat, rf, defs)
    g, loss = tr.gradients(defs)
    tl, tg = _torch_grads(MlpNet(scale, feature, wts), col, feat, rf, scale, feature)
    assert abs(loss - tl) <= 1e-5 * tl
    ours = _unpack(g.get())
    for n in tf.LAYER_NAMES:
        for a, b, what in zip(ours[n], tg[n], ("weight", "bias")):
            bound = 1e-4 * (np.abs(b) + 1e-2 * np.abs(b).max())
            bad = np.abs(a - b) > bound
            assert not bad.any(), (f"{n}.{what}: {bad.sum()} elements beyond 1e-4, max "
                                   f"{(np.abs(a - b) / (np.abs(b) + 1e-2 * np.abs(b).max())).max():.3g}")
    if scale == 2:           # the 2x block's unused output units get no gradient
        assert not ours["fc3"][0][16:].any() and not ours["fc3"][1][16:].any()


def test_adam_steps_match_torch(dev):
    from weights_tools.methods.mlp.twin import MlpNet
    torch.set_num_threads(1)
    wts = mlp_weights(7)
    color, ref, dhr = _frame(2, seed=5)
    w = dev.to_device(tf.packed(wts))
    tr = OnlineTrainer(dev, 2, True, w, batch=2, lr=1e-3, seed=1)
    net = MlpNet(2, True, wts)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    defs = tf.kernel_defines(2, True)
    frame = tr.prepare(color, dhr, ref)
    for step in range(2):
        col, feat, rf = tr.cut(frame)
        tr.load(col, feat, rf, defs)
        tr.step(defs)
        _torch_grads(net, col, feat, rf, 2, True)
        opt.step()
        d = np.abs(w.get() - tf.packed(net.tensors()))
        assert d.max() <= 1e-6, f"step {step + 1}: weights differ by {d.max():.3g}"
    assert np.abs(w.get() - tf.packed(wts)).max() > 1e-3


def test_jitter_input_trains_with_the_frames_jitter(dev, tmp_path):
    # a network with the jitter input: the gradients are those of the frame's jitter (the
    # term in fc1's bias), Adam moves the bias itself, the jitter weights stay
    from weights_tools.methods.mlp.twin import MlpNet
    torch.set_num_threads(1)
    wts = mlp_weights(7)
    wts[tf.JITTER_KEY] = (np.random.default_rng(2).standard_normal((50, 2)) * 0.5).astype(np.float32)
    color, ref, dhr = _frame(2, seed=5)
    jit = (0.3, -0.4)
    w = dev.to_device(tf.packed(wts))
    tr = OnlineTrainer(dev, 2, True, w, batch=2, lr=1e-3, seed=1, jitter_weight=wts[tf.JITTER_KEY])
    net = MlpNet(2, True, wts)
    opt = torch.optim.Adam([p for n, p in net.named_parameters() if not n.startswith("fcj")], lr=1e-3)
    defs = tf.kernel_defines(2, True)
    frame = tr.prepare(color, dhr, ref)
    for step in range(2):
        col, feat, rf = tr.cut(frame)
        tr.load(col, feat, rf, defs)
        tr.step(defs, jit)
        _torch_grads(net, col, feat, rf, 2, True, jit)
        opt.step()
        d = np.abs(w.get() - tf.packed(net.tensors()))
        assert d.max() <= 1e-6, f"step {step + 1}: weights differ by {d.max():.3g}"
    # through the upscaler: fcj kept, saved, and the frame step runs the learnt bias
    for precision in ("fp32", "fp16"):
        up = clss.Upscaler(method="mlp", scale=2, device=dev, precision=precision, online=True,
                           online_batch=2, weights=wts)
        y0 = up.step(color, None, None, jit, depth_hr=dhr, reference=ref)
        learnt = up.learnt_tensors()
        assert np.array_equal(learnt[tf.JITTER_KEY], wts[tf.JITTER_KEY])
        assert np.abs(learnt["fc1.bias"] - wts["fc1.bias"]).max() > 1e-5
        p = tmp_path / f"{precision}.safetensors"
        up.save_weights(str(p))
        fresh = clss.Upscaler(method="mlp", scale=2, device=dev, precision=precision, weights=str(p))
        assert np.array_equal(fresh.step(color, None, None, jit, depth_hr=dhr), y0)


def test_patches_are_accepted_by_gradient():
    # a frame flat on its left and busy on its right: accepted patches lean right
    ref = np.zeros((120, 160, 3), np.float32)
    ref[:, 80:] = np.random.default_rng(0).random((120, 80, 3))
    integ = pt.gradient_integral(ref)
    rule = pt.Sampler([(60, 80)], [(0, 1)], lambda k, t: integ, 2, seed=0)
    js = [rule.draw()[3] for _ in range(200)]
    assert np.mean(np.array(js) > 29) > 0.8 and rule.accepted < rule.tried


def _tiny_frames(s=2, T=4, h=26, w=30):
    g = np.random.default_rng(4)
    yy, xx = np.mgrid[0:s * h, 0:s * w]
    out = []
    for t in range(T):
        ref = (0.5 + 0.4 * np.sin((xx + 3 * t) / 2.3)[..., None] * np.cos(yy / 3.1)[..., None]
               * np.array([1.0, 0.8, 0.6])).astype(np.float32)
        ref += 0.02 * g.random(ref.shape).astype(np.float32)
        dhr = (0.3 + 0.1 * np.sin(xx / 7.0)).astype(np.float32)
        out.append((ref.reshape(h, s, w, s, 3).mean((1, 3)), ref, dhr))
    return out


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_smoke_online_api(precision, dev, tmp_path):
    frames = _tiny_frames()
    up = clss.Upscaler(method="mlp", scale=2, device=dev, precision=precision, online=True,
                       online_batch=4, online_steps=2, weights="scratch")
    w0 = up.learnt_tensors()
    for k, (c, ref, dhr) in enumerate(frames):
        y = up.step(c, depth_hr=dhr, reference=ref if k % 2 == 0 else None)
        assert y.shape == ref.shape and np.isfinite(y).all()
    assert up.online.t == 4 and len(up.online.history) == 2
    assert all(np.isfinite(l) for _, l in up.online.history)
    w1 = up.learnt_tensors()
    assert np.abs(w1["fc3.weight"] - w0["fc3.weight"]).max() > 1e-4
    # the frame step runs the learnt weights: the same as a fresh upscaler given them
    p = tmp_path / "learnt.safetensors"
    up.save_weights(str(p))
    c, _, dhr = frames[-1]
    fresh = clss.Upscaler(method="mlp", scale=2, device=dev, precision=precision, weights=str(p))
    assert np.array_equal(fresh.step(c, depth_hr=dhr), up.step(c, depth_hr=dhr))
    assert up.train_step(c, frames[-1][1], depth_hr=dhr) > 0
    with pytest.raises(ValueError, match="online=True"):
        fresh.train_step(c, frames[-1][1], depth_hr=dhr)


def test_smoke_online_cli(dev, tmp_path, capsys):
    pytest.importorskip("OpenImageIO")
    from clss import io as cio
    from clss.cli.upscale import cmd_upscale
    frames = [{"color": c, "depth": np.full(c.shape[:2], 0.5, np.float32),
               "motion": np.zeros(c.shape[:2] + (2,), np.float32), "jitter": (0.0, 0.0),
               "reference": ref, "depth_hr": dhr} for c, ref, dhr in _tiny_frames(T=3)]
    cio.write_sample_sequence(frames, str(tmp_path / "in"), gbuffers=True)
    w = tmp_path / "w.safetensors"
    assert cmd_upscale([str(tmp_path / "in"), "-o", str(tmp_path / "out"), "--method", "mlp",
                        "--online", "--online-batch", "2", "--train-every", "2",
                        "--save-weights", str(w)]) == 0
    cap = capsys.readouterr()
    assert "online: frame 0: L1" in cap.err and "online: frame 2: L1" in cap.err
    assert "online: 2 training frames, 2 steps" in cap.out
    tensors, trained = tf.load_weights(str(w))
    assert trained
    # and from the saved weights again
    assert cmd_upscale([str(tmp_path / "in"), "-o", str(tmp_path / "out2"), "--method", "mlp",
                        "--online", "--weights", str(w), "--frames", "1"]) == 0
    from clss.cli.args import UsageError
    with pytest.raises(UsageError, match="does not train online"):
        cmd_upscale([str(tmp_path / "in"), "-o", str(tmp_path / "o3"), "--method", "bicubic",
                     "--online"])
    with pytest.raises(UsageError, match="needs --online"):
        cmd_upscale([str(tmp_path / "in"), "-o", str(tmp_path / "o4"), "--method", "mlp",
                     "--save-weights", str(w)])
