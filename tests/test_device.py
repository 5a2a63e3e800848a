from pathlib import Path

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
    if D.compiler_problem(pip[0][1]):
        pytest.skip(f"pip's PoCL cannot build kernels on this machine: {D.compiler_problem(pip[0][1])}")
    assert D._pick(None) == pip[0][1]
    monkeypatch.setattr(D, "list_devices", lambda: found[::-1])
    assert D._pick(None) == pip[0][1]
    assert "pocl-binary-distribution" in D.default_reason()
    for p, d in found:
        if "+debian" in d.driver_version:
            assert not D.is_pip_pocl(p)


def test_default_passes_over_a_device_that_cannot_build(monkeypatch):
    # pip's PoCL 3.0 (LLVM 14) fails every build on a CPU its LLVM does not know (AMD Zen 5:
    # "unknown target CPU 'generic'"); the default moves on to a device that builds, says why,
    # and with none left the error lists every device and its reason.
    monkeypatch.delenv("CLSS_DEVICE", raising=False)
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    found = [(p, d) for p, d in D.list_devices() if "oclgrind" not in p.name.lower()]
    why = "error: unknown target CPU 'generic'" + D._build_hint("unknown target CPU")
    target = found[-1][1]
    fake = {d.int_ptr: why for p, d in found if d != target}
    monkeypatch.setattr(D, "compiler_problem", lambda d: fake.get(d.int_ptr))
    assert D._pick(None) == target
    if any(D._is_pocl_cpu(p, d) for p, d in found if d != target) and not D.is_pip_pocl(found[-1][0]):
        assert "passed over: error: unknown target CPU 'generic'" in D.default_reason()
    fake[target.int_ptr] = why
    with pytest.raises(D.DeviceError, match="(?s)no OpenCL device here can build a kernel.*apt-get install pocl-opencl-icd"):
        D._pick(None)


def test_conformance_devices_build(any_dev):
    # A device whose compiler fails the probe is never a conformance parametrisation:
    # every one of its cases would fail for that one reason.
    assert D.compiler_problem(any_dev.cl_device) is None


def test_devices_left_out_say_why():
    # The devices this machine's conformance tests left out, and why (a visible skip).
    broken = [(D.describe(i, p, d), D.compiler_problem(d)) for i, (p, d) in enumerate(D.list_devices())
              if D.compiler_problem(d)]
    if broken:
        pytest.skip("left out of the conformance tests (cannot build kernels): "
                    + "; ".join(f"{n}: {why}" for n, why in broken))


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


def room_sources():
    """The methods' own frame kernels, each in its room beside its frame.py."""
    import clss.methods
    return sorted(Path(clss.methods.__file__).parent.glob("*/*.cl"))


def test_every_kernel_builds_in_both_precisions(dev):
    # A porter's first question: does each source compile on my compiler? (Default -D options,
    # and the constants CLSS's frame.cl and NSRD's nsrd.cl take from the host.) The operator
    # families of kernels/ by stem, the rooms' sources by path (their headers beside them,
    # the shared ones in kernels/).
    from clss.methods.clss.frame import KERNEL as FRAME, LR_NET_CHANNELS, WIDTH_DEFINES
    from clss.methods.nsrd.frame import KERNEL as NSRD, guide_defines
    sources = [p.stem for p in sorted(D.kernels_dir().glob("*.cl"))] + room_sources()
    assert FRAME in sources and NSRD in sources
    # (NSRD's guided-base constants come from the host too)
    host = {FRAME: WIDTH_DEFINES, NSRD: guide_defines()}
    for src in sources:
        for prec in ("fp32", "fp16"):
            dev.program(src, prec, **host.get(src, {}))
            if src == FRAME:     # and its net-mode variant (other kernel signatures)
                dev.program(src, prec, **{**WIDTH_DEFINES, "NET": 1,
                                          "L_CHANNELS": LR_NET_CHANNELS})


