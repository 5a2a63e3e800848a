"""The house (docs/architecture.md, "Adding a method"): a method is one folder plus one
registry line, everything it owns is named by its spec (`MethodSpec.parts()`), nothing in
the tree is owned by no method, the architecture doc's list of parts is the spec's, and a
toy method added the way the doc says (a folder, one line) is a method everywhere: the
registry, clss.Upscaler, `clss methods` and the bench."""
from __future__ import annotations

import ast
import importlib
import os
import re
import sys

import numpy as np
import pytest

import clss
from clss import methods
from clss.pipeline.method import PARTS, WEIGHTS_DIR

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)        # bench and weights_tools, as the other bench tests reach them


def _here(path: str) -> bool:
    return os.path.exists(os.path.join(ROOT, path))


@pytest.mark.parametrize("name", methods.names())
def test_every_part_a_spec_names_exists(name):
    s = methods.spec(name)
    parts = s.parts()
    assert tuple(parts) == PARTS
    assert s.room in methods.ROOMS and _here(parts["room"])
    assert parts["kernels"], f"{name}: its spec names no frame kernel"
    for path in parts["kernels"] + parts["weights"]:
        assert _here(path), f"{name}: {path} is named by its spec and missing"
    assert (s.weights() == "trained") == bool(parts["weights"])
    module, attr = parts["onnx_twin"].split(":")
    assert callable(getattr(importlib.import_module(module), attr))
    for key in ("bench", "doc", "tests"):
        assert _here(parts[key]), f"{name}: its {key} ({parts[key]}) is missing"
    if s.shipped:               # a learned method: its training room
        assert _here(parts["torch_twin"]) and _here(parts["recipe"])
        from weights_tools import methods as training
        assert s.room in training.names()
    else:
        assert parts["torch_twin"] is None and parts["recipe"] is None


def test_nothing_in_the_tree_belongs_to_no_method():
    """Every room folder is registered, and every room's kernels, every shipped weights
    file, every training room and every bench room belongs to a registered method."""
    specs = methods.specs()
    rooms = {d for d in os.listdir(os.path.join(ROOT, "clss", "methods"))
             if os.path.isfile(os.path.join(ROOT, "clss", "methods", d, "__init__.py"))}
    assert rooms == set(methods.ROOMS), "a room folder without its registry line (or the reverse)"
    owned = {k for s in specs for k in s.parts()["kernels"]}
    for room in rooms:
        d = os.path.join("clss", "methods", room)
        cl = {f"{d}/{f}" for f in os.listdir(os.path.join(ROOT, d)) if f.endswith(".cl")}
        assert cl <= owned, f"kernels no spec names: {sorted(cl - owned)}"
    shipped = {f"clss/weights/{f}" for f in os.listdir(WEIGHTS_DIR) if f.endswith(".safetensors")}
    assert shipped == {w for s in specs for w in s.parts()["weights"]}
    from weights_tools import methods as training
    assert set(training.names()) <= set(methods.ROOMS)
    import bench.methods
    bench_rooms = {f[:-3] for f in os.listdir(os.path.dirname(bench.methods.__file__))
                   if f.endswith(".py") and f != "__init__.py"}
    assert bench_rooms == set(methods.ROOMS)


def _doc_section():
    text = open(os.path.join(ROOT, "docs", "architecture.md")).read()
    m = re.search(r"^## Adding a method\n(.*?)(?=^## )", text, re.S | re.M)
    assert m, "docs/architecture.md has no 'Adding a method' section"
    return m.group(1)


def test_the_architecture_doc_lists_the_parts_the_spec_names():
    """The doc's table of what a method owns has one row per key of MethodSpec.parts(), in
    its order, and says that the registry line is the only edit outside the folder."""
    sec = _doc_section()
    rows = re.findall(r"^\| `(\w+)` \|", sec, re.M)
    assert tuple(rows) == PARTS
    assert "ROOMS" in sec and "clss/methods/__init__.py" in sec


# ---- a toy method, added as the doc says ----------------------------------------------------

