import numpy as np
import pytest

from clss import device as D


def test_default_is_pocl(dev, monkeypatch):
    assert "Portable Computing Language" in dev.info.platform or dev.info.platform


def test_default_is_pips_pocl_whatever_the_platform_order(monkeypatch):
    # With Debian's PoCL installed too, the ICD loader lists it first; the default stays
    # the PoCL that pip installed (pocl-binary-distribution), identified by its version.
    monkeypatch.delenv("CLSS_DEVICE", raising=False)
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    found = D.list_devices()
    pip = [(p, d) for p, d in found if D.is_pip_pocl(p)]
    if not pip:
        pytest.skip("pip's PoCL (pocl-binary-distribution) is not installed")
    assert D._pick(None) == pip[0][1]
    monkeypatch.setattr(D, "list_devices", lambda: found[::-1])
    assert D._pick(None) == pip[0][1]
    assert "pocl-binary-distribution" in D.default_reason()
    for p, d in found:
        if "+debian" in d.driver_version:
            assert not D.is_pip_pocl(p)


def test_spec_by_index_and_substring():
    d0 = D.get_device("0")
    name = d0.info.name.split()[0]
    assert D.get_device(name).cl_device == d0.cl_device
    # the driver version is part of what a spec matches (two PoCLs share a platform name)
    assert D.get_device(f"({d0.info.driver})").cl_device == d0.cl_device


def test_unknown_device_lists_devices():
    with pytest.raises(D.DeviceError, match="(?s)no device matches 'no-such-gpu'.*\\[0\\]"):
        D.get_device("no-such-gpu")
    with pytest.raises(D.DeviceError, match="out of range"):
        D.get_device("99")


def test_precision_checks(dev):
    with pytest.raises(ValueError, match="precision must be one of"):
        D.storage_dtype("fp8")
    if not dev.has_fp16:
        with pytest.raises(D.DeviceError, match="cl_khr_fp16"):
            dev.require("fp16-native")
    assert D.storage_dtype("fp16") == np.float16


def test_program_cache_reuses_builds(dev):
    a = dev.program("space_to_depth", "fp32", CRD=0)
    b = dev.program("space_to_depth", "fp32", CRD=0)
    c = dev.program("space_to_depth", "fp16", CRD=0)
    assert a is b and a is not c


def test_build_error_names_kernel_and_log(dev, tmp_path, monkeypatch):
    (tmp_path / "common.h").write_text(D.kernels_dir().joinpath("common.h").read_text())
    (tmp_path / "broken.cl").write_text('#include "common.h"\n__kernel void f(__global T *x) { x[0] = undefined_thing; }\n')
    monkeypatch.setattr(D, "kernels_dir", lambda: tmp_path)
    with pytest.raises(D.KernelBuildError) as e:
        dev.kernel("broken", "f", "fp32")
    msg = str(e.value)
    assert "kernels/broken.cl" in msg and "undefined_thing" in msg


def test_missing_kernel_name(dev):
    with pytest.raises(D.KernelBuildError, match="no kernel named 'nope'"):
        dev.kernel("space_to_depth", "nope", "fp32")


def test_every_kernel_builds_in_both_precisions(dev):
    # A porter's first question: does each source compile on my compiler? (Default -D options,
    # and for frame.cl the buffer widths it takes from the host.)
    from clss.pipeline.frame import WIDTH_DEFINES
    for src in sorted(D.kernels_dir().glob("*.cl")):
        for prec in ("fp32", "fp16"):
            dev.program(src.stem, prec, **(WIDTH_DEFINES if src.stem == "frame" else {}))


def test_absurd_allocation_refused(dev):
    with pytest.raises(D.DeviceError, match="exceeds the device's max allocation"):
        dev.empty((1 << 20, 1 << 20), "fp32")
