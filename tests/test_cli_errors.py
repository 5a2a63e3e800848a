"""Every subcommand given bad arguments and bad files: one line naming the mistake, exit
status 2, no traceback, no input file touched, and nothing half-written.

The commands run in-process (clss.cli.main) on a 4-frame 13x9 sequence, so the whole
file takes seconds; every refusal here happens before any real work starts."""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import struct

import numpy as np
import pytest

pytest.importorskip("OpenImageIO")

from clss import io as cio  # noqa: E402
from clss.demo import scene  # noqa: E402
from clss.cli import main  # noqa: E402


def _digest(directory):
    h = hashlib.sha256()
    for root, _, files in sorted(os.walk(directory)):
        for f in sorted(files):
            p = os.path.join(root, f)
            h.update(p.encode() + open(p, "rb").read())
    return h.hexdigest()


def _safetensors(path, header, data=b""):
    h = json.dumps(header).encode()
    path.write_bytes(struct.pack("<Q", len(h)) + h + data)


@pytest.fixture(scope="module")
def frames():
    return scene.render_sequence(n_frames=4, render_size=(9, 13), scale=2, spp_ref=1)


@pytest.fixture(scope="module")
def work(tmp_path_factory, frames):
    """A sequence, a non-empty directory, bad weights, bad models and bad bench files."""
    d = tmp_path_factory.mktemp("cli_errors")
    cio.write_sample_sequence(frames, d / "seq")
    shutil.copytree(d / "seq", d / "bad_resets")
    side = json.loads((d / "seq" / "jitter.json").read_text())
    (d / "bad_resets" / "jitter.json").write_text(json.dumps(dict(side, resets="0,2")))
    (d / "full").mkdir()
    (d / "full" / "old.txt").write_text("a previous run")
    (d / "a_file").write_text("x")
    w = d / "weights"
    w.mkdir()
    f32 = {"dtype": "F32", "shape": [2], "data_offsets": [0, 8]}
    _safetensors(w / "list.safetensors", [1, 2])
    _safetensors(w / "no_offsets.safetensors", {"cls.stem.bias": {"dtype": "F32", "shape": [2]}})
    _safetensors(w / "truncated.safetensors", {"cls.stem.bias": dict(f32, shape=[4],
                                                                     data_offsets=[0, 16])}, bytes(8))
    _safetensors(w / "nan.safetensors", {"cls.stem.bias": f32}, np.float32([np.nan, 1]).tobytes())
    _safetensors(w / "huge.safetensors", {"cls.stem.bias": f32}, np.float32([1e30, 1]).tobytes())
    (w / "short.safetensors").write_bytes(b"abc")
    (w / "corrupt_onnx").mkdir()
    (w / "corrupt_onnx" / "classifier.onnx").write_bytes(b"\x08\x07garbage\xff\xff")
    (d / "bad.onnx").write_bytes(b"not a model")
    (d / "bench.json").write_text("[1, 2]")
    (d / "notes.txt").write_text("not an array")
    import onnx
    from onnx import TensorProto, helper
    g = helper.make_graph([helper.make_node("Relu", ["x"], ["y"])], "g",
                          [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["N", 3])],
                          [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["N", 3])])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 10
    onnx.save(m, d / "symbolic.onnx")
    return d


