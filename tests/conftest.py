"""Shared fixtures: the devices under test and the case checker.

`dev` is the default device (CLSS_DEVICE / PYOPENCL_CTX choose it, as for the
CLI; else pip's PoCL). `any_dev` runs a test once per OpenCL device found (the
conformance tests: ops against onnxruntime and the ONNX node cases), each device
its own parametrisation named after its platform and driver; oclgrind is left to
tests/test_oclgrind.py (tiny level), and a device whose compiler cannot build a
one-line kernel (clss.device.compiler_problem: pip's PoCL 3.0 on AMD Zen 5) is left
out, with tests/test_device.py saying so. CLSS_DEVICE, PYOPENCL_CTX or
CLSS_TEST_DEVICES=default narrow `any_dev` to the default device.

The tiers (docs/architecture.md, "Tests"): `make test` runs the default tier, which keeps
every kernel family and every method covered and stays under 20 minutes on 2 cores (CI);
tests marked `large` (large shapes) or `slow` (long training smokes, oclgrind beyond one
small run per family and method, the full sweeps on the devices other than the default)
are skipped unless their variable is set (CLSS_LARGE=1, CLSS_SLOW=1; `make test-all` sets
both) or `-m` names the marker. A test marked `slow_on_other_devices` is `slow` where
`any_dev` is not the default device: the second compiler runs the quick cases of every
family in the default tier, the full sweep in the slow one."""
from __future__ import annotations

import os
import re

import pytest

from clss.device import DeviceError, compiler_problem, get_device, list_devices

@pytest.fixture(scope="session")
def dev():
    return get_device()


def _device_id(platform, device) -> str:
    name = platform.name.strip()
    short = "pocl" if name == "Portable Computing Language" else name.split()[0].lower()
    return re.sub(r"[^A-Za-z0-9.+_-]", "_", f"{short}-{device.driver_version.strip()}")


def conformance_devices() -> list[tuple[str, str]]:
    """(test id, device spec) of every device the conformance tests run on."""
    narrow = (os.environ.get("CLSS_DEVICE") or os.environ.get("PYOPENCL_CTX")
              or os.environ.get("CLSS_TEST_DEVICES", "all") == "default")
    try:
        found, default = list_devices(), get_device().cl_device
    except DeviceError:   # no OpenCL at all: the tests that need a device skip
        return []
    out = []
    for i, (p, d) in enumerate(found):
        if "oclgrind" in p.name.lower() or (narrow and d != default) or compiler_problem(d):
            continue
        ident = _device_id(p, d)
        while ident in (o[0] for o in out):
            ident += f"-{i}"
        out.append((ident, str(i)))
        if d == default:
            DEFAULT_SPECS.add(str(i))
    return out


DEFAULT_SPECS: set = set()      # the default device's spec among CONFORMANCE_DEVICES
CONFORMANCE_DEVICES = conformance_devices()


@pytest.fixture(scope="session", params=[s for _, s in CONFORMANCE_DEVICES],
                ids=[i for i, _ in CONFORMANCE_DEVICES])
def any_dev(request):
    return get_device(request.param)


# marker: (the variable that runs its tier, why a test of it is skipped otherwise)
TIERS = {"large": ("CLSS_LARGE", "large shape"),
         "slow": ("CLSS_SLOW", "slow tier")}


def _on_other_device(item) -> bool:
    spec = getattr(getattr(item, "callspec", None), "params", {}).get("any_dev")
    return spec is not None and spec not in DEFAULT_SPECS


@pytest.hookimpl(tryfirst=True)    # before -m selects: `-m slow` sees the marks added here
def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.get_closest_marker("slow_on_other_devices") and _on_other_device(item):
            item.add_marker(pytest.mark.slow)
    chosen = config.getoption("markexpr", "") or ""
    for marker, (var, what) in TIERS.items():
        if os.environ.get(var) == "1" or re.search(rf"\b{marker}\b", chosen):
            continue
        skip = pytest.mark.skip(reason=f"{what}: set {var}=1 to run (make test-all runs every tier)")
        for item in items:
            if marker in item.keywords:
                item.add_marker(skip)


# pip's PoCL 3.0 aborts in the native teardown after Python's ("still have references to
# IRs - can't release LLVM context") once kernels were built: a run whose every test passed
# then exits 134. The controlling process leaves with pytest's status once the summary is
# written (as `clss` itself does: clss.cli.leave); xdist workers leave as usual.
_EXIT_STATUS: list = []


def pytest_sessionfinish(session, exitstatus):
    _EXIT_STATUS.append(int(exitstatus))


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    if _EXIT_STATUS and not hasattr(config, "workerinput"):
        from clss.exiting import leave
        leave(_EXIT_STATUS[-1])
