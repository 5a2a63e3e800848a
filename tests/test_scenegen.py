"""The training-data generator (weights_tools.scenegen): format, determinism, labels on
hand-built scenes, motion. Tiny sizes: the whole file runs in a few seconds."""
import json

import numpy as np
import pytest

from clss.demo import scene
from weights_tools import scenegen as sg
from weights_tools.__main__ import main

SIZE = (12, 20)


def _spec(objects, camera=None, light=None, frames=3, jittered=False):
    cam = dict(kind="static", speed=0.0, pos=[0.0, 1.2, 5.0], target=[0.0, 0.6, -2.0],
               side=[1.0, 0.0], bob=0.0, radius=6.0)
    cam.update(camera or {})
    lit = dict(elev=0.9, azim=0.6, sun=[1.5, 1.4, 1.3], ambient=[0.2, 0.2, 0.25],
               anim="static", rate=0.0, pulse=0.5, change_at=1, dim=0.3)
    lit.update(light or {})
    return sg.SceneSpec(seed=0, index=0, frames=frames, jittered=jittered, cut=0,
                        cameras=[cam, cam], light=lit, objects=objects)


def _plain(color):
    return dict(kind="plain", freq=1.0, basis=np.eye(3).tolist(), c0=color, c1=color, duty=0.5)


def _sphere(pos, radius, vel=(0, 0, 0), color=(0.8, 0.2, 0.1)):
    return dict(type="sphere", pos=list(pos), radius=radius, half=[radius] * 3, yaw=0.0,
                min_y=0.0, tex=_plain(list(color)), spec=[0.0, 1.0], emission=None,
                motion=dict(vel=list(vel), bounce=0.0, freq=0.0, phase=0.0, spin=0.0))


def _floor(color=(0.5, 0.5, 0.45)):
    """A plain slab over the (finely textured) ground: a smooth picture."""
    return dict(type="box", pos=[0.0, 0.01, -10.0], half=[40.0, 0.01, 30.0], yaw=0.0,
                tex=_plain(list(color)), spec=[0.0, 1.0], emission=None,
                motion=dict(vel=[0, 0, 0], bounce=0.0, freq=0.0, phase=0.0, spin=0.0))


@pytest.fixture(scope="module")
def random_seq():
    spec = sg.SceneSpec.random(7, 3, 4)
    return spec, sg.render_sequence(spec, SIZE, 2.0, 4)


def test_format(random_seq, tmp_path):
    spec, data = random_seq
    T, (h, w) = 4, SIZE
    H, W = 2 * h, 2 * w
    path = str(tmp_path / "s.npz")
    sg.write_sequence(path, data)
    d = np.load(path, allow_pickle=False)
    want = {"color": (np.float32, (T, h, w, 3)), "depth": (np.float32, (T, h, w)),
            "motion": (np.float32, (T, h, w, 2)), "jitter": (np.float32, (T, 2)),
            "reset": (np.bool_, (T,)), "reference": (np.float32, (T, H, W, 3)),
            "label_ghost": (np.uint8, (T, H, W)), "label_alias": (np.uint8, (T, H, W)),
            "scale": (np.float32, ()),
            # The G-buffers (tests/test_gbuffers.py checks their contents).
            "albedo": (np.float32, (T, h, w, 3)), "normal": (np.float32, (T, h, w, 3)),
            "albedo_hr": (np.float32, (T, H, W, 3)), "depth_hr": (np.float32, (T, H, W)),
            "normal_hr": (np.float32, (T, H, W, 3))}
    assert set(d.files) == set(want) | {"meta"}
    for k, (dt, shape) in want.items():
        assert d[k].dtype == dt and d[k].shape == shape, k
        assert np.isfinite(d[k]).all() if d[k].dtype.kind == "f" else True
    assert d["reset"][0] and float(d["scale"]) == 2.0
    assert (d["depth"] >= 0).all() and (d["depth"] <= 1).all()
    assert (np.abs(d["jitter"]) <= 0.5).all()
    assert d["label_ghost"].max() <= 2 and d["label_alias"].max() <= 2
    assert (d["label_ghost"][0] == sg.GHOST_VISIBILITY).all()     # reset frame
    meta = json.loads(str(d["meta"]))
    assert meta["seed"] == 7 and meta["index"] == 3 and meta["label_rules_version"] == 1


