"""G-buffers (issue 19): the contract's table and checks (clss.pipeline.contract), EXR
sequences that carry them (clss.io), the sample scene and the training-data generator
that render them, and Blender's passes converted to the same conventions
(weights_tools/blender/convert.py) checked against the generator on a known scene."""
from __future__ import annotations

import dataclasses
import json
import math
import os

import numpy as np
import pytest

from clss.demo import scene
from clss.errors import UserError, cli_message
from clss.pipeline import contract
from clss.pipeline.contract import GBUFFERS, FrameInputError, MissingInputError

NAMES = ("albedo", "normal", "albedo_hr", "depth_hr", "normal_hr")
RENDER, OUTPUT = (6, 10), (12, 20)


def _arrays(dtype=np.float32):
    """One frame's worth of every G-buffer, small, with plausible values."""
    rng = np.random.default_rng(0)
    out = {}
    for name, g in GBUFFERS.items():
        a = rng.random(g.shape(RENDER, OUTPUT)).astype(dtype)
        out[name] = a
    return out


# ---------------------------------------------------------------- the table

def test_table():
    assert tuple(GBUFFERS) == NAMES
    for name, g in GBUFFERS.items():
        assert g.name == name and g.resolution in contract.GBUFFER_RESOLUTIONS
        assert len(g.exr_channels) == g.channels and g.meaning
        assert all(c.startswith(name + ".") for c in g.exr_channels)
        with pytest.raises(dataclasses.FrozenInstanceError):
            g.channels = 7
    assert [GBUFFERS[n].resolution for n in NAMES] == ["render"] * 2 + ["output"] * 3
    assert [GBUFFERS[n].channels for n in NAMES] == [3, 3, 3, 1, 3]
    assert GBUFFERS["depth_hr"].shape(RENDER, OUTPUT) == OUTPUT
    assert GBUFFERS["normal"].shape(RENDER, OUTPUT) == RENDER + (3,)
    # The errors the command line already turns into one line.
    assert issubclass(MissingInputError, FrameInputError) and issubclass(MissingInputError, UserError)


def test_every_name_is_a_channels_key():
    from clss import io as cio
    from clss.cli.upscale import parse_channels
    for name, g in GBUFFERS.items():
        assert cio.BUFFER_CHANNELS[name] == g.channels
        assert cio.GBUFFER_CANDIDATES[name][0] == g.exr_channels
    got = parse_channels("albedo=A.R,A.G,A.B;normal_hr=N.X,N.Y,N.Z;depth_hr=D.Z")
    assert got == {"albedo": "A.R,A.G,A.B", "normal_hr": "N.X,N.Y,N.Z", "depth_hr": "D.Z"}


# ---------------------------------------------------------------- validate_gbuffers

def _validate(needs=NAMES, optional=(), given=None, **kw):
    return contract.validate_gbuffers("nsrd", needs, optional,
                                      _arrays() if given is None else given, RENDER, OUTPUT, **kw)


def test_all_present():
    given = _arrays(np.float16)
    given["depth_hr"] = given["depth_hr"][..., None]           # H x W x 1 is accepted
    given["normal"] = np.asfortranarray(given["normal"])       # any memory layout
    out = _validate(given=given)
    assert set(out) == set(NAMES)
    for name, a in out.items():
        assert a.dtype == np.float32 and a.flags.c_contiguous
        assert a.shape == GBUFFERS[name].shape(RENDER, OUTPUT)
        np.testing.assert_array_equal(a.reshape(-1), given[name].astype(np.float32).reshape(-1))


def test_unused_and_optional():
    given = _arrays()
    # Needed + optional present are returned; one the method does not use is left out.
    out = contract.validate_gbuffers("mlp", ("depth_hr",), ("normal_hr", "albedo_hr"),
                                     {"depth_hr": given["depth_hr"], "albedo": given["albedo"],
                                      "normal_hr": None}, RENDER, OUTPUT)
    assert set(out) == {"depth_hr"}
    assert contract.validate_gbuffers("bicubic", (), (), given, RENDER, OUTPUT) == {}
    # Not even checked: a method's unused buffer cannot fail its frame.
    assert contract.validate_gbuffers("mlp", ("depth_hr",), (),
                                      {"depth_hr": given["depth_hr"], "albedo": "junk"},
                                      RENDER, OUTPUT).keys() == {"depth_hr"}
    with pytest.raises(ValueError, match="unknown G-buffer name.*'?albedo_lr"):
        contract.validate_gbuffers("x", ("albedo_lr",), (), {}, RENDER, OUTPUT)


