"""Every method with its shipped weights, fed each jitter pattern engines send
(clss.io.jitter.PATTERNS) on a tiny static sequence, at 2x (issue 53): the output is
finite, and the method handles the jitter as docs/input-contract.md ("Without jitter, and
other patterns") says. The scene is a linear colour ramp rendered at each frame's jittered
sample positions, so where a sample goes is measurable: the error against the ramp at the
output pixel centres with the jitter as rendered, and with it negated (the classic sign
error of an engine integration).

  placed     each sample at its jittered position: the right jitter beats the negated one
             for every moving pattern; zero jitter reconstructs the centred samples
  quantised  (nsrr's zero-upsampling) each sample in the output pixel its position falls
             in: the right jitter beats the negated one on the 2x2 grid, whose samples sit
             at output pixel centres; the other patterns lose the position in the pixel
  ignored    jitter is not an input: the output does not depend on it
"""
import numpy as np
import pytest

import clss
from clss import methods
from clss.io.jitter import PATTERNS, pattern_jitter

H, W, S, T = 16, 24, 2, 6
BEHAVIOUR = {"jbicubic": "placed", "clss-rules": "placed", "clss": "placed", "mlp": "placed",
             "nsrd": "placed", "nss": "placed", "nsrr": "quantised",
             "bicubic": "ignored", "mlp-nofeature": "ignored"}
ZERO_BOUND = 0.01       # mean |error| on the ramp (values 0.1-1) with zero jitter


def ramp(x, y):
    return np.stack([0.1 + 0.03 * x, 0.1 + 0.04 * y, 0.3 + 0.01 * (x + y)], -1).astype(np.float32)


def _gbuffers():
    return dict(albedo=np.ones((H, W, 3), np.float32),
                normal=np.tile(np.float32([0, 0, 1]), (H, W, 1)),
                albedo_hr=np.ones((H * S, W * S, 3), np.float32),
                depth_hr=np.full((H * S, W * S), 0.5, np.float32))


def ramp_error(method, dev, pattern, sign):
    """Mean |output - ramp| inside a 6-pixel border after T frames of a static ramp
    rendered with `pattern`'s jitter and fed that jitter times `sign`."""
    up = clss.Upscaler(method=method, scale=S, device=dev)
    gb = _gbuffers()
    for t, (jx, jy) in enumerate(pattern_jitter(pattern, T, S)):
        xs, ys = np.meshgrid(np.arange(W) + 0.5 + jx, np.arange(H) + 0.5 + jy)
        out = up.step(ramp(xs, ys), np.full((H, W), 0.5, np.float32),
                      np.zeros((H, W, 2), np.float32), (sign * jx, sign * jy), reset=t == 0, **gb)
    assert out.shape == (H * S, W * S, 3) and np.isfinite(out).all()
    X, Y = np.meshgrid(np.arange(W * S) + 0.5, np.arange(H * S) + 0.5)
    return float(np.abs(out - ramp(X / S, Y / S))[6:-6, 6:-6].mean())


def test_every_method_has_a_documented_jitter_behaviour():
    for name in methods.names():
        if S * 1.0 < methods.spec(name).scales[0] or S > methods.spec(name).scales[1]:
            continue
        reads = "jitter" in methods.spec(name).inputs
        assert name in BEHAVIOUR, f"{name}: say how it handles jitter (and in input-contract.md)"
        assert (BEHAVIOUR[name] != "ignored") == reads, name


@pytest.mark.parametrize("pattern", list(PATTERNS))
@pytest.mark.parametrize("method", list(BEHAVIOUR))
def test_method_with_pattern(method, pattern, dev):
    right = ramp_error(method, dev, pattern, 1)
    if pattern == "zero":
        assert right < ZERO_BOUND, right
        return
    negated = ramp_error(method, dev, pattern, -1)
    kind = BEHAVIOUR[method]
    if kind == "ignored":
        assert right == negated
    elif kind == "placed" or pattern == "2x2":
        assert right < negated, (right, negated)
    else:
        assert right < 2 * ZERO_BOUND, right
