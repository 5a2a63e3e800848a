import json
import os

import numpy as np
import pytest

oiio = pytest.importorskip("OpenImageIO")

from clss import io as cio  # noqa: E402
from clss.demo import scene  # noqa: E402


def _exr(path, data, names, window=None, full=None):
    """Write an EXR by hand; window = (x, y) data-window origin, full = (w, h) display."""
    h, w, c = data.shape
    spec = oiio.ImageSpec(w, h, c, "float")
    spec.channelnames = tuple(names)
    if window is not None:
        spec.x, spec.y = window
        spec.full_x, spec.full_y = 0, 0
        spec.full_width, spec.full_height = full
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(np.ascontiguousarray(data, np.float32))
    out.close()


@pytest.fixture(scope="module")
def frames():
    return scene.render_sequence(n_frames=3, render_size=(18, 32), scale=2, spp_ref=1)


def test_sample_sequence_round_trip(tmp_path, frames):
    paths = cio.write_sample_sequence(frames, str(tmp_path))
    assert os.path.basename(paths[-1]) == "jitter.json"
    seq = cio.read_sequence(str(tmp_path))
    assert len(seq) == 3 and seq.frame_numbers == [0, 1, 2]
    for a, b in zip(frames, seq):
        np.testing.assert_allclose(b.color, a.color, rtol=1e-3, atol=1e-4)   # half
        assert np.array_equal(b.depth, a.depth) and np.array_equal(b.motion, a.motion)
        np.testing.assert_allclose(b.reference, a.reference, rtol=1e-3, atol=1e-4)
        assert b.jitter == a.jitter and b.reset == a.reset
        assert b.color.dtype == np.float32 and b.depth.shape == a.depth.shape
    assert not [p for p in os.listdir(tmp_path) if ".tmp" in p]


def test_channel_search_and_override(tmp_path):
    rng = np.random.default_rng(0)
    d = rng.random((4, 5, 6), np.float32)
    p = tmp_path / "a.0001.exr"
    _exr(p, d, ["R", "G", "B", "depth.Z", "velocity.R", "velocity.G"])
    f = cio.read_frame(str(p))
    np.testing.assert_array_equal(f["depth"], d[..., 3])
    np.testing.assert_array_equal(f["motion"], d[..., 4:6])
    # Blender-like layer names: the Combined layer is found, the rest is named.
    q = tmp_path / "b.0001.exr"
    names = ["View.Combined.R", "View.Combined.G", "View.Combined.B", "View.Depth.Z",
             "View.Vector.X", "View.Vector.Y"]
    _exr(q, d, names)
    with pytest.raises(cio.InputError, match=r"b\.0001\.exr.*no depth channel"):
        cio.read_frame(str(q))
    f = cio.read_frame(str(q), channels={"depth": "View.Depth.Z",
                                         "motion": ("View.Vector.X", "View.Vector.Y")})
    np.testing.assert_array_equal(f["color"], d[..., :3])
    np.testing.assert_array_equal(f["motion"], d[..., 4:6])
    with pytest.raises(cio.InputError, match=r"b\.0001\.exr.*'mv\.x' for motion"):
        cio.read_frame(str(q), channels={"depth": "View.Depth.Z", "motion": "mv.x,mv.y"})


def test_data_window_placed_in_display_window(tmp_path):
    d = np.arange(2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3) + 1
    p = tmp_path / "w.exr"
    _exr(p, d, ["R", "G", "B"], window=(4, 1), full=(8, 5))
    a, names = cio.read_exr(str(p))
    assert a.shape == (5, 8, 3) and names == ["R", "G", "B"]
    np.testing.assert_array_equal(a[1:3, 4:7], d)
    assert a.sum() == d.sum()
    # A data window hanging over the display window's edge is clipped.
    _exr(p, d, ["R", "G", "B"], window=(-1, 4), full=(8, 5))
    a, _ = cio.read_exr(str(p))
    np.testing.assert_array_equal(a[4:5, 0:2], d[0:1, 1:3])
    assert a.sum() == d[0:1, 1:3].sum()