@pytest.mark.parametrize("name", NAMES)
def test_missing(name):
    given = _arrays()
    del given[name]
    with pytest.raises(MissingInputError) as e:
        _validate(given=given)
    msg, cli = str(e.value), cli_message(e.value)
    g = GBUFFERS[name]
    assert "'nsrd'" in msg and f"needs {name}," in msg
    # Where it is read from: keyword, npz key, EXR channels, --channels.
    assert f"keyword {name}=" in msg and f".npz key '{name}'" in msg
    assert ",".join(g.exr_channels) in msg and f"--channels '{name}=" in msg
    assert f"{name}.NNNN.exr" in msg
    assert "'nsrd'" in cli and f"--channels '{name}=" in cli and "keyword" not in cli
    assert "\n" not in cli
    # The other inputs were given: only this one is named as missing.
    assert msg.split("needs ")[1].split(", which")[0] == name


def test_missing_names_every_one():
    given = _arrays()
    for n in ("albedo", "albedo_hr", "normal"):
        del given[n]
    with pytest.raises(MissingInputError, match=r"needs albedo, normal, albedo_hr, which") as e:
        _validate(given=given)
    for n in ("albedo", "normal", "albedo_hr"):
        assert f"keyword {n}=" in str(e.value)


@pytest.mark.parametrize("name", NAMES)
def test_wrong_shape(name):
    given = _arrays()
    g = GBUFFERS[name]
    other = RENDER if g.resolution == "output" else OUTPUT     # the other resolution
    given[name] = np.zeros(g.shape(other, other), np.float32)
    with pytest.raises(FrameInputError, match=rf"^{name}: expected shape") as e:
        _validate(given=given)
    assert not isinstance(e.value, MissingInputError)
    assert f"{g.resolution} resolution" in str(e.value)
    if g.channels == 3:    # a channel too few
        given[name] = np.zeros(g.shape(RENDER, OUTPUT)[:2] + (2,), np.float32)
        with pytest.raises(FrameInputError, match=rf"^{name}: expected shape"):
            _validate(given=given)


@pytest.mark.parametrize("name", NAMES)
def test_wrong_type(name):
    given = _arrays()
    given[name] = given[name].astype(np.float64)
    with pytest.raises(FrameInputError, match=rf"^{name}: expected dtype float16 or float32"):
        _validate(given=given)
    given[name] = given[name].tolist()
    with pytest.raises(FrameInputError, match=rf"^{name}: expected a numpy array"):
        _validate(given=given)


@pytest.mark.parametrize("name", NAMES)
def test_non_finite(name):
    given = _arrays()
    a = given[name]
    a.reshape(-1)[5] = np.nan
    a.reshape(-1)[7] = np.inf
    with pytest.raises(FrameInputError, match=rf"^{name}: expected finite values, got 2 "
                                              r"non-finite.*sanitize=True") as e:
        _validate(given=given)
    assert "--sanitize" in cli_message(e.value)
    report = {}
    out = _validate(given=given, sanitize=True, report=report)
    assert report == {name: 2} and np.isfinite(out[name]).all()
    assert out[name].reshape(-1)[5] == 0 and out[name].reshape(-1)[7] == 0
    assert np.isnan(given[name].reshape(-1)[5])            # the caller's array untouched


# ---------------------------------------------------------------- clss.io

oiio = pytest.importorskip("OpenImageIO")
from clss import io as cio  # noqa: E402


def _frames(n=2, gb=True):
    return scene.render_sequence(n, (9, 16), 2.0, spp_ref=1, gbuffers=gb)


