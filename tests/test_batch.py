"""`clss batch` (issue 52 part 2): sequences through Ray, one worker per device; a broken
sequence reported while the others finish; a batch killed mid-run resumed, its finished
frames kept (same mtimes) and every frame bit-identical to one `clss upscale` run. The
journal's checks (sizes, headers, torn lines, other settings) and the worker's resume run
without Ray; the Ray tests share one local session (starting Ray takes seconds)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import clss.io as cio
from clss import methods
from clss.cli import main
from clss.cli.batch import RAY_MISSING, _parser, output_names
from clss.cli.batch_resume import JOURNAL, Journal, settings_of
from clss.cli.batch_work import SequenceWorker
from clss.demo.scene import render_sequence
from clss.device import get_device, list_devices
from clss.pipeline.contract import CANNOT

METHOD = ["--method", "clss-rules"]     # temporal (resuming must warm its history), fast
FRAMES = {"a": 8, "b": 5}


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """Two tiny sequences, a copy of b with a frame that cannot be read, and each good
    sequence upscaled once by `clss upscale` (the reference every batch must match)."""
    d = tmp_path_factory.mktemp("batch")
    for name, n in FRAMES.items():
        cio.write_sample_sequence(render_sequence(n, (12, 20), 2.0, spp_ref=0, seed=n),
                                  d / "in" / name)
    (d / "in" / "broken").mkdir()
    for f in os.listdir(d / "in" / "b"):
        (d / "in" / "broken" / f).write_bytes((d / "in" / "b" / f).read_bytes())
    (d / "in" / "broken" / "frame.0002.exr").write_bytes(b"not an EXR file")
    for name in FRAMES:
        assert main(["upscale", str(d / "in" / name), "-o", str(d / "ref" / name), *METHOD,
                     "--device", _device()]) == 0
    return d


def _device() -> str:
    """The default device's index: the batch's workers and `clss upscale` run on it."""
    chosen = get_device().cl_device
    return str(next(i for i, (_, d) in enumerate(list_devices()) if d == chosen))


def _frames(directory):
    return sorted(f for f in os.listdir(directory) if f.startswith("frame."))


def _same_as_reference(work, out, name):
    ref = work / "ref" / name
    assert _frames(out) == _frames(ref)
    for f in _frames(ref):
        assert np.array_equal(cio.read_exr(out / f)[0], cio.read_exr(ref / f)[0]), f


def _job(work, name, out, *flags):
    """What `clss batch` hands a worker for one sequence (the parser's own options)."""
    a = vars(_parser().parse_args([str(work / "in" / name), "-o", str(out), *METHOD, *flags]))
    a.update(method="clss-rules", mode=None)
    return dict(index=0, name=name, input=str(work / "in" / name), out=str(out),
                method="clss-rules", args=a)


# ---------------------------------------------------------------- without Ray

class _Events(list):
    """What the worker puts its progress on (a ray.util.queue.Queue in a batch)."""
    put = list.append


def test_a_worker_resumes_where_frames_are_missing(work, tmp_path):
    """Frames 3 and 5 lost: the worker steps 0..5 (history), writes only 3 and 5, and
    every frame is the uninterrupted run's."""
    out = tmp_path / "a"
    worker = SequenceWorker(_device())
    r = worker.run(_job(work, "a", out))
    assert r["error"] is None and r["written"] == 8
    _same_as_reference(work, out, "a")
    kept = {f: os.stat(out / f).st_mtime_ns for f in _frames(out)}
    for f in ("frame.0003.exr", "frame.0005.exr"):
        os.remove(out / f)
        del kept[f]
    events = _Events()
    r = worker.run(_job(work, "a", out), events)
    assert (r["written"], r["skipped"], r["warmed"]) == (2, 6, 4), r["error"]
    assert events[0] == ("skipped", 0, 6) and events.count(("frame", 0)) == 2
    assert {f: os.stat(out / f).st_mtime_ns for f in kept} == kept
    _same_as_reference(work, out, "a")


def test_only_intact_journalled_frames_count(work, tmp_path):
    """A file cut short, a frame never journalled and a torn journal line are redone; a
    killed write's temporary file is removed."""
    out = tmp_path / "a"
    assert SequenceWorker(_device()).run(_job(work, "a", out))["error"] is None
    data = (out / "frame.0001.exr").read_bytes()
    (out / "frame.0001.exr").write_bytes(data[:len(data) // 2])
    lines = (out / JOURNAL).read_text().splitlines()
    lines = [ln for ln in lines if json.loads(ln)["frame"] != 4] + [lines[-1][:20]]
    (out / JOURNAL).write_text("\n".join(lines) + "\n")
    (out / ".frame.0006.exr.abc123.tmp.exr").write_bytes(b"half a frame")
    settings = settings_of(_job(work, "a", out)["args"])
    done = Journal(str(out)).open(settings, False, [], (24, 40))
    assert done == {0, 2, 3, 5, 6, 7}
    assert not [f for f in os.listdir(out) if ".tmp" in f]
    r = SequenceWorker(_device()).run(_job(work, "a", out))
    assert (r["written"], r["skipped"]) == (2, 6), r
    _same_as_reference(work, out, "a")


def test_other_settings_or_foreign_files_are_refused(work, tmp_path):
    out = tmp_path / "a"
    assert SequenceWorker(_device()).run(_job(work, "a", out, "--frames", "2"))["error"] is None
    r = SequenceWorker(_device()).run(_job(work, "a", out, "--exposure", "2"))
    assert "holds frames made with --exposure 1.0, not 2.0" in r["error"] and r["written"] == 0
    r = SequenceWorker(_device()).run(_job(work, "a", out, "--exposure", "2", "--overwrite"))
    assert r["error"] is None and r["written"] == 8
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("x")
    r = SequenceWorker(_device()).run(_job(work, "a", tmp_path / "mine"))
    assert "not empty and holds no clss batch output" in r["error"]


def test_output_names_tell_inputs_apart(tmp_path):
    for d in ("s1/beauty", "s2/beauty", "s3"):
        (tmp_path / d).mkdir(parents=True)
    names = output_names([str(tmp_path / d) for d in ("s1/beauty", "s2/beauty", "s3")])
    assert names == ["s1_beauty", "s2_beauty", "s3"]
    assert output_names([str(tmp_path / "s3" / "shot_a.####.exr")]) == ["shot_a"]
    assert main(["batch", str(tmp_path / "s3"), str(tmp_path / "s3/"), "-o",
                 str(tmp_path / "o")]) == 2


def test_help_names_the_batch_and_the_upscale_flags(capsys):
    assert main(["batch", "--help"]) == 0
    out = capsys.readouterr().out
    for flag in ("--ray-address", "--overwrite", "--method", "--ldr", "--motion-scale", "--png"):
        assert flag in out


def test_importing_clss_and_its_batch_command_does_not_import_ray():
    code = "import sys, clss, clss.cli.batch, clss.cli.batch_work; print('ray' in sys.modules)"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.stdout.strip() == "False", r.stderr[-2000:]


def test_without_ray_one_line_names_the_extra(work, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)       # import ray -> ImportError
    assert main(["batch", str(work / "in" / "a"), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert RAY_MISSING in err and "clss[batch]" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_a_flag_the_method_cannot_honour_ends_the_batch_before_it_starts(work, tmp_path, capsys):
    cannot = [n for n in methods.names() if methods.spec(n).handling("hdr")[0] == CANNOT]
    if not cannot:
        pytest.skip("every method honours --ldr")
    rc = main(["batch", str(work / "in" / "a"), "-o", str(tmp_path / "o"), "--method", cannot[0],
               "--ldr"])
    err = capsys.readouterr().err
    assert rc == 2 and f"--ldr: the method {cannot[0]} cannot honour it" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "o").exists()


# ---------------------------------------------------------------- on Ray

@pytest.fixture(scope="module")
def ray_session():
    ray = pytest.importorskip("ray", reason="clss batch needs Ray: pip install 'clss[batch]'")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield ray
    ray.shutdown()


def test_a_broken_sequence_is_reported_and_the_others_finish(work, tmp_path, ray_session,
                                                             capsys, monkeypatch):
    """Relative paths too: the workers' working directory is not the driver's."""
    monkeypatch.chdir(work / "in")
    rc = main(["batch", "a", "broken", "nowhere", "b", "-o", str(tmp_path / "out"), *METHOD,
               "--device", _device()])
    err = capsys.readouterr().err
    assert rc == 1 and "Traceback" not in err
    failed = [ln for ln in err.splitlines() if " failed: " in ln]
    assert len(failed) == 2, err
    assert failed[0].startswith("clss batch: broken (") and "frame.0002.exr" in failed[0]
    assert failed[1].startswith("clss batch: nowhere (") and "no files match" in failed[1]
    for name in FRAMES:
        _same_as_reference(work, tmp_path / "out" / name, name)


def _alive_workers(ray):
    from ray._private import state
    return [a for a in state.actors().values()
            if a.get("ActorClassName") == "SequenceWorker" and a.get("State") == "ALIVE"]


def test_a_killed_batch_resumes_without_redoing_frames(work, tmp_path, ray_session, capsys):
    """The driver is killed (SIGKILL) after a few frames; the same command again keeps
    those frames (same mtimes), makes the rest, and all are `clss upscale`'s."""
    ray = ray_session
    out, argv = tmp_path / "out", [str(work / "in" / "a"), "-o", str(tmp_path / "out"), *METHOD,
                                   "--device", _device()]
    env = dict(os.environ, CLSS_BATCH_FRAME_DELAY="1")
    driver = subprocess.Popen([sys.executable, "-m", "clss", "batch", *argv, "--ray-address",
                               ray.get_runtime_context().gcs_address], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    journal, t0 = out / "a" / JOURNAL, time.time()
    while not (journal.is_file() and len(journal.read_text().splitlines()) >= 3):
        assert driver.poll() is None, driver.stderr.read().decode()
        assert time.time() - t0 < 120, "the batch wrote no frames"
        time.sleep(0.05)
    driver.send_signal(signal.SIGKILL)
    driver.wait()
    driver.stderr.close()
    while _alive_workers(ray):          # Ray ends the dead driver's workers
        assert time.time() - t0 < 180
        time.sleep(0.1)
    # Finished: the frames journalled (a frame written but not yet journalled is redone).
    done = [json.loads(ln)["frame"] for ln in journal.read_text().splitlines()]
    kept = {f"frame.{n:04d}.exr": os.stat(out / "a" / f"frame.{n:04d}.exr").st_mtime_ns
            for n in done}
    assert 3 <= len(kept) < FRAMES["a"]
    assert main(["batch", *argv]) == 0
    report = capsys.readouterr().out
    assert f"{FRAMES['a'] - len(kept)} frames written, {len(kept)} kept" in report
    assert {f: os.stat(out / "a" / f).st_mtime_ns for f in kept} == kept
    _same_as_reference(work, out / "a", "a")