def test_per_buffer_files_and_csv_jitter(tmp_path):
    rng = np.random.default_rng(1)
    for n in (7, 8):
        _exr(tmp_path / f"color.{n:04d}.exr", rng.random((4, 6, 3), np.float32), "RGB")
        _exr(tmp_path / f"depth.{n:04d}.exr", rng.random((4, 6, 1), np.float32), ["Z"])
        _exr(tmp_path / f"motion.{n:04d}.exr", rng.random((4, 6, 2), np.float32), ["R", "G"])
    (tmp_path / "jitter.csv").write_text("frame,jx,jy\n7,0.25,-0.125\n8,-0.5,0.5\n")
    for src in (str(tmp_path),
                {b: str(tmp_path / f"{b}.%04d.exr") for b in ("color", "depth", "motion")}):
        seq = cio.read_sequence(src)
        assert seq.frame_numbers == [7, 8]
        f = seq[1]
        assert f.jitter == (-0.5, 0.5) and f.depth.shape == (4, 6) and f.motion.shape == (4, 6, 2)
        assert f.meta["files"]["depth"].endswith("depth.0008.exr")


def test_size_mismatch_names_files(tmp_path):
    _exr(tmp_path / "color.0001.exr", np.zeros((4, 6, 3)), "RGB")
    _exr(tmp_path / "depth.0001.exr", np.zeros((4, 5, 1)), ["Z"])
    _exr(tmp_path / "motion.0001.exr", np.zeros((4, 6, 2)), ["R", "G"])
    seq = cio.read_sequence(str(tmp_path), jitter="zero")
    with pytest.raises(cio.InputError, match=r"depth\.0001\.exr.*5x4.*color\.0001\.exr"):
        seq[0]
    # Across frames.
    for n, w in ((1, 6), (2, 7)):
        _exr(tmp_path / f"f.{n}.exr", np.zeros((4, w, 6)), ["R", "G", "B", "Z", "mv.x", "mv.y"])
    seq = cio.read_sequence(str(tmp_path / "f.%d.exr"), jitter="zero")
    seq[0]
    with pytest.raises(cio.InputError, match=r"f\.2\.exr.*7x4.*f\.1\.exr"):
        seq[1]


def test_unreadable_and_missing(tmp_path):
    p = tmp_path / "bad.0001.exr"
    p.write_bytes(b"not an exr at all")
    with pytest.raises(cio.InputError, match="bad.0001.exr"):
        cio.read_sequence(str(tmp_path / "bad.%04d.exr"), jitter="zero")[0]
    with pytest.raises(cio.InputError, match="nothing.exr: no such file"):
        cio.read_exr(str(tmp_path / "nothing.exr"))
    with pytest.raises(cio.InputError, match="no files match"):
        cio.read_sequence(str(tmp_path / "none.%04d.exr"), jitter="zero")
    assert issubclass(cio.InputError, ValueError)


def test_jitter_sources(tmp_path):
    d = np.zeros((2, 3, 6), np.float32)
    for n in (3, 4, 5):
        _exr(tmp_path / f"s.{n}.exr", d, ["R", "G", "B", "Z", "mv.x", "mv.y"])
    pat = str(tmp_path / "s.%d.exr")
    with pytest.raises(cio.InputError, match="no jitter sidecar"):
        cio.read_sequence(pat)
    seq = cio.read_sequence(pat, scale=2)
    assert [f.jitter for f in seq] == [scene.halton_jitter(i, 2) for i in range(3)]
    (tmp_path / "j.json").write_text(json.dumps({"jitter": {"3": [0.1, 0.2], "4": [0, 0],
                                                            "5": [-0.1, 0.3]}, "resets": [5]}))
    seq = cio.read_sequence(pat, jitter=str(tmp_path / "j.json"))
    assert seq[0].jitter == (0.1, 0.2) and seq[2].reset and not seq[1].reset
    seq = cio.read_sequence(pat, jitter=[[0.0, 0.1], [0.2, 0.3], [0.4, -0.5]])
    assert seq[1].jitter == (0.2, 0.3)
    with pytest.raises(cio.InputError, match="outside"):
        cio.read_sequence(pat, jitter=[[0.0, 0.1], [0.7, 0.3], [0.4, -0.5]])
    (tmp_path / "short.csv").write_text("0.1,0.1\n")
    with pytest.raises(cio.InputError, match="1 jitter values for 3 frames"):
        cio.read_sequence(pat, jitter=str(tmp_path / "short.csv"))