def test_io_round_trip(tmp_path):
    frames = _frames()
    cio.write_sample_sequence(frames, str(tmp_path), gbuffers=True)
    names = set(os.listdir(tmp_path))
    assert {f"{n}.{i:04d}.exr" for n in ("albedo_hr", "depth_hr", "normal_hr")
            for i in range(2)} <= names
    _, ch = cio.read_exr(str(tmp_path / "frame.0001.exr"))
    assert sorted(ch) == sorted(["R", "G", "B", "Z", "mv.x", "mv.y", "albedo.R", "albedo.G",
                                 "albedo.B", "normal.X", "normal.Y", "normal.Z"])
    seq = cio.read_sequence(str(tmp_path))
    assert len(seq) == 2 and seq.frame_numbers == [0, 1]
    assert str(tmp_path / "depth_hr.0001.exr") in seq.files
    for a, b in zip(frames, seq):
        assert set(b.gbuffers) == set(NAMES)
        np.testing.assert_allclose(b.gbuffers["albedo"], a.gbuffers["albedo"], rtol=1e-3)  # half
        for n in ("normal", "albedo_hr", "depth_hr", "normal_hr"):
            np.testing.assert_array_equal(b.gbuffers[n], a.gbuffers[n])
            assert b[n] is b.gbuffers[n]
        # The rest reads as it always did.
        assert np.array_equal(b.depth, a.depth) and np.array_equal(b.motion, a.motion)
        assert b.meta["files"]["normal_hr"].endswith(f"normal_hr.{a.index:04d}.exr")
    # A numbered pattern finds the per-buffer files beside its frames too.
    seq = cio.read_sequence(str(tmp_path / "frame.%04d.exr"))
    assert set(seq[1].gbuffers) == set(NAMES)


def test_io_without_gbuffers(tmp_path):
    """The files written without G-buffers are what they always were, and read back
    with an empty gbuffers dict (absent is no error at read time)."""
    frames = _frames(1)
    cio.write_sample_sequence(frames, str(tmp_path))
    assert sorted(os.listdir(tmp_path)) == ["frame.0000.exr", "jitter.json", "reference.0000.exr"]
    _, ch = cio.read_exr(str(tmp_path / "frame.0000.exr"))
    assert sorted(ch) == sorted(["R", "G", "B", "Z", "mv.x", "mv.y"])
    f = cio.read_sequence(str(tmp_path))[0]
    assert f.gbuffers == {} and f["albedo"] is None
    # Naming a G-buffer's channels makes it required: not found is an error then.
    with pytest.raises(cio.InputError, match=r"channel 'A\.R' for albedo not found"):
        cio.read_sequence(str(tmp_path), channels={"albedo": "A.R,A.G,A.B"})[0]
    with pytest.raises(cio.InputError, match=r"names depth_hr, but there are no depth_hr files") as e:
        cio.read_sequence(str(tmp_path), channels={"depth_hr": "D"})
    assert "--channels" in cli_message(e.value)


def _exr(path, data, names):
    h, w, c = data.shape
    spec = oiio.ImageSpec(w, h, c, "float")
    spec.channelnames = tuple(names)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(np.ascontiguousarray(data, np.float32))
    out.close()


