"""The method interface (clss.methods, clss.Upscaler(method=...)): the registry, every
method against its whole-frame ONNX twin, the G-buffer contract as each method sees it,
and `clss methods`.

Twin tolerances (per frame, output only; test_method_clss_frame.py holds CLSS's history to
its oracle in detail): fp32 |d| <= 1e-4 * max|ref| + 1e-4 * |ref| on every pixel where
the twin's outputs are continuous, i.e. on >= 99 % of pixels for the temporal methods
(CLSS's integer decisions may flip on a few, reference.md s11); fp16 (half storage)
within 1e-2 * max|ref| + 1e-2 * |ref| on >= 99 % of pixels.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

import clss
from clss import methods
from clss.pipeline import contract
from clss.pipeline.method import MethodSpec, MethodUpscaler
from helpers import RESET_AT, frames

RENDER = (13, 17)          # odd and prime: partial vectors, unpadded rows


def test_registry_names_aliases_and_errors():
    assert methods.names()[:4] == ["bicubic", "jbicubic", "clss-rules", "clss"]
    for alias, name in (("rules", "clss-rules"), ("net", "clss"), ("CLSS", "clss")):
        assert methods.canonical(alias) == name
    for planned in methods.PLANNED:          # listed, not runnable yet
        with pytest.raises(ValueError, match="not built yet"):
            methods.canonical(planned)
    with pytest.raises(ValueError, match="expected one of bicubic, jbicubic"):
        methods.canonical("taa")
    with pytest.raises(ValueError, match=r"got 'nsrdd'; did you mean 'nsrd'\?"):
        methods.canonical("nsrdd")
    with pytest.raises(ValueError, match=r"did you mean 'clss-rules'\?"):
        methods.canonical("rulez")          # an alias's misspelling names the method
    for s in methods.specs():
        assert s.doc.startswith("docs/methods/") and s.label and s.summary
        assert s.weights() in ("trained", "untrained", "none needed")
        assert set(s.gbuffers) | set(s.optional) <= set(contract.GBUFFERS)
        assert s.twin, f"{s.name} has no ONNX twin"


def test_upscaler_dispatch_and_mode_alias(dev):
    up = clss.Upscaler(method="clss-rules", scale=2, device=dev)
    assert up.method == "clss-rules" and up.mode == "rule" and isinstance(up, clss.Upscaler)
    assert clss.Upscaler(2.0, "rules", device=dev).method == "clss-rules"
    assert clss.Upscaler(2.0, mode="net", device=dev, weights="untrained").method == "clss"
    assert clss.Upscaler(method="clss", mode="rules", device=dev).method == "clss-rules"
    assert clss.Upscaler(method="bicubic", scale=3, device=dev).method == "bicubic"
    with pytest.raises(ValueError, match="mode: applies to the method 'clss' only"):
        clss.Upscaler(method="bicubic", mode="rules", device=dev)
    with pytest.raises(ValueError, match="mode: expected 'net' or 'rules'"):
        clss.Upscaler(2.0, "fancy", device=dev)
    with pytest.raises(ValueError, match=r"scale: expected a number in \[1, 16\]"):
        clss.Upscaler(method="bicubic", scale=0.5, device=dev)
    with pytest.raises(ValueError, match="precision: expected 'auto' or 'fp32' or 'fp16'"):
        clss.Upscaler(method="jbicubic", precision="fp64", device=dev)


@pytest.mark.parametrize("method, key, close", [("nsrr", "widht", "widths"),
                                                ("nsrd", "precison", "precision"),
                                                ("mlp", "onlin", "online")])
def test_an_unknown_keyword_names_the_closest(method, key, close, dev):
    with pytest.raises(TypeError, match=rf"method='{method}'\): unexpected keyword argument "
                                        rf"'{key}'; did you mean '{close}'\?"):
        clss.Upscaler(method=method, device=dev, **{key: 1})
    # one with nothing close lists what the method takes
    with pytest.raises(TypeError, match="'zzz'; it takes scale, device, precision"):
        clss.Upscaler(method="bicubic", device=dev, zzz=1)
    # a caller feeding several methods passes each only what it takes; the contract's
    # parameters go to every method (tests/test_contract.py: it honours or refuses them)
    assert methods.options("bicubic", depth_inverted=False, exposure=2.0, weights=None,
                           widths="fast") == {"depth_inverted": False, "exposure": 2.0}


def test_a_scale_without_shipped_weights_is_refused(dev):
    spec = methods.spec("nsrd")
    have = " and ".join(f"{s:g}" for s in spec.trained_scales())
    assert have == "2 and 4"
    with pytest.raises(ValueError, match=rf"nsrd: no trained weights for scale 3 \(the package "
                                         rf"has weights for scales {have}\).*allow_untrained"):
        clss.Upscaler(method="nsrd", scale=3, device=dev)
    assert clss.Upscaler(method="nsrd", scale=3, device=dev, allow_untrained=True).trained is False
    assert clss.Upscaler(method="nsrd", scale=3, device=dev, weights="untrained").trained is False
    # NSRR's networks do not depend on the scale: the nearest trained one serves (docs)
    assert clss.Upscaler(method="nsrr", scale=3, device=dev).trained is True


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("name", methods.names())
def test_step_device_is_step_on_float32_arrays(name, precision, dev):
    """Every method's step_device takes float32 arrays in both precisions, gives what step
    gives, and raises the same error types."""
    f = frames(RENDER, 1)[0]
    up = clss.Upscaler(method=name, device=dev, precision=precision, **_kwargs(name))
    ref = clss.Upscaler(method=name, device=dev, precision=precision, **_kwargs(name))

    def d(a):
        return dev.to_device(np.ascontiguousarray(a, np.float32))
    gb = {k: d(v) for k, v in f.gbuffers.items()}
    out = up.step_device(d(f.color), d(f.depth), d(f.motion), f.jitter, **gb)
    assert out.dtype == np.float32 and out.shape == (26, 34, 3)
    assert np.array_equal(out.get(), ref.step(f.color, f.depth, f.motion, f.jitter,
                                               **f.gbuffers))
    with pytest.raises(contract.FrameInputError, match="color: expected a pyopencl"):
        up.step_device(f.color, d(f.depth), d(f.motion), f.jitter, **gb)
    with pytest.raises(contract.FrameInputError, match=r"color: expected shape \(h, w, 3\)"):
        up.step_device(d(f.color[..., :2]), d(f.depth), d(f.motion), f.jitter, **gb)


def _kwargs(name):
    # the trained methods at their seeded init, which their twins build too
    return {"weights": "untrained"} if methods.spec(name).weights() != "none needed" else {}


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("name", methods.names())
def test_method_matches_its_onnx_twin(name, precision, dev):
    seq = frames(RENDER, 6)
    ours = clss.Upscaler(method=name, scale=2.0, device=dev, precision=precision,
                         **_kwargs(name))
    twin = methods.twin(name, RENDER, 2.0)
    for i, f in enumerate(seq):
        reset = i == RESET_AT
        a = ours.step(f.color, f.depth, f.motion, f.jitter, reset=reset, **f.gbuffers)
        b = twin.step(f.color, f.depth, f.motion, f.jitter, reset=reset, **f.gbuffers)
        assert a.shape == b.shape == (26, 34, 3) and a.dtype == np.float32
        tol = 1e-4 if precision == "fp32" else 1e-2
        ok = (np.abs(a - b) <= tol * np.abs(b).max() + tol * np.abs(b)).all(-1).mean()
        need = 1.0 if precision == "fp32" and not methods.spec(name).temporal else 0.99
        assert ok >= need, f"{name}/{precision} frame {i}: {ok:.2%} of pixels within tolerance"


def test_jbicubic_is_the_frame_step_without_history(dev):
    # bit for bit what CLSS's rule mode gives when every frame is a reset
    seq = frames(RENDER, 4)
    jb = clss.Upscaler(method="jbicubic", device=dev)
    rules = clss.Upscaler(method="clss-rules", device=dev)
    for f in seq:
        a = jb.step(f.color, f.depth, f.motion, f.jitter)
        b = rules.step(f.color, f.depth, f.motion, f.jitter, reset=True)
        assert np.array_equal(a, b)


# ---- G-buffers as a method sees them ------------------------------------------------------

def _needs(buffers):
    """A method that needs `buffers` (a test double: the registry's methods take their
    G-buffers through the same MethodUpscaler._gbuffers)."""
    spec = MethodSpec("needy", "needy", "needs G-buffers", lambda **kw: None, gbuffers=buffers)

    class Needy(MethodUpscaler):
        render_size = None

        def __init__(self):
            self.spec = spec
            self._init_common(2.0, None, "fp32")

        def step(self, color, depth, motion, jitter, reset=False, reactive=None, **gb):
            h, w = color.shape[:2]
            return self._gbuffers(gb, (h, w), contract.output_size(h, w, self.scale))
    return Needy()


@pytest.mark.parametrize("name", list(contract.GBUFFERS))
def test_a_missing_gbuffer_is_a_named_error(name):
    f = frames(RENDER, 1)[0]
    up = _needs((name,))
    got = up.step(f.color, f.depth, f.motion, f.jitter, **f.gbuffers)
    assert list(got) == [name] and got[name].dtype == np.float32
    gb = {k: v for k, v in f.gbuffers.items() if k != name}
    with pytest.raises(contract.MissingInputError) as e:
        up.step(f.color, f.depth, f.motion, f.jitter, **gb)
    msg = str(e.value)
    assert "method 'needy' needs " + name in msg and f"{name}=" in msg and "--channels" in msg


@pytest.mark.parametrize("name", methods.names())
def test_every_method_names_each_gbuffer_it_needs(name, dev):
    # Today's methods need none; each one that does (NSRD's albedo, the MLP's depth_hr)
    # is held here to the named error for every buffer it needs.
    spec = methods.spec(name)
    f = frames(RENDER, 1)[0]
    for g in spec.gbuffers:
        up = clss.Upscaler(method=name, device=dev, **_kwargs(name))
        gb = {k: v for k, v in f.gbuffers.items() if k != g}
        with pytest.raises(contract.MissingInputError, match=g):
            up.step(f.color, f.depth, f.motion, f.jitter, **gb)
    # and every method runs on a frame with every G-buffer given (unused ones ignored)
    up = clss.Upscaler(method=name, device=dev, **_kwargs(name))
    assert up.step(f.color, f.depth, f.motion, f.jitter, **f.gbuffers).shape == (26, 34, 3)


# ---- the command line ------------------------------------------------------------------------

def test_clss_methods_lists_every_method(capsys):
    from clss.cli import main
    assert main(["methods"]) == 0
    out = capsys.readouterr().out
    for name in methods.names() + list(methods.PLANNED):
        assert name in out
    assert "trained" in out and "none needed" in out
    assert main(["methods", "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert [m["name"] for m in rec["methods"]] == methods.names()
    assert all(set(m) >= {"inputs", "gbuffers", "scales", "precisions", "weights"}
               for m in rec["methods"])


def test_clss_eval_scores_without_torch(tmp_path, capsys):
    # `clss eval`: the scoring of weights_tools eval from the runtime's own command
    from clss.cli import main
    from clss.demo.scene import render_frame
    fr = [render_frame(30 + i, (9, 14), 2.0, spp_ref=2) for i in range(4)]
    p = tmp_path / "cap.npz"
    np.savez(p, color=np.stack([f.color for f in fr]), depth=np.stack([f.depth for f in fr]),
             motion=np.stack([f.motion for f in fr]), jitter=np.array([f.jitter for f in fr],
                                                                       np.float32),
             reset=np.array([True, False, False, False]),
             reference=np.stack([f.reference for f in fr]), scale=np.float32(2.0))
    rc = main(["eval", str(p), "--methods", "bicubic,rules", "--warmup", "1", "--flip-every",
               "3", "--out", str(tmp_path / "ev")])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert "bicubic" in cap.out and "CLSS rules" in cap.out and "tPSNR" in cap.out
    rec = json.loads((tmp_path / "ev" / "eval.json").read_text())
    assert list(rec["sequences"][0]["methods"]) == ["bicubic", "clss-rules"]
    assert main(["eval", str(p), "--methods", "taa"]) == 2
    assert "expected a subset of bicubic,jbicubic" in capsys.readouterr().err


def test_upscale_refuses_a_method_without_its_gbuffers_before_writing(tmp_path):
    from clss.cli.args import UsageError
    from clss.cli.upscale import _check_gbuffers
    from clss.io import FrameSequence  # noqa: F401  (the frames _check_gbuffers reads)
    f = frames(RENDER, 1)[0]

    class Frame:
        color, gbuffers = f.color, {k: v for k, v in f.gbuffers.items() if k != "albedo"}
    spec = MethodSpec("needy", "needy", "", lambda **kw: None, gbuffers=("albedo", "depth_hr"))
    with pytest.raises(UsageError, match="needs albedo") as e:
        _check_gbuffers("needy", spec, Frame, 2.0)
    assert "nothing was written" in str(e.value) and "--channels 'albedo=" in str(e.value)


def test_step_device_takes_float16_arrays(dev):
    """step_device converts float16 device arrays on the device (pipeline.method.
    convert_storage, round to nearest even both ways, as numpy): bit-equal to numpy, and
    the frame equals the host step on the same values."""
    from clss.pipeline.method import convert_storage
    g = np.random.default_rng(0)
    x = np.concatenate([g.standard_normal(997) * 100, [0.5 + 2.0 ** -11, 65504.0, 1e-6, -0.0]])
    x = x.astype(np.float32)
    h = convert_storage(dev.to_device(x), np.float16)
    assert h.dtype == np.float16 and np.array_equal(h.get(), x.astype(np.float16))
    assert np.array_equal(convert_storage(h, np.float32).get(), x.astype(np.float16).astype(np.float32))
    f = frames(RENDER, 1)[0]
    c16 = f.color.astype(np.float16)
    want = clss.Upscaler(method="clss-rules", device=dev).step(
        c16.astype(np.float32), f.depth, f.motion, f.jitter)
    got = clss.Upscaler(method="clss-rules", device=dev).step_device(
        convert_storage(dev.to_device(f.color), np.float16), dev.to_device(f.depth),
        dev.to_device(f.motion), f.jitter)
    assert np.array_equal(got.get(), want)
