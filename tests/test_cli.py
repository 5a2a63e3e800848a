import json
import subprocess
import sys

from clss.cli import main


def test_help_lists_commands(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert "verify" in out and "devices" in out


def test_devices(capsys):
    assert main(["devices"]) == 0
    assert "fp16 arithmetic" in capsys.readouterr().out


def test_verify_table_and_json(tmp_path, capsys):
    j = tmp_path / "v.json"
    rc = main(["verify", "--family", "space_to_depth", "--precision", "all", "--json", str(j)])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "PASS" in out and "FAIL" not in out.split("\n\n")[0]
    rows = json.loads(j.read_text())["rows"]
    assert rows and all(r["passed"] for r in rows)
    assert {r["precision"] for r in rows} >= {"fp32", "fp16"}


def test_verify_bad_arguments():
    assert main(["verify", "--family", "nope"]) == 2
    assert main(["verify", "--device", "no-such-device"]) == 2
    assert main(["nope"]) == 2


def test_module_entry_point():
    p = subprocess.run([sys.executable, "-m", "clss", "--help"], capture_output=True, text=True)
    assert p.returncode == 0 and "verify" in p.stdout