def test_io_channel_names_and_per_buffer_files(tmp_path):
    rng = np.random.default_rng(1)
    h, w = 4, 6
    d = rng.random((h, w, 12), np.float32)
    # Renderer-style names, found without help: Albedo.* and N.*.
    _exr(tmp_path / "a.0000.exr", d, ["R", "G", "B", "Z", "mv.x", "mv.y", "Albedo.R",
                                      "Albedo.G", "Albedo.B", "N.X", "N.Y", "N.Z"])
    f = cio.read_sequence(str(tmp_path / "a.0000.exr"), jitter="zero")[0]
    np.testing.assert_array_equal(f.gbuffers["albedo"], d[..., 6:9])
    np.testing.assert_array_equal(f.gbuffers["normal"], d[..., 9:12])
    # Other names through channels= (what --channels 'albedo=...' passes).
    _exr(tmp_path / "b.0000.exr", d, ["R", "G", "B", "Z", "mv.x", "mv.y", "Q.R", "Q.G", "Q.B",
                                      "V.a", "V.b", "V.c"])
    f = cio.read_sequence(str(tmp_path / "b.0000.exr"), jitter="zero",
                          channels={"albedo": "Q.R,Q.G,Q.B", "normal": ("V.a", "V.b", "V.c")})[0]
    np.testing.assert_array_equal(f.gbuffers["albedo"], d[..., 6:9])
    np.testing.assert_array_equal(f.gbuffers["normal"], d[..., 9:12])
    assert cio.read_sequence(str(tmp_path / "b.0000.exr"), jitter="zero")[0].gbuffers == {}

    # One file per buffer: depth_hr.* is not taken for depth.*, nor albedo_hr.* for albedo.*
    per = tmp_path / "per"
    per.mkdir()
    for n in range(2):
        _exr(per / f"color.{n:04d}.exr", d[..., :3], ["R", "G", "B"])
        _exr(per / f"depth.{n:04d}.exr", d[..., 3:4], ["Z"])
        _exr(per / f"motion.{n:04d}.exr", d[..., 4:6], ["R", "G"])
        _exr(per / f"normal_{n:04d}.exr", d[..., 9:12], ["X", "Y", "Z"])
        _exr(per / f"depth_hr.{n:04d}.exr", np.full((2 * h, 2 * w, 1), n + 0.5), ["Z"])
        _exr(per / f"albedo_hr.{n:04d}.exr", np.full((2 * h, 2 * w, 3), 0.25), ["R", "G", "B"])
    seq = cio.read_sequence(str(per), jitter="zero", scale=2)
    f = seq[1]
    np.testing.assert_array_equal(f.depth, d[..., 3])
    assert set(f.gbuffers) == {"normal", "depth_hr", "albedo_hr"}
    np.testing.assert_array_equal(f.gbuffers["normal"], d[..., 9:12])
    assert f.gbuffers["depth_hr"].shape == (2 * h, 2 * w) and f.gbuffers["depth_hr"][0, 0] == 1.5
    # An output-size buffer of the wrong size names the file.
    with pytest.raises(cio.InputError, match=r"albedo_hr\.0001\.exr: albedo_hr is 12x8, the output size \(scale 1\.5\) is 9x6"):
        cio.read_sequence(str(per), jitter="zero", scale=1.5)[1]
    # A G-buffer some frames lack is refused with the frame.
    os.remove(per / "normal_0001.exr")
    with pytest.raises(cio.InputError, match=r"no normal file for frame 1"):
        cio.read_sequence(str(per), jitter="zero")
    with pytest.raises(cio.InputError, match=r"unknown G-buffer 'albedo_lr'"):
        cio.read_sequence(str(per), jitter="zero", gbuffers={"albedo_lr": "x.%04d.exr"})


# ---------------------------------------------------------------- clss.demo.scene

def test_scene_frames_carry_every_gbuffer():
    h, w = 18, 32
    frames = scene.render_sequence(3, (h, w), 2.0, spp_ref=1)
    plain = scene.render_sequence(3, (h, w), 2.0, spp_ref=1, gbuffers=False)
    for f, p in zip(frames, plain):
        assert p.gbuffers == {}
        for k in ("color", "depth", "motion", "reference"):
            assert np.array_equal(f[k], p[k]), k          # unchanged by the G-buffers
        assert f.jitter == p.jitter and f.reset == p.reset
        assert set(f.gbuffers) == set(NAMES)
        for n, a in f.gbuffers.items():
            assert a.dtype == np.float32 and a.flags.c_contiguous and np.isfinite(a).all()
            assert a.shape == GBUFFERS[n].shape((h, w), (2 * h, 2 * w)), n
        _check_gbuffer_values(f.gbuffers, f.depth)
        # What clss.Upscaler's methods check them with accepts them as they are.
        got = contract.validate_gbuffers("all", NAMES, (), f.gbuffers, (h, w), (2 * h, 2 * w))
        assert set(got) == set(NAMES)
    again = scene.render_frame(2, (h, w), 2.0, spp_ref=1)
    for n in NAMES:
        assert np.array_equal(again.gbuffers[n], frames[2].gbuffers[n])