# (argv, what the one-line message must contain). {d} is the work directory.
BAD = [
    # upscale
    ("upscale {d}/seq -o {d}/o --device nosuch", "no device matches 'nosuch'"),
    ("upscale {d}/seq -o {d}/o --device ''", "--device"),
    ("upscale {d}/seq -o {d}/o --scale 0", "--scale"),
    ("upscale {d}/seq -o {d}/o --scale -2", "--scale"),
    ("upscale {d}/seq -o {d}/o -n 0", "--frames"),
    ("upscale {d}/seq -o {d}/o -n -3", "--frames"),
    ("upscale {d}/seq -o {d}/seq", "holds the input files"),
    ("upscale {d}/seq -o {d}", "holds the input files"),
    ("upscale {d}/seq -o {d}/seq/frame.0000.exr", "is a file"),
    ("upscale {d}/seq -o {d}/a_file/sub", "a_file is a file"),
    ("upscale {d}/seq -o {d}/full", "not empty"),
    ("upscale {d}/seq -o ''", "-o"),
    ("upscale {d}/seq -o {d}/o --motion-scale 2", "--motion-scale"),
    ("upscale {d}/seq -o {d}/o --motion-scale W,Q", "--motion-scale"),
    ("upscale {d}/seq -o {d}/o --channels colour=R,G,B", "unknown buffer 'colour'"),
    ("upscale {d}/seq -o {d}/o --channels depth", "--channels"),
    ("upscale {d}/seq -o {d}/o --channels depth=Q", "channel 'Q' for depth not found"),
    ("upscale {d}/seq -o {d}/o --mode rules --weights {d}/weights", "--weights applies to the net mode"),
    ("upscale {d}/seq -o {d}/o --weights ''", "--weights"),
    ("upscale {d}/seq -o {d}/o --weights {d}/weights/list.safetensors", "list.safetensors: not a valid"),
    ("upscale {d}/seq -o {d}/o --weights {d}/weights/no_offsets.safetensors", "data_offsets"),
    ("upscale {d}/seq -o {d}/o --weights {d}/weights/truncated.safetensors", "truncated"),
    ("upscale {d}/seq -o {d}/o --weights {d}/weights/short.safetensors", "short.safetensors"),
    ("upscale {d}/seq -o {d}/o --weights {d}/weights/nan.safetensors", "'cls.stem.bias' holds 1 non-finite"),
    ("upscale {d}/seq -o {d}/o --weights {d}/weights/huge.safetensors", "'cls.stem.bias' holds a value"),
    ("upscale {d}/seq -o {d}/o --weights {d}/weights/corrupt_onnx", "classifier.onnx: not an ONNX model"),
    ("upscale {d}/seq -o {d}/o --weights {d}/nothing", "does not exist"),
    ("upscale {d}/seq -o {d}/o --jitter {d}/nothing.json", "nothing.json"),
    ("upscale {d}/seq -o {d}/o --exposure 0", "--exposure"),
    ("upscale {d}/bad_resets -o {d}/o", "'resets' must be a list of frame numbers"),
    ("upscale {d}/seq -o {d}/o --mode bogus", "--mode"),
    ("upscale {d}/seq -o {d}/o --method nsrd --scale 3",
     "--method nsrd --scale 3: no trained weights for this scale"),
    ("upscale {d}/nothing -o {d}/o", "no files match"),
    ("upscale {d}/seq", "-o/--out"),
    # demo
    ("demo -o {d}/o -n 0", "--frames"),
    ("demo -o {d}/o --size 2x2", "--size"),
    ("demo -o {d}/o --modes rules,fancy", "--modes"),
    ("demo -o {d}/o --modes rules --weights {d}/weights", "--weights applies to the net mode"),
    ("demo -o {d}/full", "not empty"),
    ("demo -o {d}/a_file", "is a file"),
    ("demo -o {d}/o --scale 0", "--scale"),
    ("demo -o {d}/o --device nosuch --modes rules", "no device matches"),
    ("demo -o {d}/o --spp 0", "--spp"),
    ("demo -o {d}/o --workers -1", "--workers"),
    ("demo -o {d}/o --weights {d}/weights/nan.safetensors", "nan.safetensors"),
    ("demo -o {d}/o --methods nsrd --scale 3", "--weights untrained for the seeded init"),
    # verify, devices
    ("verify --json {d}/missing/v.json", "--json"),
    ("verify --json {d}", "is a directory"),
    ("verify --family nope", "unknown family"),
    ("verify --device nosuch", "no device matches"),
    ("verify --device ''", "--device"),
    ("verify --level huge", "--level"),
    ("devices --json {d}/missing/d.json", "does not exist"),
    # info, run
    ("info {d}/nothing.onnx", "no such model file"),
    ("info {d}/bad.onnx", "bad.onnx: not an ONNX model"),
    ("info {d}/symbolic.onnx", "--input-shape x="),
    ("info {d}/symbolic.onnx --input-shape x=0x3", "--input-shape"),
    ("info {d}/symbolic.onnx --input-shape 4x3", "--input-shape"),
    ("info {d}/symbolic.onnx --input-shape x=2x3 --json {d}/symbolic.onnx", "is an input file"),
    ("info {d}/symbolic.onnx --input-shape x=2x3 --json {d}/missing/i.json", "does not exist"),
    ("run {d}/symbolic.onnx --input foo=", "--input foo="),
    ("run {d}/symbolic.onnx --input =x.npy", "--input =x.npy"),
    ("run {d}/symbolic.onnx --input x={d}/nothing.npy", "nothing.npy: no such file"),
    ("run {d}/symbolic.onnx --input x={d}/notes.txt", "notes.txt: not a .npy array"),
    ("run {d}/symbolic.onnx --random-inputs", "--input-shape"),
    ("run {d}/symbolic.onnx --repeat 0", "--repeat"),
    ("run {d}/symbolic.onnx --output-dir {d}/a_file", "is a file"),
    ("run {d}/symbolic.onnx --json {d}/missing/r.json", "does not exist"),
    # model info, model run (the group)
    ("model info {d}/nothing.onnx", "no such model file"),
    ("model info {d}/bad.onnx", "bad.onnx: not an ONNX model"),
    ("model info {d}", "is a directory"),
    ("model info", "the following arguments are required: model"),
    ("model info {d}/symbolic.onnx --json {d}/symbolic.onnx", "is an input file"),
    ("model info {d}/symbolic.onnx --json {d}/missing/i.json", "does not exist"),
    ("model info {d}/symbolic.onnx --input-shape x=2x3", "unrecognized arguments: --input-shape"),
    ("model run {d}/symbolic.onnx --repeat 0", "--repeat"),
    ("model run {d}/symbolic.onnx --input x={d}/nothing.npy", "nothing.npy: no such file"),
    ("model nosuch", "unknown subcommand 'nosuch'"),
    ("model", "give a subcommand: info, run"),
    # bench, tune
    ("bench --quick --full", "--quick and --full"),
    ("bench --methods --host-waits", "--methods and --host-waits"),
    ("bench --compare {d}/bench.json {d}/bench.json", "not a clss bench result"),
    ("bench --compare {d}/nothing.json {d}/bench.json", "nothing.json: no such file"),
    ("bench --json {d}/missing/b.json", "--json"),
    ("bench --out {d}/a_file", "is a file"),
    ("bench --runs 0", "--runs"),
    ("bench --budget -1", "--budget"),
    ("bench --device nosuch --no-peak --filter nothing", "no device matches"),
    ("bench --tiny --no-peak --filter nothing", "matches no case"),
    ("verify --filter nothing", "matches no op"),
    ("tune --runs 0", "--runs"),
    ("tune --quick --full", "--quick and --full"),
    ("tune --db {d}/missing/t.json", "--db"),
    ("tune --device nosuch", "no device matches"),
    # the command itself
    ("nosuch", "unknown command"),
]