TOY_CL = """\
/* The toy method's frame kernel: nearest-neighbour upsampling of the colour. */
#include "common.h"

/** @param[in]  color [h,w,3] float32
 *  @param[out] out   [H,W,3] float32 */
__kernel void toy_nearest(__global const float *color, __global float *out,
                          int h, int w, int H, int W) {
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= W || y >= H) return;
    const int sx = min(x * w / W, w - 1), sy = min(y * h / H, h - 1);
    for (int c = 0; c < 3; c++) out[(y * W + x) * 3 + c] = color[(sy * w + sx) * 3 + c];
}
"""

TOY_UPSCALER = '''\
"""The toy method: nearest-neighbour upsampling, colour only."""
from pathlib import Path

import numpy as np

from clss.pipeline.contract import output_size
from clss.pipeline.method import MethodSpec, MethodUpscaler

KERNEL = Path(__file__).with_name("toy.cl")


class ToyFrame:
    def __init__(self, dev, h, w, scale):
        self.dev, self.h, self.w = dev, h, w
        self.H, self.W = output_size(h, w, scale)
        self.in_color = dev.empty((h, w, 3), dtype=np.float32)
        self.out = dev.empty((self.H, self.W, 3), dtype=np.float32)

    def run(self, color, out=None):
        out = self.out if out is None else out
        i32 = np.int32
        ev = self.dev.launch(self.dev.kernel(KERNEL, "toy_nearest"), (self.W, self.H),
                             (color.data, out.data, i32(self.h), i32(self.w), i32(self.H),
                              i32(self.W)))
        return out, ev


class ToyUpscaler(MethodUpscaler):
    def __init__(self, scale=2.0, device=None, precision="fp32"):
        self.spec = SPEC
        self._init_common(scale, device, precision)

    def _build_frame_step(self, h, w):
        return ToyFrame(self.dev, h, w, self.scale)

    def _enqueue(self, fs, arrays, jitter, out):
        return fs.run(arrays["color"], out=out)


SPEC = MethodSpec("toy", "toy", "nearest neighbour (a test's toy method)", ToyUpscaler,
                  inputs=("color",), precisions=("fp32",), temporal=False,
                  kernels=(KERNEL.name,), doc="docs/methods/toy.md")
SPECS = {"toy": SPEC}
'''

TOY_BENCH = '''\
"""The toy method's bench room."""
HOST_WAITS = ("toy",)


def cases(tier):
    return []
'''


@pytest.fixture
def toy_method(tmp_path, monkeypatch):
    """The toy method's folder (clss/methods/toy/: __init__, upscaler, toy.cl) and bench
    room, in a temporary tree that the clss.methods and bench.methods packages search, and
    its one line in ROOMS."""
    import bench.methods
    room = tmp_path / "rooms" / "toy"
    room.mkdir(parents=True)
    (room / "__init__.py").write_text("from .upscaler import SPECS\n")
    (room / "upscaler.py").write_text(TOY_UPSCALER)
    (room / "toy.cl").write_text(TOY_CL)
    (tmp_path / "bench_rooms").mkdir()
    (tmp_path / "bench_rooms" / "toy.py").write_text(TOY_BENCH)
    monkeypatch.setattr(methods, "__path__", list(methods.__path__) + [str(tmp_path / "rooms")])
    monkeypatch.setattr(bench.methods, "__path__",
                        list(bench.methods.__path__) + [str(tmp_path / "bench_rooms")])
    monkeypatch.setattr(methods, "ROOMS", methods.ROOMS + ("toy",))      # the one line
    yield
    for mod in [m for m in sys.modules if m.startswith(("clss.methods.toy", "bench.methods.toy"))]:
        del sys.modules[mod]