def _check_gbuffer_values(gb, depth):
    """Sky: albedo, normal and depth 0; surfaces: unit normals, albedo >= 0."""
    for alb, nrm, dep in ((gb["albedo"], gb["normal"], depth),
                          (gb["albedo_hr"], gb["normal_hr"], gb["depth_hr"])):
        sky = dep == 0
        assert sky.any() and (~sky).any()
        assert (alb[sky] == 0).all() and (nrm[sky] == 0).all()
        assert (alb >= 0).all() and alb[~sky].max() > 0.3
        np.testing.assert_allclose(np.linalg.norm(nrm[~sky], axis=-1), 1, atol=1e-5)
        # Seen surfaces face the camera (+z toward it) but for grazing silhouettes.
        assert (nrm[~sky][:, 2] > 0).mean() > 0.95


def test_scene_gbuffers_where_they_are_taken():
    """Render-size G-buffers come from the colour's own (jittered) samples, output-size
    ones from the output pixel centres: both agree with a plain ray cast there."""
    h, w, t = 18, 32, 5
    f = scene.render_frame(t, (h, w), 2.0, spp_ref=0)
    prims, cam = scene.scene_at(float(t)), scene.camera_at(float(t), w / h)
    jx, jy = f.jitter
    us = np.arange(w, dtype=np.float32) + np.float32(0.5 + jx)
    vs = np.arange(h, dtype=np.float32) + np.float32(0.5 + jy)
    g = scene.trace_gbuffers(scene._View(prims, cam, w, h), us, vs)
    assert np.array_equal(g["albedo"], f.gbuffers["albedo"])
    assert np.array_equal(g["normal"], f.gbuffers["normal"])
    assert np.array_equal(g["depth"], f.depth)
    H, W = 2 * h, 2 * w
    out = {}
    scene._trace(scene._View(prims, cam, W, H), np.arange(W, dtype=np.float32) + 0.5,
                 np.arange(H, dtype=np.float32) + 0.5, out=out)
    np.testing.assert_array_equal(f.gbuffers["depth_hr"], scene.reversed_z(out["t"]))
    # The ground: its texture's albedo (ks 0), and world up seen from this camera.
    ground = out["ids"] == scene.GROUND_ID
    up_cam = np.array([cam.right[1], cam.up[1], -cam.fwd[1]], np.float32)
    np.testing.assert_allclose(f.gbuffers["normal_hr"][ground], np.broadcast_to(
        up_cam, (ground.sum(), 3)), atol=1e-6)
    table = {tuple(c) for c in scene.DEFAULT_GROUND.albedo.T.tolist()}
    assert {tuple(c) for c in f.gbuffers["albedo_hr"][ground].tolist()} <= table
    # The red striped ball: its albedo plus its specular factor (1.0).
    ball = out["ids"] == 0
    assert ball.sum() > 10
    red = np.array([0.8, 0.12, 0.1], np.float32) + np.float32(1.0)
    white = np.array([0.85, 0.85, 0.8], np.float32) + np.float32(1.0)
    a = f.gbuffers["albedo_hr"][ball]
    assert (np.isclose(a, red).all(-1) | np.isclose(a, white).all(-1)).all()


# ---------------------------------------------------------------- the generator

from weights_tools import scenegen as sg  # noqa: E402


def test_generator_writes_every_gbuffer(tmp_path):
    spec = sg.SceneSpec.random(5, 2, 3)
    h, w = 12, 20
    data = sg.render_sequence(spec, (h, w), 2.0, 2)
    plain = sg.render_sequence(spec, (h, w), 2.0, 2, gbuffers=False)
    assert set(data) == set(plain) | set(NAMES)
    for k in plain:                                   # existing keys bit for bit
        assert np.array_equal(data[k], plain[k]), k
    T = 3
    for n in NAMES:
        g = GBUFFERS[n]
        assert data[n].dtype == np.float32
        assert data[n].shape == (T,) + g.shape((h, w), (2 * h, 2 * w)), n
    for t in range(T):
        _check_gbuffer_values({n: data[n][t] for n in NAMES}, data["depth"][t])
    again = sg.render_sequence(sg.SceneSpec.random(5, 2, 3), (h, w), 2.0, 2)
    for n in NAMES:
        assert np.array_equal(data[n], again[n]), n
    path = str(tmp_path / "s.npz")
    sg.write_sequence(path, data)
    with np.load(path, allow_pickle=False) as z:
        for n in NAMES:
            assert np.array_equal(z[n], data[n])


