import math

import numpy as np
import pytest

from clss.demo import scene

SMALL = (54, 96)


@pytest.fixture(scope="module")
def frames():
    return scene.render_sequence(n_frames=6, render_size=SMALL, scale=2, spp_ref=4, seed=3)


def test_halton_jitter():
    assert scene.jitter_sequence_length(2) == 32
    assert scene.jitter_sequence_length(1.5) == 18
    assert scene.jitter_sequence_length(3) == 72
    assert scene.halton_jitter(0, 2) == pytest.approx((0.0, 1 / 3 - 0.5))
    assert scene.halton_jitter(1, 2) == pytest.approx((-0.25, 2 / 3 - 0.5))
    assert scene.halton_jitter(32, 2) == scene.halton_jitter(0, 2)
    js = np.array([scene.halton_jitter(i, 2) for i in range(32)])
    assert (js >= -0.5).all() and (js < 0.5).all()
    assert len({tuple(j) for j in js}) == 32
    # Well spread: every quadrant of the pixel gets a quarter of the samples.
    q = (js[:, 0] >= 0) * 2 + (js[:, 1] >= 0)
    assert set(np.bincount(q, minlength=4).tolist()) <= {7, 8, 9}


def test_frame_contract(frames):
    h, w = SMALL
    for i, f in enumerate(frames):
        assert f.index == i and f.reset == (i == 0)
        assert f.color.shape == (h, w, 3) and f.color.dtype == np.float32
        assert f.depth.shape == (h, w) and f.depth.dtype == np.float32
        assert f.motion.shape == (h, w, 2) and f.motion.dtype == np.float32
        assert f.reference.shape == (2 * h, 2 * w, 3) and f.reference.dtype == np.float32
        for a in (f.color, f.depth, f.motion, f.reference):
            assert np.isfinite(a).all()
        assert f.color.min() >= 0 and f.color.max() > 1.5          # HDR highlights
        assert f.depth.min() == 0 and 0 < f.depth.max() <= 1        # sky = 0, reversed-Z
        assert f.jitter == pytest.approx(scene.halton_jitter(i, 2))
        assert f["color"] is f.color


def test_deterministic(frames):
    again = scene.render_frame(4, render_size=SMALL, scale=2, spp_ref=4, seed=3)
    for k in ("color", "depth", "motion", "reference"):
        assert np.array_equal(again[k], frames[4][k])
    other = scene.render_frame(4, render_size=SMALL, scale=2, spp_ref=4, seed=4)
    assert np.array_equal(other.color, frames[4].color)
    assert not np.array_equal(other.reference, frames[4].reference)


def test_things_move_and_alias(frames):
    a, b = frames[1], frames[5]
    assert np.abs(a.motion).max() > 1 and np.median(np.abs(a.motion[..., 0])) > 0.1
    assert np.abs(a.color - b.color).mean() > 0.02
    # Point sampling aliases: the low-res frame is far from the box-filtered reference.
    h, w = SMALL
    ref_lo = a.reference.reshape(h, 2, w, 2, 3).mean((1, 3))
    assert np.abs(ref_lo - a.color).mean() > 0.02
    # ... but both estimate the same picture.
    assert abs(ref_lo.mean() - a.color.mean()) < 0.03


def _world_from_depth(cam, depth, jitter, w, h):
    jj, ii = np.meshgrid(np.arange(w) + 0.5 + jitter[0], np.arange(h) + 0.5 + jitter[1])
    d = cam.rays(jj, ii, w, h)
    z = scene.NEAR / np.where(depth > 0, depth, np.nan)
    return [cam.pos[k] + z * d[k] for k in range(3)], jj, ii


def _bilinear(img, x, y):
    h, w = img.shape
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    ok = (x0 >= 0) & (y0 >= 0) & (x0 < w - 1) & (y0 < h - 1)
    x0, y0 = np.clip(x0, 0, w - 2), np.clip(y0, 0, h - 2)
    v = ((img[y0, x0] * (1 - fx) + img[y0, x0 + 1] * fx) * (1 - fy)
         + (img[y0 + 1, x0] * (1 - fx) + img[y0 + 1, x0 + 1] * fx) * fy)
    return np.where(ok, v, np.nan)


