import math

import numpy as np
import pytest

from clss import io as cio
from clss import metrics


def _img(seed, shape=(24, 32, 3)):
    return np.random.default_rng(seed).random(shape, dtype=np.float32)


def test_psnr_known_values():
    a = np.full((16, 16, 3), 0.5, np.float32)
    assert metrics.psnr(a, a) == math.inf
    assert metrics.psnr(a + 0.1, a, tonemapped=True) == pytest.approx(20.0, abs=1e-4)
    # Linear inputs are tone-mapped first: a highlight error of 10 in linear is bounded.
    b = a.copy()
    b[0, 0] = 50.0
    assert metrics.psnr(b, a) > 20
    with pytest.raises(ValueError, match="shapes differ"):
        metrics.psnr(a, a[:8])


def test_ssim():
    a = _img(0)
    assert metrics.ssim(a, a) == pytest.approx(1.0)
    noisy = a + 0.2 * _img(1)
    assert metrics.ssim(noisy, a) < 0.95
    assert metrics.ssim(a[..., 0], a[..., 0]) == pytest.approx(1.0)
    assert metrics.ssim(a[:5, :5], a[:5, :5]) == pytest.approx(1.0)   # small window


def test_temporal_psnr_catches_flicker():
    ref = [0.2 + 0.6 * _img(0)] * 4   # away from the [0, 1] clip
    steady = [r + 0.05 for r in ref]
    flicker = [r + (0.05 if i % 2 else -0.05) for i, r in enumerate(ref)]
    assert metrics.temporal_psnr(steady, ref, tonemapped=True) == math.inf
    assert metrics.temporal_psnr(flicker, ref, tonemapped=True) == pytest.approx(
        10 * np.log10(1 / 0.1 ** 2), abs=1e-3)
    # Both have about the same per-frame PSNR.
    m = metrics.sequence_metrics(flicker, ref, tonemapped=True)
    assert len(m["psnr"]) == 4 and m["psnr_mean"] > 25 and m["tpsnr"] < 21
    with pytest.raises(ValueError):
        metrics.temporal_psnr(ref[:1], ref[:1])


def test_temporal_profile():
    frames = [np.full((5, 7, 3), t, np.float32) + np.arange(7)[None, :, None]
              for t in range(3)]
    p = metrics.temporal_profile(frames, row=2, repeat=2)
    assert p.shape == (7, 6, 3)
    assert p[4, 0, 0] == 4 and p[4, 5, 0] == 6
    p = metrics.temporal_profile(frames, col=1, span=(1, 4), repeat=1)
    assert p.shape == (3, 3, 3)
    with pytest.raises(ValueError):
        metrics.temporal_profile(frames)


def test_side_by_side(tmp_path):
    lo, hi = _img(0, (10, 16, 3)), _img(1, (20, 32, 3))
    c = metrics.side_by_side([lo, hi], ["render", "reference"], gap=2, band=14)
    assert c.shape == (34, 66, 3) and c.min() >= 0 and c.max() <= 1
    # The low-res image is enlarged by pixel repetition.
    np.testing.assert_allclose(c[14:16, 0:2], np.broadcast_to(cio.tonemap(lo[0, 0]), (2, 2, 3)))
    # Labels draw into the band.
    assert c[:14].std() > 0.01
    z = metrics.side_by_side([lo, hi], crop=(2, 10, 4, 12), zoom=3)
    assert z.shape == (24, 24 + 4 + 24, 3)
    p = metrics.save_side_by_side(str(tmp_path / "s.png"), [lo, hi], ["a", "b"])
    a, _ = cio.read_exr(p)
    assert a.shape == (40, 68, 3)
    q = metrics.save_temporal_profiles(str(tmp_path / "t.png"), [[lo] * 3, [lo * 2] * 3],
                                       ["one", "two"], row=3)
    assert cio.read_exr(q)[0].shape[1] == 2 * 12 + 4


def test_text_bitmap():
    t = metrics.text_bitmap("PSNR 31.2 dB", 14)
    if t is None:
        pytest.skip("no font")
    assert t.ndim == 2 and 8 <= t.shape[0] <= 20 and t.max() > 0.9


def test_disocclusion_mask_finds_what_a_moving_box_uncovers():
    from clss.metrics import disocclusion_mask
    h, w = 12, 16
    prev = np.full((h, w), 0.1, np.float32)        # background at view depth 10 (near = 1)
    prev[4:8, 4:8] = 0.5                           # a box at 2, which moves right by 3
    cur = np.full((h, w), 0.1, np.float32)
    cur[4:8, 7:11] = 0.5
    motion = np.zeros((h, w, 2), np.float32)
    motion[4:8, 7:11, 0] = -3                      # the box's pixels came from 3 to the left
    m = disocclusion_mask(prev, cur, motion, (h, w))
    want = np.zeros((h, w), bool)
    want[4:8, 4:7] = True                          # background the box uncovered
    assert np.array_equal(m, want)
    # off screen counts; at 2x each render pixel is 2x2 output pixels
    motion[:, 0, 0] = -1
    m2 = disocclusion_mask(prev, cur, motion, (2 * h, 2 * w))
    assert m2[0:2, 0:2].all() and m2.sum() == 4 * (want.sum() + h)