def _plain(color):
    return dict(kind="plain", freq=1.0, basis=np.eye(3).tolist(), c0=list(color),
                c1=list(color), duty=0.5)


FLOOR_Y, FLOOR_COLOR, FLOOR_KS = 0.02, (0.5, 0.45, 0.4), 0.1
BALL_COLOR, BALL_KS, BALL_R = (0.7, 0.2, 0.1), 0.3, 0.5


def _known_spec():
    """A plain floor slab (top at y = 0.02) and a plain ball moving right and toward the
    camera, seen by a camera that slides, dollies and turns (the aim point sweeps)."""
    still = dict(vel=[0, 0, 0], bounce=0.0, freq=0.0, phase=0.0, spin=0.0)
    floor = dict(type="box", pos=[0.0, FLOOR_Y / 2, -10.0], half=[300.0, FLOOR_Y / 2, 300.0],
                 yaw=0.0, tex=_plain(FLOOR_COLOR), spec=[FLOOR_KS, 20.0], emission=None,
                 motion=still)
    ball = dict(type="sphere", pos=[-0.4, 0.7, 0.5], radius=BALL_R, half=[BALL_R] * 3, yaw=0.0,
                min_y=0.0, tex=_plain(BALL_COLOR), spec=[BALL_KS, 30.0], emission=None,
                motion=dict(still, vel=[0.15, 0.0, 0.1]))
    cam = dict(kind="mixed", speed=0.08, pos=[0.0, 1.3, 5.0], target=[0.0, 0.5, -2.0],
               side=[0.8, 0.6], bob=0.0, radius=6.0)
    light = dict(elev=0.9, azim=0.6, sun=[1.5, 1.4, 1.3], ambient=[0.2, 0.2, 0.25],
                 anim="static", rate=0.0, pulse=0.5, change_at=1, dim=0.3)
    return sg.SceneSpec(seed=0, index=0, frames=3, jittered=True, cut=0, cameras=[cam, cam],
                        light=light, objects=[floor, ball])


# clss.demo.scene's world has +y up and +z toward the viewer; Blender's has +z up (and +y
# away): X = x, Y = -z, Z = y, a rotation.
TO_BLENDER = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def _blender_camera(cam):
    """(location, world rotation) of the Blender camera that sees what `cam` sees: a
    Blender camera looks along its local -z with +y up, so its rotation's columns are
    right, up and backward (-forward)."""
    R = TO_BLENDER @ np.stack([cam.right, cam.up, -cam.fwd], 1)
    return TO_BLENDER @ cam.pos, R


