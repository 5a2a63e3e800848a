"""The op table (clss/model/optable.py) against the registry and docs/model.md: every op
clss runs has an entry, every entry names an op clss runs (or one of PENDING, the ops
being added for issue 49), and the document shows the rendered table."""
from __future__ import annotations

import os

import pytest

from clss.model import optable
from clss.model.graph import LOWERED_OPS, MAX_OPSET, MIN_OPSET

DOC = os.path.join(os.path.dirname(__file__), "..", "docs", "model.md")


def test_every_registered_op_has_an_entry():
    missing = sorted(optable.registered() - set(optable.OPS))
    assert not missing, f"ops clss runs with no entry in clss/model/optable.py OPS: {missing}"


def test_every_entry_is_registered():
    have = optable.registered()
    stale = sorted(set(optable.OPS) - have - optable.PENDING)
    assert not stale, f"OPS entries for ops clss does not run (no handler, not lowered): {stale}"


def test_pending_only_shrinks():
    landed = sorted(optable.PENDING & optable.registered())
    assert not landed, f"registered now; remove them from optable.PENDING: {landed}"
    assert optable.PENDING <= set(optable.OPS)


def test_lowered_ops_are_in_the_table():
    assert set(LOWERED_OPS) <= set(optable.OPS)


def test_entries_are_one_short_line():
    for op, limits in optable.OPS.items():
        assert limits and "\n" not in limits and len(limits) < 400, op


def test_opsets_column():
    assert optable.opsets_text("Conv") == f"{MIN_OPSET}-{MAX_OPSET} (11)"
    assert optable.opsets_text("Gelu") == f"20-{MAX_OPSET} (20)"
    assert optable.opsets_text("LayerNormalization").startswith("17-")
    assert optable.opsets_text("Upsample").startswith("none (deprecated")
    first, last, forms = optable.opsets("Resize")
    assert (first, last) == (MIN_OPSET, MAX_OPSET) and forms == [11, 13, 18, 19]


def test_docs_show_the_rendered_table():
    with open(DOC, encoding="utf-8") as f:
        text = f.read()
    assert text.count(optable.BEGIN) == 1 and text.count(optable.END) == 1
    assert optable.splice(text, optable.render_markdown()) == text, \
        "docs/model.md's op table is stale: run python -m clss.model.optable --write docs/model.md"


def test_render_lists_every_entry_once():
    md = optable.render_markdown()
    rows = [ln for ln in md.splitlines() if ln.startswith("| ") and not ln.startswith("| op |")]
    assert sorted(r.split(" | ")[0][2:] for r in rows) == sorted(optable.OPS)


def test_write_and_check(tmp_path):
    p = tmp_path / "doc.md"
    p.write_text(f"# x\n\n{optable.BEGIN}\nold\n{optable.END}\n\nafter\n")
    assert optable.main(["--check", str(p)]) == 1
    assert optable.write_doc(str(p)) is True
    assert optable.write_doc(str(p)) is False
    assert optable.main(["--check", str(p)]) == 0
    text = p.read_text()
    assert text.startswith("# x\n") and text.endswith("\n\nafter\n") and "| Conv |" in text
    p.write_text("no markers")
    with pytest.raises(ValueError, match="markers"):
        optable.write_doc(str(p))