@pytest.mark.parametrize("method, key, close", [("nsrr", "widht", "widths"),
                                                ("nsrd", "precison", "precision"),
                                                ("mlp", "onlin", "online")])
def test_an_unknown_upscaler_keyword_is_one_line(method, key, close, capsys):
    """A keyword argument a method does not take (clss.Upscaler's TypeError) ends a
    command in one line with status 2, as a UserError does."""
    import clss
    from clss.cli.main import run_command
    rc = run_command("clss x", lambda argv: clss.Upscaler(method=method, **{key: 1}), [])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert f"unexpected keyword argument {key!r}; did you mean {close!r}?" in err


def _argv(template, d):
    import shlex
    return shlex.split(template.format(d=d))


@pytest.mark.parametrize("template,expected", BAD, ids=[t for t, _ in BAD])
def test_bad_arguments_fail_in_one_line(work, template, expected, capsys):
    before = _digest(work / "seq")
    rc = main(_argv(template, work))
    cap = capsys.readouterr()
    assert rc == 2, (template, cap.err)
    assert "Traceback" not in cap.err + cap.out
    first = cap.err.strip().splitlines()[0]
    assert first.startswith("clss"), cap.err
    assert expected in cap.err, cap.err
    assert _digest(work / "seq") == before
    assert not (work / "o").exists(), "a refused run created its output directory"