def _cycles_passes(cam, prev_cam, ball_c, ball_c_prev, w, h, jitter=(0.0, 0.0)):
    """The passes Cycles writes for the known scene, computed here independently of
    clss.demo.scene's tracer, in Blender's conventions (sources: Blender's manual for the
    passes; Cycles' kernel, primitive_motion_vector, for the Vector pass):
      * raster coordinates in pixels from the image's bottom-left corner, +y up; the
        focal length is the one of a 60 degree vertical field of view (Blender fits the
        larger side: w > h here, angle = 2 atan(tan 30 deg * w / h));
      * the camera shift of render_validation.py samples pixel (i, j) at
        (j + 0.5 + jx, i + 0.5 + jy) of the unshifted image, rows counted from the top;
      * Depth.Z: distance along the camera's view axis (planar), 1e10 where nothing is hit;
      * Normal: world-space normal (Blender's world); DiffCol, GlossCol: the diffuse and
        glossy colour (albedo) of the closures; 0 on the background;
      * Vector: X, Y = previous raster position - current (Cycles' motion_pre -
        motion_center, the previous frame's object and camera transforms, the current
        projection: a shift cancels); Z, W = current - next (junk here: unused)."""
    L, R = _blender_camera(cam)
    Lp, Rp = _blender_camera(prev_cam)
    f = (h / 2) / math.tan(math.radians(30.0))
    jx, jy = jitter
    cols, rows = np.meshgrid(np.arange(w) + 0.5 + jx, np.arange(h) + 0.5 + jy)
    xr, yr = cols, h - rows                      # raster, +y up from the bottom edge
    dcam = np.stack([(xr - w / 2) / f, (yr - h / 2) / f, -np.ones_like(xr)], -1)
    d = dcam @ R.T                               # world directions (unit view-axis component)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = (FLOOR_Y - L[2]) / d[..., 2]
    t_floor = np.where(t_floor > 0, t_floor, np.inf)
    C, Cp = TO_BLENDER @ ball_c, TO_BLENDER @ ball_c_prev
    oc = L - C
    a = np.sum(d * d, -1)
    b = d @ oc
    disc = b * b - a * (oc @ oc - BALL_R ** 2)
    with np.errstate(invalid="ignore"):
        t_ball = (-b - np.sqrt(disc)) / a
    t_ball = np.where((disc > 0) & (t_ball > 0), t_ball, np.inf)
    on_ball = t_ball < t_floor
    t = np.minimum(t_ball, t_floor)
    hit = np.isfinite(t)
    P = L + np.where(hit, t, 0)[..., None] * d
    normal = np.where(on_ball[..., None], (P - C) / BALL_R, [0.0, 0.0, 1.0])
    P_prev = P + np.where(on_ball[..., None], Cp - C, 0.0)   # the floor stands still
    q = (P_prev - Lp) @ Rp                       # previous camera's coordinates
    xp = w / 2 + f * q[..., 0] / -q[..., 2]
    yp = h / 2 + f * q[..., 1] / -q[..., 2]
    diff = np.where(on_ball[..., None], BALL_COLOR, FLOOR_COLOR)
    gloss = np.where(on_ball, BALL_KS, FLOOR_KS)[..., None] * np.ones(3)
    zero = ~hit[..., None]
    ch = {"Depth.Z": np.where(hit, t, 1e10),
          "Vector.X": np.where(hit, xp - xr, 0.0), "Vector.Y": np.where(hit, yp - yr, 0.0),
          "Vector.Z": np.full(t.shape, 123.0), "Vector.W": np.full(t.shape, -77.0)}
    for k, c in enumerate("XYZ"):
        ch["Normal." + c] = np.where(zero[..., 0], 0.0, normal[..., k])
    for k, c in enumerate("RGB"):
        ch["DiffCol." + c] = np.where(zero[..., 0], 0.0, diff[..., k])
        ch["GlossCol." + c] = np.where(zero[..., 0], 0.0, gloss[..., k])
        ch["Combined." + c] = np.full(t.shape, 0.5)
    ch["Combined.A"] = np.ones(t.shape)
    return {"ViewLayer." + k: v.astype(np.float32) for k, v in ch.items()}, R