def test_deterministic(random_seq):
    spec, data = random_seq
    again = sg.render_sequence(sg.SceneSpec.random(7, 3, 4), SIZE, 2.0, 4)
    for k in data:
        assert np.array_equal(data[k], again[k]), k
    assert sg.SceneSpec.random(8, 3, 4).to_json() != spec.to_json()
    assert sg.SceneSpec.random(7, 4, 4).to_json() != spec.to_json()


def test_trace_points_matches_trace():
    """The general (per-point) tracer sees what the separable one sees."""
    spec = sg.SceneSpec.random(3, 1, 2)
    prims = sg.build_primitives(spec, 1.0)
    h, w = 24, 40
    view = scene._View(prims, sg.camera_at(spec, 1.0, w / h), w, h, sg.light_at(spec, 1.0))
    us, vs = np.arange(w, dtype=np.float32) + 0.3, np.arange(h, dtype=np.float32) + 0.6
    out = {}
    color = scene._trace(view, us, vs, out=out)[0]
    u, v = np.meshgrid(us, vs)
    c, t, ids = scene.trace_points(view, u.ravel(), v.ravel())
    same = ids == out["ids"].ravel()
    assert same.mean() > 0.99          # float rounding may flip a silhouette sample
    np.testing.assert_allclose(c[same], color.reshape(3, -1).T[same], atol=2e-3)
    np.testing.assert_allclose(t[same], out["t"].ravel()[same], rtol=1e-4)


def _ids(spec, i, size):
    """Primitive ids at the output pixel centres of frame i."""
    h, w = size
    view = scene._View(sg.build_primitives(spec, float(i)), sg.camera_at(spec, float(i), w / h),
                       w, h, sg.light_at(spec, float(i)))
    out = {}
    scene._trace(view, np.arange(w, dtype=np.float32) + 0.5,
                 np.arange(h, dtype=np.float32) + 0.5, out=out)
    return out["ids"]