def test_a_new_method_is_a_folder_plus_one_line(toy_method, dev, capsys):
    assert methods.names()[-1] == "toy"
    s = methods.spec("toy")
    assert s.room == "toy"
    assert s.parts()["kernels"] == ("clss/methods/toy/toy.cl",)
    # clss.Upscaler builds it, with the shared checks, the template's step and step_device
    up = clss.Upscaler(method="toy", scale=2)
    color = np.arange(5 * 7 * 3, dtype=np.float32).reshape(5, 7, 3)
    out = up.step(color, np.zeros((5, 7), np.float32), np.zeros((5, 7, 2), np.float32), (0, 0))
    assert out.shape == (10, 14, 3) and np.array_equal(out, color.repeat(2, 0).repeat(2, 1))
    assert np.array_equal(up.step_device(dev.to_device(color)).get(), out)
    with pytest.raises(TypeError, match="did you mean 'precision'"):
        clss.Upscaler(method="toy", precison="fp32")
    # `clss methods` lists it, the bench finds its bench room and host-wait row
    from clss.cli.main import main
    assert main(["methods"]) == 0
    assert "nearest neighbour (a test's toy method)" in capsys.readouterr().out
    import bench.methods
    assert "toy" in dict(bench.methods.bench_rooms())
    assert "toy" in bench.methods.host_wait_methods()


def test_the_import_contracts_name_no_room():
    """.importlinter holds the rooms by wildcard: no contract lists a room by name, so a new
    room is held without an edit there."""
    text = open(os.path.join(ROOT, ".importlinter")).read()
    for room in methods.ROOMS:
        assert not re.search(rf"\b(clss|bench|weights_tools)\.methods\.{room}\b", text), room
    assert "clss.methods.*" in text and "bench.methods.*" in text and "weights_tools.methods.*" in text


def test_setup_finds_every_room():
    """The package list is found (setup.py), not kept: a new room is installed with no edit."""
    from setuptools import find_packages
    found = set(find_packages(ROOT, include=["clss", "clss.*"]))
    assert {f"clss.methods.{r}" for r in methods.ROOMS} <= found


# ---------------------------------------------------------------- studies/ (issue 52)

STUDIES = os.path.join(ROOT, "studies")
PACKAGES = ("clss", "bench", "weights_tools")


def _studies():
    """Every file of studies/ but its README, as paths relative to studies/."""
    out = []
    for d, _, files in os.walk(STUDIES):
        out += [os.path.relpath(os.path.join(d, f), STUDIES) for f in files
                if f != "README.md" and "__pycache__" not in d]
    return sorted(out)


def test_studies_live_outside_the_packages_and_are_indexed():
    """Dated one-off studies sit in studies/, never inside an importable package, and
    studies/README.md has a line for each (what it measured, its date, its result)."""
    for pkg in PACKAGES:
        for d, dirs, files in os.walk(os.path.join(ROOT, pkg)):
            assert "studies" not in dirs, f"{d}/studies: studies belong in studies/"
            dated = [f for f in files if f.endswith(".py") and re.match(r"\d{4}-\d\d-\d\d-", f)]
            assert not dated, f"{d}: dated one-off scripts {dated} belong in studies/"
    index = open(os.path.join(STUDIES, "README.md")).read()
    rows = re.findall(r"^\| `([^`]+)` \| (\d{4}-\d\d-\d\d) \|", index, re.M)
    assert sorted(r[0] for r in rows) == _studies(), "studies/README.md: one line per study"


def _package_imports(path):
    """(module, name or None) of each import of clss, bench or weights_tools in a script."""
    for node in ast.walk(ast.parse(open(path).read())):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module \
                and node.module.split(".")[0] in PACKAGES:
            yield from ((node.module, a.name) for a in node.names)
        elif isinstance(node, ast.Import):
            yield from ((a.name, None) for a in node.names if a.name.split(".")[0] in PACKAGES)


@pytest.mark.parametrize("study", [s for s in _studies() if s.endswith(".py")])
def test_a_study_imports_what_exists(study):
    """A study stays runnable as far as moves go: every module and name it takes from the
    packages still exists (a moved module, like clss.scene to clss.demo.scene, is caught;
    the torch-only ones are checked where the [train] extra is installed)."""
    for module, name in _package_imports(os.path.join(STUDIES, study)):
        try:
            mod = importlib.import_module(module)
            if name is not None and not hasattr(mod, name):
                importlib.import_module(f"{module}.{name}")     # a submodule, else it fails
        except ModuleNotFoundError as e:
            # a submodule that needs an optional extra (weights_tools' torch twins) is
            # skipped as its module would be: a fresh `make test` has no [train] extra
            if e.name in ("torch", "bpy", "ray"):
                pytest.skip(f"{module}{'.' + name if name else ''} needs {e.name}")
            raise
