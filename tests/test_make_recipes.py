"""The Makefile's training recipes hold together (issue 31: `make train*` from a fresh clone).

Every `python -m weights_tools` command that `make -n` prints for the training targets is
handed to weights_tools' own argument parser, so a renamed or dropped flag fails here in
seconds instead of an hour into `make train-nsrd`; and every `--init` and `cp` source must be
written by an earlier command of the same run (a stage reading a file nothing wrote fails
the same way on a fresh clone). `make train-smoke` runs the same recipes for real, with bpy.
Skipped without make or torch (the [train] extra builds the training parsers)."""
from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess

import pytest

pytest.importorskip("torch")
if shutil.which("make") is None:
    pytest.skip("make is not installed", allow_module_level=True)

from weights_tools.__main__ import parser, spelled_out  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TARGETS = ("train-data-blender", "train", "train-mlp", "train-nsrr", "train-nsrd", "train-nss",
           "train-nss-gym")
COMMAND = re.compile(r"-m weights_tools (.*?)(?=\s*(?:&&|\|\||;|$))")


def dry_run(tmp_path, *args):
    """`make -n` of ARGS (targets and variables), with the stamps of an installed venv (so make
    prints the recipes, not the setup) and OUT in tmp_path: the recipe lines, their
    continuation lines joined."""
    stamps = {}
    for name in ("STAMP", "TRAIN_STAMP", "DATA_STAMP"):     # in this order: each newer
        stamps[name] = tmp_path / f"{name.lower()}"
        stamps[name].touch()
    out = subprocess.run(
        ["make", "-n", "--no-print-directory", "-C", ROOT, *args, f"OUT={tmp_path}/out",
         *(f"{k}={v}" for k, v in stamps.items())],
        capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout.replace("\\\n", " ").splitlines()


def commands(lines):
    """Each weights_tools command line as its argument list, in the order make runs them."""
    found = []
    for line in lines:
        for m in COMMAND.finditer(line):
            found.append(shlex.split(m.group(1)))
    return found


@pytest.fixture(scope="module")
def shipped_lines(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("make")
    return dry_run(tmp, *TARGETS, f"DATA={tmp}/data", "NSRD_ABLATIONS=1")


@pytest.fixture(scope="module")
def smoke_lines(tmp_path_factory):
    """make train-smoke: the same targets with its step counts and tiny sizes."""
    lines = dry_run(tmp_path_factory.mktemp("smoke"), "train-smoke")
    assert "out/smoke/data/" in "\n".join(lines), lines[:3]
    return lines


@pytest.mark.parametrize("which", ["shipped", "smoke"])
def test_every_training_command_parses(which, shipped_lines, smoke_lines):
    lines = shipped_lines if which == "shipped" else smoke_lines
    cmds = commands(lines)
    assert {c[0] for c in cmds} >= {"gen", "blender", "seeds", "train"}, cmds
    methods = {c[1] for c in cmds if c[0] == "train"}
    assert methods >= {"mlp", "nsrr", "nsrd", "nss"}, methods
    p = parser()
    for argv in cmds:
        try:
            args = p.parse_args(spelled_out(argv))
        except SystemExit:
            pytest.fail(f"weights_tools does not take this Makefile command: {shlex.join(argv)}")
        if argv[0] == "seeds":      # its --train options go to every seed's `train`
            inner = ["train", args.method, "--data", "d", "--out", "o",
                     *shlex.split(args.train or "")]
            try:
                p.parse_args(spelled_out(inner))
            except SystemExit:
                pytest.fail(f"`seeds --train` options that `train` does not take: {args.train}")


def _outputs(argv):
    return [argv[i + 1] for i, a in enumerate(argv[:-1]) if a == "--out"]


@pytest.mark.parametrize("which", ["shipped", "smoke"])
def test_every_stage_reads_what_an_earlier_stage_wrote(which, shipped_lines, smoke_lines):
    lines = shipped_lines if which == "shipped" else smoke_lines
    written = []        # --out directories, in order
    for line in lines:
        for m in COMMAND.finditer(line):
            argv = shlex.split(m.group(1))
            for i, a in enumerate(argv[:-1]):
                if a == "--init":
                    src = argv[i + 1]
                    assert any(src.startswith(d.rstrip("/") + "/") for d in written), \
                        f"--init {src}: no earlier command of the run writes it ({shlex.join(argv)})"
            written += _outputs(argv)
        if line.startswith("cp ") and "/out/" in line:
            src = shlex.split(line)[1]
            assert any(src.startswith(d.rstrip("/") + "/") for d in written), \
                f"{line}: no earlier command of the run writes {src}"


def test_smoke_runs_every_stage_for_a_few_steps(smoke_lines):
    """Every step count of the smoke is the smoke's (2, NSS's warm restart twice that): a
    stage whose steps the smoke does not set would run at full length there."""
    for argv in commands(smoke_lines):
        for i, a in enumerate(argv[:-1]):
            if a in ("--steps", "--cls-steps", "--comp-steps"):
                assert int(argv[i + 1]) <= 4, shlex.join(argv)
        if argv[0] == "seeds":
            opts = shlex.split(argv[argv.index("--train") + 1])
            assert opts[opts.index("--cls-steps") + 1] == "2", opts


def test_smoke_writes_no_shipped_weights(smoke_lines):
    """make train-smoke must leave the package's weights alone."""
    copies = [shlex.split(line) for line in smoke_lines if line.startswith("cp ")]
    assert len(copies) >= 7, smoke_lines
    for argv in copies:
        assert "clss/weights" not in argv[-1], shlex.join(argv)