def test_blender_conventions_match_the_generator(tmp_path):
    """What Cycles would write for a known scene (a floor and a moving ball, a camera
    that moves and turns, jittered), through convert.py, equals what the generator
    writes for the same scene: motion (Vector pass sign and y axis), depth (planar Z ->
    reversed-Z), normals (world -> camera space), albedo (DiffCol + GlossCol), and the
    output-resolution G-buffers."""
    from weights_tools.blender import convert
    spec = _known_spec()
    h, w, scale = 24, 40, 2.0
    H, W = 48, 80
    gen = sg.render_sequence(spec, (h, w), scale, 1)
    src = tmp_path / "known"
    src.mkdir()
    frames = []
    for i in range(spec.frames):
        cam, prev_cam = (sg.camera_at(spec, float(i), w / h), sg.camera_at(spec, i - 1.0, w / h))
        ball = sg.build_primitives(spec, float(i))[1]
        jitter = tuple(float(v) for v in gen["jitter"][i])
        lr, R = _cycles_passes(cam, prev_cam, ball.rigid.c, ball.rigid.cp, w, h, jitter)
        hr, _ = _cycles_passes(cam, prev_cam, ball.rigid.c, ball.rigid.cp, W, H)
        ref = {k: v for k, v in hr.items() if ".Combined." in k}
        for name, ch in ((f"lr_{i:04d}.exr", lr), (f"hr_{i:04d}.exr", hr),
                         (f"ref_{i:04d}.exr", ref)):
            names = list(ch)
            _exr(src / name, np.stack([ch[n] for n in names], -1), names)
        frames.append(dict(lr=f"lr_{i:04d}.exr", ref=f"ref_{i:04d}.exr", hr=f"hr_{i:04d}.exr",
                           jitter=list(jitter), reset=i == 0, camera_rotation=R.tolist()))
    rec = dict(scene="known", description="floor and ball", render_size=[h, w],
               output_size=[H, W], scale=scale, near=scene.NEAR, spp=1, ref_spp=1,
               blender="synthetic", seconds={}, frames=frames)
    (src / "frames.json").write_text(json.dumps(rec))
    got = convert.convert_scene(str(src))
    assert set(NAMES) <= set(got) and "gbuffers" in json.loads(str(got["meta"]))

    assert np.abs(gen["jitter"]).max() > 0.05           # jittered, and the camera turns:
    r0, r2 = (np.array(f["camera_rotation"]) for f in (frames[0], frames[2]))
    assert np.abs(r0 - r2).max() > 0.01
    for i in range(1, spec.frames):
        for (depth, motion, albedo, normal) in (("depth", "motion", "albedo", "normal"),
                                                ("depth_hr", None, "albedo_hr", "normal_hr")):
            want_d, got_d = gen[depth][i], got[depth][i]
            hit = want_d > 0
            # The same surface in both (pixels along a silhouette may differ).
            same = hit & (np.abs(got_d - want_d) <= 1e-4 * want_d)
            assert same.sum() > 0.97 * hit.sum() and hit.mean() > 0.5, (i, depth)
            assert (got_d[~hit] == 0).sum() >= 0.97 * (~hit).sum()
            np.testing.assert_allclose(got[normal][i][same], gen[normal][i][same], atol=2e-4)
            np.testing.assert_allclose(got[albedo][i][same], gen[albedo][i][same], atol=1e-6)
            if motion is not None:
                m_got, m_want = got[motion][i][same], gen[motion][i][same]
                np.testing.assert_allclose(m_got, m_want, atol=3e-3)
                assert np.abs(m_want).max() > 1.0           # the check has teeth
                # Blender's Y unflipped, or its sign kept, would be far off.
                assert np.abs(m_got[:, 1] + m_want[:, 1]).max() > 0.1
    # The ball's albedo is its colour + its specular factor, the floor's likewise.
    ball_px = np.isclose(got["albedo"][1], np.add(BALL_COLOR, BALL_KS)).all(-1)
    assert ball_px.sum() > 10


def test_convert_gbuffers_from_passes_rotation():
    """A camera looking along Blender's -x with +z up (so its right is +y): a wall
    facing +x is seen head-on (+z in camera space), the floor's +z up is camera +y."""
    from weights_tools.blender import convert
    R = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])   # columns: x, y, z
    assert np.isclose(np.linalg.det(R), 1)
    ch = {f"DiffCol.{c}": np.full((1, 3), 0.25, np.float32) for c in "RGB"}
    ch.update({f"GlossCol.{c}": np.full((1, 3), 0.5, np.float32) for c in "RGB"})
    n = np.array([[[1, 0, 0], [0, 0, 1], [0, 0, 0]]], np.float32)     # wall, floor, sky
    ch.update({f"Normal.{c}": n[..., k] for k, c in enumerate("XYZ")})
    ch["Depth.Z"] = np.array([[2.0, 0.1, 1e10]], np.float32)
    g = convert.gbuffers_from_passes(ch, R, 0.1)
    np.testing.assert_allclose(g["normal"][0], [[0, 0, 1], [0, 1, 0], [0, 0, 0]], atol=1e-7)
    np.testing.assert_allclose(g["albedo"][0], 0.75)
    np.testing.assert_allclose(g["depth"][0], [0.05, 1.0, 0.0])
