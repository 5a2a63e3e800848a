"""The record of the shipped weights (docs/training.md, "The shipped weights: where and how
long they trained"; issue 53 item 5): every file in clss/weights/ has exactly one row, so a
new shipped file without its record (the make target, the stages, the machine, the time)
fails here. Each row names a make target the Makefile has and a method page that exists."""
from __future__ import annotations

import glob
import os
import re

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HEADING = "## The shipped weights: where and how long they trained"


def _rows() -> list[list[str]]:
    with open(os.path.join(ROOT, "docs", "training.md"), encoding="utf-8") as f:
        text = f.read()
    assert text.count(HEADING + "\n") == 1, f"docs/training.md: one section {HEADING!r}"
    section = text.split(HEADING + "\n", 1)[1].split("\n## ", 1)[0]
    rows = []
    for line in section.splitlines():
        if not line.startswith("|"):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells[0] == "file" or set("".join(cells)) <= set("-: "):
            continue                                    # the header and its rule
        rows.append(cells)
    assert rows, "the section holds no table rows"
    return rows


def test_every_shipped_weights_file_has_exactly_one_row():
    shipped = sorted(os.path.basename(p)
                     for p in glob.glob(os.path.join(ROOT, "clss", "weights", "*.safetensors")))
    assert shipped, "clss/weights/ holds no .safetensors"
    named = [r[0].strip("`") for r in _rows()]
    for name in shipped:
        assert named.count(name) == 1, (
            f"clss/weights/{name}: {named.count(name)} rows in docs/training.md's {HEADING!r} "
            "(one expected: where and how long it trained)")
    extra = sorted(set(named) - set(shipped))
    assert not extra, f"rows for files not in clss/weights/: {extra}"


def test_each_row_names_a_make_target_and_its_method_page():
    with open(os.path.join(ROOT, "Makefile"), encoding="utf-8") as f:
        targets = set(re.findall(r"^([A-Za-z0-9_%-]+):", f.read(), re.M))
    for cells in _rows():
        assert len(cells) == 7, f"{cells[0]}: {len(cells)} cells, 7 expected"
        made = re.findall(r"`make ([a-z0-9-]+)", cells[1])
        assert made, f"{cells[0]}: no `make TARGET` in {cells[1]!r}"
        for t in made:
            assert t in targets, f"{cells[0]}: make {t} is not a Makefile target"
        assert re.search(r"\b\d{4}-\d{2}-\d{2}, [0-9a-f]{7,40}\b", cells[5]), (
            f"{cells[0]}: the shipped cell names no date and commit: {cells[5]!r}")
        pages = re.findall(r"\]\((methods/[^)#]+\.md)", cells[6])
        assert pages, f"{cells[0]}: no docs/methods/ page linked"
        for page in pages:
            assert os.path.exists(os.path.join(ROOT, "docs", page)), f"{cells[0]}: docs/{page} missing"