def test_write_exr_formats_and_names(tmp_path):
    p = tmp_path / "x.exr"
    img = np.random.default_rng(2).random((3, 4, 3), np.float32)
    cio.write_exr(str(p), img, half=[True, True, False], channel_names=["R", "G", "Z"])
    inp = oiio.ImageInput.open(str(p))
    spec = inp.spec()
    fmts = {n: str(spec.channelformat(i)) for i, n in enumerate(spec.channelnames)}
    inp.close()
    assert fmts == {"R": "half", "G": "half", "Z": "float"}
    a, names = cio.read_exr(str(p))
    assert np.array_equal(a[..., names.index("Z")], img[..., 2])
    with pytest.raises(ValueError, match="channel names"):
        cio.write_exr(str(p), img, channel_names=["R"])


def test_atomic_write_keeps_old_file(tmp_path):
    p = tmp_path / "keep.exr"
    cio.write_exr(str(p), np.ones((2, 2, 3)))
    before = p.read_bytes()

    def broken(tmp):
        with open(tmp, "wb") as fh:
            fh.write(b"partial")
        raise OSError("disk full")
    with pytest.raises(OSError, match="disk full"):
        cio._atomic_write(str(p), broken)
    assert p.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["keep.exr"]


def test_png_tonemap(tmp_path):
    img = np.zeros((2, 3, 3), np.float32)
    img[0, 0] = 100.0
    img[0, 1] = 0.18
    img[1, 2] = np.nan
    p = tmp_path / "t.png"
    cio.write_png(str(p), img)
    a, _ = cio.read_exr(str(p))          # OpenImageIO reads PNG too (as float 0..1)
    assert a.shape == (2, 3, 3)
    assert a[0, 0].min() > 0.99 and a[1, 0].max() == 0 and a[1, 2].max() == 0
    assert 0.3 < a[0, 1, 0] < 0.6        # mid grey lands mid-range
    t = cio.tonemap(np.linspace(0, 20, 50, dtype=np.float32))
    assert (np.diff(t) >= 0).all() and t[0] == 0 and t[-1] <= 1


def test_writes_respect_the_umask(tmp_path, frames):
    """Atomic writes (mkstemp, then rename) give files the mode open() would."""
    from clss.networks import save_weights
    old = os.umask(0o007)
    try:
        paths = cio.write_sample_sequence(frames[:1], str(tmp_path / "seq"))
        cio.write_png(str(tmp_path / "a.png"), frames[0].color)
        save_weights({"w": np.ones(3, np.float32)}, str(tmp_path / "w.safetensors"))
    finally:
        os.umask(old)
    for p in paths + [str(tmp_path / "a.png"), str(tmp_path / "w.safetensors")]:
        assert os.stat(p).st_mode & 0o777 == 0o660, p


def test_frame_selection_is_exact(tmp_path, frames):
    d = tmp_path / "seq"
    cio.write_sample_sequence(frames, str(d))
    for n in (7, 8):
        os.rename(d / f"frame.{n - 7:04d}.exr", d / f"frame.{n:04d}.exr")
    os.remove(d / "jitter.json")
    seq = cio.read_sequence(str(d), jitter="zero")
    assert seq.frame_numbers == [2, 7, 8]                     # numbers kept, gaps too
    (d / "frame.0002_old.exr").write_bytes((d / "frame.0002.exr").read_bytes())
    with pytest.raises(cio.InputError, match=r"frame\.0002_old\.exr.*frame\.%04d\.exr"):
        cio.read_sequence(str(d), jitter="zero")
    with pytest.raises(cio.InputError, match=r"frame\.0002_old\.exr"):
        cio.read_sequence(str(d / "*.exr"), jitter="zero")
    assert cio.read_sequence(str(d / "frame.%04d.exr"), jitter="zero").frame_numbers == [2, 7, 8]
    (d / "frame.7.exr").write_bytes((d / "frame.0007.exr").read_bytes())
    with pytest.raises(cio.InputError, match="frame 7 is given twice"):
        cio.read_sequence(str(d / "frame.%04d.exr"), jitter="zero")


def test_unknown_channels_key_is_refused(tmp_path, frames):
    cio.write_sample_sequence(frames, str(tmp_path))
    with pytest.raises(cio.InputError, match="unknown buffer 'colour'") as e:
        cio.read_sequence(str(tmp_path), channels={"colour": "R,G,B"})
    assert "--channels" in e.value.cli and "--channels" not in str(e.value)