def test_clss_device_environment(work, monkeypatch, capsys):
    from clss import device
    monkeypatch.setattr(device, "_devices", {})        # get_device(None) caches the default
    monkeypatch.setenv("CLSS_DEVICE", "nosuch")
    for argv in (["upscale", str(work / "seq"), "-o", str(work / "o")], ["verify"],
                 ["demo", "-o", str(work / "o"), "--modes", "rules"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "no device matches 'nosuch'" in err and "Traceback" not in err


def test_version_and_help(capsys):
    from clss import __version__
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"clss {__version__}"
    assert main(["upscale", "--help"]) == 0
    out = capsys.readouterr().out
    for flag in ("--exposure", "--overwrite", "--motion-scale", "--sanitize"):
        assert flag in out
    assert main(["demo", "--help"]) == 0
    assert "output directory" in capsys.readouterr().out


# ---------------------------------------------------------------- upscale runs

def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    assert "Traceback" not in cap.err
    return rc, cap


def test_overwrite_replaces_the_whole_set(work, tmp_path, capsys):
    out = tmp_path / "out"
    assert _run(["upscale", work / "seq", "-o", out, "--mode", "rules", "--png"], capsys)[0] == 0
    assert len(os.listdir(out)) == 8
    rc, cap = _run(["upscale", work / "seq", "-o", out, "--mode", "rules", "-n", "2"], capsys)
    assert rc == 2 and "not empty" in cap.err and len(os.listdir(out)) == 8
    (out / "notes.txt").write_text("mine")
    rc, _ = _run(["upscale", work / "seq", "-o", out, "--mode", "rules", "-n", "2", "--overwrite"],
                 capsys)
    assert rc == 0
    assert sorted(os.listdir(out)) == ["frame.0000.exr", "frame.0001.exr", "notes.txt"]


def test_frames_are_named_by_their_number(work, tmp_path, capsys):
    seq = tmp_path / "seq"
    seq.mkdir()
    side = json.loads((work / "seq" / "jitter.json").read_text())
    for i in range(4):
        shutil.copy(work / "seq" / f"frame.{i:04d}.exr", seq / f"shot_{i + 10:03d}.exr")
    side["frames"] = [10, 11, 12, 13]
    side["resets"] = [10]
    (seq / "jitter.json").write_text(json.dumps(side))
    out = tmp_path / "out"
    assert _run(["upscale", seq, "-o", out, "--mode", "rules"], capsys)[0] == 0
    assert sorted(os.listdir(out)) == [f"frame.{n:04d}.exr" for n in (10, 11, 12, 13)]
    # A stray file is refused by name, and nothing is written ...
    shutil.copy(seq / "shot_012.exr", seq / "shot_012_backup.exr")
    shutil.copy(seq / "shot_012.exr", seq / "notes.exr")
    rc, cap = _run(["upscale", seq, "-o", tmp_path / "o2", "--mode", "rules"], capsys)
    assert rc == 2 and "notes.exr, shot_012_backup.exr" in cap.err and "shot_###.exr" in cap.err
    assert not (tmp_path / "o2").exists()
    # ... while a numbered pattern selects the frames exactly.
    rc, _ = _run(["upscale", seq / "shot_%03d.exr", "-o", tmp_path / "o3", "--mode", "rules"], capsys)
    assert rc == 0 and sorted(os.listdir(tmp_path / "o3")) == sorted(os.listdir(out))
    # The same number twice (shot_12 and shot_012) is ambiguous.
    os.remove(seq / "shot_012_backup.exr")
    os.remove(seq / "notes.exr")
    shutil.copy(seq / "shot_012.exr", seq / "shot_12.exr")
    rc, cap = _run(["upscale", seq, "-o", tmp_path / "o4", "--mode", "rules"], capsys)
    assert rc == 2 and "frame 12 is given twice" in cap.err


def test_sanitize_reports_what_it_replaced(work, tmp_path, capsys):
    seq = tmp_path / "seq"
    shutil.copytree(work / "seq", seq)
    data, names = cio.read_exr(seq / "frame.0002.exr")
    data[1, 2, 0] = data[3, 4, 3] = np.nan
    cio.write_exr(seq / "frame.0002.exr", data, half=False, channel_names=names)
    rc, cap = _run(["upscale", seq, "-o", tmp_path / "a", "--mode", "rules"], capsys)
    assert rc == 2 and "frame 2" in cap.err and "--sanitize" in cap.err
    assert "sanitize=True" not in cap.err
    rc, cap = _run(["upscale", seq, "-o", tmp_path / "b", "--mode", "rules", "--sanitize"], capsys)
    assert rc == 0
    assert "--sanitize: replaced 2 non-finite values in 1 of 4 frames: frame 2 (color 1, depth 1)" \
        in cap.out


def test_motion_scale_in_render_sizes(work, tmp_path, capsys):
    rc, cap = _run(["upscale", work / "seq", "-o", tmp_path / "a", "--mode", "rules",
                    "--motion-scale", "-W,H", "-n", "2"], capsys)
    assert rc == 0, cap.err
    from clss.cli.args import motion_scale, resolve_motion_scale
    assert resolve_motion_scale(motion_scale("-W,H"), (9, 13)) == (-13.0, 9.0)
    assert resolve_motion_scale(motion_scale("0.5,-1"), (9, 13)) == (0.5, -1.0)


def test_ctrl_c_leaves_whole_frames(work, tmp_path, capsys, monkeypatch):
    """Interrupted while frame 2 is half written (its EXR done, its PNG not): frame 2's
    files are removed, the message counts 2 frames, the status is 130."""
    import clss.io
    real = clss.io.write_png

    def write_png(path, *a, **k):
        if "frame.0002" in str(path):
            raise KeyboardInterrupt
        return real(path, *a, **k)
    monkeypatch.setattr(clss.io, "write_png", write_png)
    out = tmp_path / "out"
    rc, cap = _run(["upscale", work / "seq", "-o", out, "--mode", "rules", "--png"], capsys)
    assert rc == 130
    assert "interrupted; 2 frames written to" in cap.err
    assert sorted(os.listdir(out)) == ["frame.0000.exr", "frame.0000.png", "frame.0001.exr",
                                       "frame.0001.png"]


def test_ctrl_c_elsewhere_exits_130(capsys, monkeypatch):
    import clss.cli

    def interrupted(argv):
        raise KeyboardInterrupt
    monkeypatch.setitem(clss.cli.COMMANDS, "devices", (interrupted, ""))
    assert main(["devices"]) == 130
    err = capsys.readouterr().err
    assert "clss devices: interrupted" in err and "Traceback" not in err


def test_outputs_respect_the_umask(work, tmp_path, capsys):
    old = os.umask(0o027)
    try:
        rc, _ = _run(["upscale", work / "seq", "-o", tmp_path / "out", "--mode", "rules", "--png",
                      "-n", "1"], capsys)
    finally:
        os.umask(old)
    assert rc == 0
    for f in os.listdir(tmp_path / "out"):
        assert os.stat(tmp_path / "out" / f).st_mode & 0o777 == 0o640, f


def test_progress_lines_off_a_terminal():
    import io
    from clss.progress import progress
    log = io.StringIO()
    assert list(progress(range(3), desc="upscale", unit="frame", file=log, interval=0)) == [0, 1, 2]
    lines = log.getvalue().splitlines()
    assert len(lines) == 3 and lines[1].startswith("upscale: 2/3 frames (") and "ETA" in lines[1]
    quiet = io.StringIO()
    assert list(progress([1, 2], file=quiet)) == [1, 2] and quiet.getvalue() == ""


def test_read_only_output_places(work, tmp_path, monkeypatch, capsys):
    """A read-only directory (simulated: the tests may run as root, who may write anywhere)
    is refused before any work, for -o and for --json."""
    import errno
    import tempfile

    def denied(*a, **k):
        raise PermissionError(errno.EACCES, "Permission denied")
    monkeypatch.setattr(tempfile, "TemporaryFile", denied)
    monkeypatch.setattr(os, "access", lambda *a, **k: False)
    (tmp_path / "ro").mkdir()
    for argv, expected in (
            (["upscale", work / "seq", "-o", tmp_path / "ro"], "cannot write there (permission denied)"),
            (["upscale", work / "seq", "-o", tmp_path / "ro" / "new"], "is not writable"),
            (["verify", "--json", tmp_path / "ro" / "v.json"], "not writable"),
            (["demo", "-o", tmp_path / "ro" / "d"], "is not writable")):
        rc, cap = _run(argv, capsys)
        assert rc == 2 and expected in cap.err, cap.err


def test_demo_ctrl_c_leaves_whole_frames(frames, tmp_path, capsys, monkeypatch):
    import clss.io
    real = clss.io.write_png
    # The module's frames instead of rendering the scene again (seconds on a busy machine).
    monkeypatch.setattr(scene, "iter_sequence", lambda n, *a, **k: iter(frames[:n]))

    def write_png(path, *a, **k):
        if os.path.join("clss-rules", "frame.0001") in str(path):
            raise KeyboardInterrupt
        return real(path, *a, **k)
    monkeypatch.setattr(clss.io, "write_png", write_png)
    out = tmp_path / "demo"
    # --exr: the full sequences, whose frames must stay whole (by default the demo writes only
    # its pictures, after the last frame)
    rc, cap = _run(["demo", "-o", out, "-n", "3", "--size", "13x9", "--methods",
                    "bicubic,clss-rules", "--workers", "1", "--spp", "1", "--exr"], capsys)
    assert rc == 130 and "interrupted; 1 frames written" in cap.err, cap.err
    for d in ("bicubic", "clss-rules"):
        assert sorted(os.listdir(out / d)) == ["frame.0000.exr", "frame.0000.png"]
    assert sorted(os.listdir(out / "input")) == ["albedo_hr.0000.exr", "depth_hr.0000.exr",
                                                 "frame.0000.exr", "jitter.json",
                                                 "normal_hr.0000.exr", "reference.0000.exr"]
    side = json.loads((out / "input" / "jitter.json").read_text())
    assert side["frames"] == [0] and len(side["jitter"]) == 1
    assert cio.read_sequence(str(out / "input")).frame_numbers == [0]