def test_room_source_named_by_its_path(dev, tmp_path):
    # A room's source: its own headers beside it, the shared ones from kernels/; errors name
    # the file where it is (no method's source is in kernels/).
    assert not any(p.stem in {s.stem for s in room_sources()} for p in D.kernels_dir().glob("*.cl"))
    from clss.methods.mlp.mlp_upscale import KERNEL
    assert D.kernel_label(KERNEL) == "clss/methods/mlp/mlp_upscale.cl"
    src = D.Device.source(KERNEL)
    assert "#define OFF1" in src and "CLSS_PQ_H" in src    # mlp_layout.h beside it, pq.h shared
    (tmp_path / "room.h").write_text("#define ROOM_VALUE 2\n")
    (tmp_path / "room.cl").write_text('#include "room.h"\n#include "common.h"\n'
                                      "__kernel void f(__global T *x) { x[0] = ROOM_VALUE + missing; }\n")
    with pytest.raises(D.KernelBuildError) as e:
        dev.kernel(tmp_path / "room.cl", "f", "fp32")
    assert "room.cl failed to build" in str(e.value) and "missing" in str(e.value)
    (tmp_path / "lost.cl").write_text('#include "nowhere.h"\n')
    with pytest.raises(D.KernelBuildError, match="no header nowhere.h"):
        D.Device.source(tmp_path / "lost.cl")


def test_absurd_allocation_refused(dev):
    with pytest.raises(D.DeviceError, match="exceeds the device's max allocation"):
        dev.empty((1 << 20, 1 << 20), "fp32")


def test_a_broken_cached_build_is_retried_around_the_caches(monkeypatch):
    """A cached binary another process was writing (issue 52: three cold-cache processes,
    one failed with 'failed to build' or 'has no kernel named'): clss builds once more
    around pyopencl's and the driver's caches before reporting anything."""
    import pyopencl as cl
    from clss.device import Device, get_device
    dev = Device(get_device(None).cl_device)
    calls = []
    real = Device._build

    def flaky(self, src, options, fresh=False, prog=None):
        calls.append(fresh)
        if not fresh:
            raise cl.RuntimeError("simulated: a half-written cache entry")
        return real(self, src, options, fresh, prog)
    monkeypatch.setattr(Device, "_build", flaky)
    k = dev.kernel("elementwise", "unary", "fp32", UOP=0)
    assert k is not None and calls == [False, True]
    calls.clear()
    # a program whose cached binary lacks a kernel the source declares: rebuilt, then found
    monkeypatch.setattr(Device, "_build", real)
    prog = dev.program("elementwise", "fp32", UOP=1)
    dev._programs = {key: (cl.Program(dev.context, "__kernel void other(int x) {}").build()
                           if p is prog else p) for key, p in dev._programs.items()}
    assert dev.kernel("elementwise", "unary", "fp32", UOP=1) is not None


def test_simd_lanes_are_what_the_compiler_emits(any_dev):
    """A CPU device's lanes come from its compiler's target macros, and the register tiles
    (conv.vector_width) and the shipped table (tuning.device_class) follow them, whatever
    width the driver prefers (pip's PoCL 3.0 prefers 16 on a Zen 4 and emits AVX2)."""
    from clss import tuning
    from clss.ops import conv
    lanes = any_dev.simd_lanes
    if not any_dev.is_cpu:
        assert lanes is None
        return
    assert lanes in (4, 8, 16, None)
    if lanes:
        assert conv.vector_width(any_dev) == max(8, lanes)
        assert tuning.device_class(any_dev) == {16: "cpu-avx512", 8: "cpu-avx2", 4: "default"}[lanes]
    assert D.simd_lanes(any_dev.cl_device) == lanes       # probed once, then remembered


def test_simd_lanes_are_kept_on_disk_for_the_next_process(any_dev, tmp_path, monkeypatch):
    import json
    if not any_dev.is_cpu:
        return
    monkeypatch.setenv("CLSS_CACHE_DIR", str(tmp_path))
    lanes = D._probe_lanes(any_dev.cl_device)
    (key, kept), = json.loads((tmp_path / "lanes.json").read_text()).items()
    assert kept == lanes and any_dev.cl_device.name.strip() in key
    # the next process reads it: a changed file is what it answers, no probe
    (tmp_path / "lanes.json").write_text(json.dumps({key: 4}))
    assert D._probe_lanes(any_dev.cl_device) == 4


def test_a_driver_preferring_more_lanes_than_its_compiler_emits_gets_the_compilers():
    from clss import tuning
    from clss.ops import conv

    class CL:
        preferred_vector_width_float = 16

    class Info:
        platform, name, vendor = "Portable Computing Language", "pthread-AMD EPYC", ""

    class Dev:
        is_cpu, simd_lanes, cl_device, info = True, 8, CL(), Info()
    assert conv.vector_width(Dev()) == 8 and tuning.device_class(Dev()) == "cpu-avx2"
    Dev.simd_lanes = None       # no probe answer: the driver's preferred width
    assert conv.vector_width(Dev()) == 16 and tuning.device_class(Dev()) == "cpu-avx512"
