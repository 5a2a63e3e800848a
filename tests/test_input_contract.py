"""docs/input-contract.md is complete enough to feed clss from the text alone: its worked
example (the Python that writes a sequence, the `clss upscale` line, the API loop) runs
as written, and the upscaled frames match the scene the example describes."""
from __future__ import annotations

import os
import re
import shlex
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("OpenImageIO")

from clss.cli import main  # noqa: E402

DOC = Path(__file__).resolve().parents[1] / "docs" / "input-contract.md"


def _blocks(lang):
    return re.findall(rf"```{lang}\n(.*?)```", DOC.read_text(), re.S)


def test_readme_links_the_contract():
    readme = (DOC.parents[1] / "README.md").read_text()
    assert "docs/input-contract.md" in readme
    assert "../shared" not in readme


def test_worked_example_runs_as_written(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    writer, api, _ = _blocks("python")
    scope = {}
    exec(compile(writer, "input-contract.md: example", "exec"), scope)
    assert sorted(os.listdir("shots")) == [f"frame.{n:04d}.exr" for n in range(4)] + ["jitter.json"]
    command = [c for c in _blocks("sh") if c.startswith("clss upscale")][0].strip()
    assert main(shlex.split(command)[1:]) == 0, capsys.readouterr().err
    names = sorted(os.listdir("up"))
    assert names == sorted([f"frame.{n:04d}.{e}" for n in range(4) for e in ("exr", "png")])

    from clss.io import read_exr
    out, _ = read_exr("up/frame.0003.exr")
    assert out.shape == (72, 128, 3) and np.isfinite(out).all()
    # The scene at output resolution (pixel centres, no jitter) of the last frame: the
    # upscaled frame is much closer to it than the render enlarged by nearest neighbour
    # (mean error 0.022 against 0.050), which holds only when the example's signs of motion
    # and jitter are the ones clss reads (negated jitter: 0.046; negated motion: 0.11).
    I, J = np.mgrid[0:72, 0:128].astype(np.float32)
    camera = scope["PAN"] * 3
    truth = scope["wall"]((J + 0.5) / 2 + camera, (I + 0.5) / 2)
    render, _ = read_exr("shots/frame.0003.exr")
    nearest = np.repeat(np.repeat(render[..., :3], 2, 0), 2, 1)
    inner = (slice(4, -4), slice(4, -4))
    err_clss = np.abs(out - truth)[inner].mean()
    err_nearest = np.abs(nearest - truth)[inner].mean()
    assert err_clss < 0.6 * err_nearest, (err_clss, err_nearest)

    scope = {}
    exec(compile(api, "input-contract.md: API", "exec"), scope)
    assert scope["out"].shape == (72, 128, 3)


def test_contract_example_runs_as_written():
    """Section 6's clss.Contract example builds every method it names with that contract."""
    scope = {}
    exec(compile(_blocks("python")[2], "input-contract.md: Contract", "exec"), scope)
    import clss
    assert scope["up"].method == "nss" and scope["up"].contract == scope["engine"]
    assert scope["engine"] == clss.Contract(depth_inverted=False, motion_scale=(1280, 720),
                                            jitter_scale=(-1, -1), exposure=2.0)