def test_visibility_ghosting_trails_a_moving_object():
    spec = _spec([_floor(), _sphere((-0.5, 0.8, 2.2), 0.6, vel=(0.3, 0, 0))])
    d = sg.render_sequence(spec, SIZE, 2.0, 1)
    H, W = 2 * SIZE[0], 2 * SIZE[1]
    before, now = _ids(spec, 1, (H, W)) == 1, _ids(spec, 2, (H, W)) == 1
    trailing = before & ~now                  # floor uncovered as the ball moves right
    leading = now & ~before
    assert trailing.sum() >= 10 and leading.sum() >= 10
    g = d["label_ghost"][2]
    assert (g[trailing] == sg.GHOST_VISIBILITY).mean() > 0.9
    assert (g[leading] == sg.GHOST_VISIBILITY).mean() < 0.2   # the ball was visible there
    far = np.zeros_like(now)
    far[:, :W // 8] = True                    # left strip: static floor and sky
    assert (g[far & ~before & ~now] == sg.GHOST_NONE).all()


def test_geometry_aliasing_on_a_thin_wire():
    wire = dict(type="fence", along_z=False, start=[-6.0, 0.0, -1.0], n=4, spacing=4.0,
                height=1.6, pole_r=0.004, wire_r=0.003, wires=1, color=[0.9, 0.9, 0.9],
                wire_color=[0.05, 0.05, 0.05])
    spec = _spec([_floor(), wire], frames=1)
    d = sg.render_sequence(spec, SIZE, 2.0, 16)
    a = d["label_alias"][0]
    ids = _ids(spec, 0, a.shape)
    assert (a == sg.ALIAS_GEOMETRY).sum() >= a.shape[1] // 2          # along the wire
    # Far from the wire and the horizon: one surface, smooth: no aliasing.
    sky_rows = (ids == scene.SKY_ID).all(1)
    assert sky_rows[:3].all() and (a[:3] == sg.ALIAS_NONE).all()


def test_thin_wire_shading_stays_bounded():
    """Millimetre wires: the float32 hit point is coarse next to the radius; the normal
    must stay of unit length or highlights reach thousands."""
    fence = dict(type="fence", along_z=False, start=[-6.0, 0.0, -6.0], n=13, spacing=1.0,
                 height=1.5, pole_r=0.01, wire_r=0.002, wires=4, color=[0.5, 0.5, 0.5],
                 wire_color=[0.8, 0.8, 0.8])
    spec = _spec([fence], camera=dict(pos=[0.0, 1.0, 6.0], target=[0.0, 0.8, -6.0]),
                 light=dict(sun=[3.0, 3.0, 3.0]), frames=1)
    prims = sg.build_primitives(spec, 0.0)
    n = 400          # the 4 mm wires, 12 m away, cover 0.2 px: some rows hit them
    view = scene._View(prims, sg.camera_at(spec, 0.0, 1.0), n, n, sg.light_at(spec, 0.0))
    u, v = np.meshgrid(np.arange(n, dtype=np.float32) + 0.5, np.arange(n) + 0.5)
    color, _, ids = scene.trace_points(view, u.ravel(), v.ravel())
    assert (ids >= 13).sum() > 20                            # wires seen
    assert color.max() < 4.0


def test_shading_ghosting_when_the_sun_dims():
    spec = _spec([_floor(), _sphere((0.0, 0.6, -1.0), 0.6)],
                 light=dict(anim="flicker", change_at=2, dim=0.3))
    d = sg.render_sequence(spec, SIZE, 2.0, 1)
    g1, g2 = d["label_ghost"][1], d["label_ghost"][2]
    assert (g1 == sg.GHOST_NONE).all()                       # nothing changes 0 -> 1
    lit = g2 != sg.GHOST_NONE
    assert (g2[lit] == sg.GHOST_SHADING).all() and lit.mean() > 0.5   # the floor, the ball


def test_motion_warps_the_previous_frame_onto_the_current():
    """Static smooth scene, panning and dollying camera: the previous colour sampled at
    p + motion matches the current colour away from edges."""
    objs = [_floor(), _sphere((-1.0, 0.6, -1.0), 0.6), _sphere((1.2, 0.9, -3.0), 0.9,
                                                              color=(0.2, 0.3, 0.8))]
    spec = _spec(objs, camera=dict(kind="mixed", speed=0.08, side=[0.8, 0.6]), jittered=True)
    h, w = 30, 48
    d = sg.render_sequence(spec, (h, w), 2.0, 1)
    cur, prev = d["color"][2], d["color"][1]
    (jx, jy), (pjx, pjy) = d["jitter"][2], d["jitter"][1]
    ii, jj = np.mgrid[0:h, 0:w].astype(np.float32)
    # Sample positions p (with this frame's jitter) and their previous positions; the
    # previous buffer holds samples at (j + 0.5 + pjx, i + 0.5 + pjy).
    qx = jj + 0.5 + jx + d["motion"][2, ..., 0] - 0.5 - pjx
    qy = ii + 0.5 + jy + d["motion"][2, ..., 1] - 0.5 - pjy
    assert np.abs(d["motion"][2]).max() > 1.0
    x0, y0 = np.floor(qx).astype(int), np.floor(qy).astype(int)
    ok = (x0 >= 0) & (y0 >= 0) & (x0 < w - 1) & (y0 < h - 1)
    x0, y0 = np.clip(x0, 0, w - 2), np.clip(y0, 0, h - 2)
    fx, fy = (qx - x0)[..., None], (qy - y0)[..., None]
    warped = ((prev[y0, x0] * (1 - fx) + prev[y0, x0 + 1] * fx) * (1 - fy)
              + (prev[y0 + 1, x0] * (1 - fx) + prev[y0 + 1, x0 + 1] * fx) * fy)
    err = np.abs(warped - cur).max(-1)[ok]
    still = np.abs(prev - cur).max(-1)[ok]
    assert np.median(err) < 2e-3 and np.percentile(err, 80) < 0.01
    assert np.percentile(still, 80) > 5 * np.percentile(err, 80)


def test_gen_command(tmp_path, capsys):
    out = tmp_path / "set"
    args = ["gen", "--out", str(out), "--sequences", "2", "--frames", "2", "--size", "8x12",
            "--spp", "2", "--workers", "1", "--quiet"]
    assert main(args) == 0
    assert sorted(p.name for p in out.iterdir()) == ["READY", "seq_0000.npz", "seq_0001.npz",
                                                     "stats.json"]
    stats = json.loads((out / "stats.json").read_text())
    assert abs(sum(stats["frequencies"]["alias"]) - 1) < 1e-9
    assert "visibility" in capsys.readouterr().out
    assert main(args) == 2                                  # refuses to overwrite
    assert "already exists" in capsys.readouterr().err
