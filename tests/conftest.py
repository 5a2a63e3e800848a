"""Shared fixtures: the device under test and the case checker.

CLSS_DEVICE / PYOPENCL_CTX choose the device, as for the CLI (default PoCL)."""
from __future__ import annotations

import os

import pytest

from clss.conformance import check
from clss.device import get_device

PRECISIONS = ("fp32", "fp16")


@pytest.fixture(scope="session")
def dev():
    return get_device()


def assert_case(case, dev, precision):
    """Diff one conformance case against onnxruntime; the failure message is the row."""
    row = check(case, dev, precision)
    assert row.passed, (f"{case.name} {precision}: max abs {row.max_abs:.3g}, max rel {row.max_rel:.3g}, "
                        f"err/tol {row.ratio:.3g} (tol {row.tolerance}) {row.detail}")
    return row


def pytest_configure(config):
    config.addinivalue_line("markers", "large: large shapes; run with CLSS_LARGE=1")


def pytest_collection_modifyitems(config, items):
    if os.environ.get("CLSS_LARGE") == "1":
        return
    skip = pytest.mark.skip(reason="large shape: set CLSS_LARGE=1 to run")
    for item in items:
        if "large" in item.keywords:
            item.add_marker(skip)