@pytest.mark.parametrize("t", [3, 12])
def test_motion_depth_jitter_conventions(t):
    """Follow each ground pixel's motion into the previous frame: the previous depth
    buffer, bilinearly interpolated there (exact for a plane: reversed-Z depth is
    affine in screen space), must equal the depth of the same world point seen by the
    previous camera. Off by any jitter or half-pixel convention, it would not."""
    h, w = 72, 128
    cur = scene.render_frame(t, (h, w), 2, spp_ref=0)
    prev = scene.render_frame(t - 1, (h, w), 2, spp_ref=0)
    cam, pcam = scene.camera_at(t, w / h), scene.camera_at(t - 1, w / h)
    P, u, v = _world_from_depth(cam, cur.depth, cur.jitter, w, h)
    Pp, _, _ = _world_from_depth(pcam, prev.depth, prev.jitter, w, h)
    ground = np.abs(P[1]) < 1e-3
    prev_ground = np.nan_to_num(np.abs(Pp[1]), nan=1.0) < 1e-3
    qx, qy = u + cur.motion[..., 0], v + cur.motion[..., 1]
    # Prev buffer index of the position (its samples sit at j + 0.5 + jx').
    ix, iy = qx - 0.5 - prev.jitter[0], qy - 0.5 - prev.jitter[1]
    allg = _bilinear(prev_ground.astype(float), ix, iy) > 0.999
    sel = ground & allg
    assert sel.sum() > 0.3 * h * w
    up, vp, zp = pcam.project(P[0], P[1], P[2], w, h)
    np.testing.assert_allclose(up[sel], qx[sel], atol=2e-3)
    np.testing.assert_allclose(vp[sel], qy[sel], atol=2e-3)
    got = _bilinear(prev.depth.astype(np.float64), ix, iy)[sel]
    np.testing.assert_allclose(got, scene.NEAR / zp[sel], rtol=2e-3)
    # A half-pixel error in the convention would be visible in this test.
    off = _bilinear(prev.depth.astype(np.float64), ix + 0.5, iy + 0.5)[sel]
    assert np.nanmax(np.abs(off / (scene.NEAR / zp[sel]) - 1)) > 1e-2


def test_moving_object_motion():
    """A pixel on the translating blue sphere moves with the sphere, not the ground."""
    h, w, t = 72, 128, 10
    f = scene.render_frame(t, (h, w), 2, spp_ref=0)
    prims = scene.scene_at(float(t))
    mover = prims[1]
    cam, pcam = scene.camera_at(t, w / h), scene.camera_at(t - 1, w / h)
    P, u, v = _world_from_depth(cam, f.depth, f.jitter, w, h)
    c = mover.rigid.c
    on = np.abs(np.sqrt(sum((P[k] - c[k]) ** 2 for k in range(3))) - mover.r) < 1e-3
    assert on.sum() > 50
    shift = mover.rigid.cp - mover.rigid.c
    up, vp, _ = pcam.project(P[0] + shift[0], P[1] + shift[1], P[2] + shift[2], w, h)
    np.testing.assert_allclose(up[on] - u[on], f.motion[..., 0][on], atol=2e-3)
    np.testing.assert_allclose(vp[on] - v[on], f.motion[..., 1][on], atol=2e-3)


def test_fractional_scale_and_odd_spp():
    f = scene.render_frame(2, (20, 36), 1.5, spp_ref=5)
    assert f.reference.shape == (30, 54, 3)
    assert f.jitter == pytest.approx(scene.halton_jitter(2, 1.5))
    assert scene.output_size((270, 480), 1.7) == (459, 816)


def test_default_size_frame_cost():
    """One default-size frame (480x270 -> 960x540, 16 spp) stays cheap; the whole
    30-frame default sequence took ~21 s on one core when this was written."""
    import time
    t0 = time.perf_counter()
    f = scene.render_frame(7)
    dt = time.perf_counter() - t0
    assert f.reference.shape == (540, 960, 3)
    assert dt < 6.0, dt
    assert math.isfinite(float(f.reference.sum()))


def test_workers_match_serial():
    a = scene.render_sequence(3, (18, 32), 2, spp_ref=1)
    b = scene.render_sequence(3, (18, 32), 2, spp_ref=1, workers=2)
    for x, y in zip(a, b):
        assert np.array_equal(x.color, y.color) and np.array_equal(x.reference, y.reference)
