"""make gpu-report (bench/gpu_report.py): the folder it writes, on any machine (--smoke: tiny
shapes, one kernel family, one network). The GPU figures themselves come from a GPU."""
import json
import subprocess
import sys


def test_the_report_folder_holds_each_step_and_the_commit(tmp_path):
    out = tmp_path / "report"
    r = subprocess.run([sys.executable, "-m", "bench.gpu_report", "--smoke", "--steps", "devices,verify",
                        "--out", str(out), "--budget-s", "600"], capture_output=True, text=True, timeout=700)
    doc = json.loads((out / "report.json").read_text())
    assert set(doc["steps"]) == {"devices", "verify"}, r.stderr[-2000:]
    assert doc["steps"]["verify"]["rc"] == 0, (out / "verify.txt").read_text()[-3000:]
    assert len(doc["commit"]) == 40
    md = (out / "report.md").read_text()
    assert "| verify | ok |" in md and "conv2d_gemm" not in md or "Conv" in md
    assert "passed" in (out / "verify.txt").read_text()
    assert r.returncode == 0


def test_a_bad_step_name_is_refused(tmp_path):
    r = subprocess.run([sys.executable, "-m", "bench.gpu_report", "--steps", "verify,bogus",
                        "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "--steps" in r.stderr and "Traceback" not in r.stderr
