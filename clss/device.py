"""OpenCL platform/device choice, capabilities, and the program cache.

Choice order: an explicit spec (``--device``), then ``CLSS_DEVICE``, then
``PYOPENCL_CTX`` (pyopencl's own convention, "platform:device" indices), then
the default (`default_reason`): the CPU device of the PoCL that pip installs
(pocl-binary-distribution, a dependency of clss), else any PoCL CPU device,
else the first device found. A spec is an index into `list_devices()` or a
case-insensitive substring of "platform / device (driver)".

The default passes over a device whose compiler cannot build a one-line kernel
(`compiler_problem`): pip's PoCL 3.0 (LLVM 14) on a processor its LLVM does not
know, AMD Zen 5 for one, names the CPU "generic" and fails every build with
"unknown target CPU 'generic'". A device chosen explicitly is used as asked.
"""
from __future__ import annotations

import hashlib
import os
import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from .cachedir import cache_dir, locked, read_json, update_json, write_atomic

PRECISIONS = ("fp32", "fp16", "fp16-native")

# -D options per precision; see kernels/common.h.
_PRECISION_DEFINES = {"fp32": {}, "fp16": {"CLSS_FP16": 1}, "fp16-native": {"CLSS_FP16_NATIVE": 1}}


class DeviceError(RuntimeError):
    """No usable device, or a device lacks what was asked of it."""


class KernelBuildError(RuntimeError):
    """A kernel source failed to build; the message carries the build log, `cli` the one
    line the command line prints (Device._build_error)."""

    cli: str | None = None


# How long a build waits for another process building the same program (then it builds
# unlocked: a stopped process must not hang the others), and the number of lock stripes.
_BUILD_LOCK_WAIT_S = 600.0
_BUILD_LOCKS = 32


def kernels_dir() -> Path:
    """The shared .cl sources (the operator families) and headers: the repo's kernels/ in a
    checkout, clss/kernels when installed. A method's own frame kernels are in its room."""
    repo = Path(__file__).resolve().parent.parent / "kernels"
    if (repo / "common.h").is_file():
        return repo
    installed = Path(__file__).resolve().parent / "kernels"
    if (installed / "common.h").is_file():
        return installed
    raise DeviceError(f"kernel sources not found (looked in {repo} and {installed})")


def kernel_path(source: str | os.PathLike) -> Path:
    """The .cl file of a kernel source. A stem ("conv") names kernels/<stem>.cl, an operator
    family any method may use; a path names a method's own frame kernels, which sit in its
    room beside its frame.py (clss/methods/<name>/<name>.cl), so that the floors below
    clss.methods name no method."""
    if isinstance(source, os.PathLike):
        return Path(source)
    return kernels_dir() / f"{source}.cl"


def kernel_label(source: str | os.PathLike) -> str:
    """A kernel source as messages name it: kernels/conv.cl, clss/methods/<name>/<name>.cl."""
    if not isinstance(source, os.PathLike):
        return f"kernels/{source}.cl"
    path = Path(source).resolve()
    try:
        return path.relative_to(Path(__file__).resolve().parent.parent).as_posix()
    except ValueError:
        return str(path)


def storage_dtype(precision: str) -> np.dtype:
    check_precision(precision)
    return np.dtype(np.float32 if precision == "fp32" else np.float16)


def check_precision(precision: str) -> None:
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")


def list_devices() -> list[tuple[cl.Platform, cl.Device]]:
    try:
        platforms = cl.get_platforms()
    except cl.Error as e:  # no ICD at all
        raise DeviceError(f"no OpenCL platform found ({e}); install pocl-binary-distribution") from e
    return [(p, d) for p in platforms for d in p.get_devices()]


def describe(index: int, platform: cl.Platform, device: cl.Device) -> str:
    return f"[{index}] {platform.name.strip()} / {device.name.strip()} ({device.driver_version.strip()})"


def pip_pocl_version() -> str | None:
    """The PoCL version pip installed (package pocl-binary-distribution), or None."""
    import importlib.metadata
    try:
        return importlib.metadata.version("pocl-binary-distribution")
    except importlib.metadata.PackageNotFoundError:
        return None


def is_pip_pocl(platform: cl.Platform) -> bool:
    """Whether the platform is the PoCL pip installed: its version string names that
    PoCL release ("OpenCL 3.0 PoCL 3.0-rc2 ..." for package 3.0). Distribution builds
    tag theirs ("PoCL 3.1+debian"), so a system PoCL of the same release is not taken
    for it; the ICD loader's platform order is not a stable criterion (it lists
    /etc/OpenCL/vendors first)."""
    import re
    v = pip_pocl_version()
    return v is not None and re.search(rf"PoCL {re.escape(v)}(?![\d.+])", platform.version) is not None


def _is_pocl_cpu(platform: cl.Platform, device: cl.Device) -> bool:
    return "portable computing language" in platform.name.lower() and bool(device.type & cl.device_type.CPU)


def default_reason() -> str:
    """Which device the default is, and why (for `clss devices` and errors)."""
    for var in ("CLSS_DEVICE", "PYOPENCL_CTX"):
        if os.environ.get(var):
            return f"chosen by ${var}={os.environ[var]!r}"
    chosen = _pick(None)
    platform = next(p for p, d in list_devices() if d == chosen)
    if is_pip_pocl(platform):
        return (f"the CPU device of the PoCL pip installs (pocl-binary-distribution {pip_pocl_version()}): "
                "every clss install has it and CI proves every kernel on it")
    broken = "; ".join(f"[{i}] passed over: {why.split(';')[0]}" for i, why in skipped_defaults())
    if _is_pocl_cpu(platform, chosen):
        why = broken or "pip's PoCL is not installed"
        return f"the first PoCL CPU device that builds kernels ({why})"
    return "the first device that builds kernels" + (f" ({broken})" if broken else " (no PoCL installed)")


_PROBE_SOURCE = "__kernel void clss_probe(__global float *a) { a[get_global_id(0)] *= 2.0f; }"
_probed: dict[int, str | None] = {}


def compiler_problem(device: cl.Device) -> str | None:
    """None if the device builds a one-line kernel, else why not (the build log's first
    line, with what to do where the cause is known). Probed once per device and process."""
    key = device.int_ptr
    if key not in _probed:
        problem = None
        try:
            ctx = cl.Context([device])
            prog = cl.Program(ctx, _PROBE_SOURCE)
            try:
                with first_build_lock("probe", ctx):
                    prog.build()
            except cl.RuntimeError as e:
                log = (_build_log(prog, device) or str(e)).strip()
                problem = next((ln.strip() for ln in log.splitlines() if ln.strip()), "build failed")
        except cl.Error as e:
            problem = f"no context ({e})"
        _probed[key] = problem if problem is None else problem + _build_hint(problem)
    return _probed[key]


_first_builds: set = set()


def first_build_lock(name: str, context=None):
    """The inter-process lock around the first build, in this process, of a program clss
    does not build through Device.kernel (the device probes, pyopencl's fill and
    ElementwiseKernel programs): they go through the same driver cache, whose entries
    PoCL 3.0/3.1 replace racily (Device._build), and on a cold cache two processes
    building one of them at once failed ("failed to build the program", the concurrency
    stress test). Later uses in the process (and context: pyopencl builds per context)
    take no lock; the lock file is named by `name` alone, the same in every process."""
    import contextlib
    seen = (name, getattr(context, "int_ptr", None))
    if seen in _first_builds:
        return contextlib.nullcontext()
    _first_builds.add(seen)
    return locked(cache_dir() / "locks" / f"build-first-{re.sub(r'[^A-Za-z0-9_.-]', '_', name)[:80]}",
                  timeout=_BUILD_LOCK_WAIT_S)


# What the kernel compiler vectorises to, read from the macros its front end defines for the
# target it compiles for. A driver's preferred vector width is not that: pip's PoCL 3.0 (LLVM
# 14) reports 16 float lanes on an AMD Zen 4 while it compiles for `znver3` (AVX2: sixteen
# 8-lane registers), so a register tile sized for 16 lanes spilled there (docs/devices.md).
_SIMD_SOURCE = """__kernel void clss_simd(__global int *o) {
#if defined(__AVX512F__)
    o[0] = 16;
#elif defined(__AVX__)
    o[0] = 8;
#elif defined(__SSE2__) || defined(__ARM_NEON) || defined(__ARM_NEON__)
    o[0] = 4;
#else
    o[0] = 0;
#endif
}"""
_simd: dict[int, int | None] = {}


def simd_lanes(device: cl.Device) -> int | None:
    """The float lanes of the vector registers a CPU device's compiler targets (16 AVX-512,
    8 AVX/AVX2, 4 SSE/NEON), from its predefined macros; None for a GPU or where the probe
    says nothing (an unknown ISA, a failed build). Probed once per device, driver and PoCL
    target (kept in lanes.json in clss's cache directory: the probe's build took 0.5 s of
    every process's first frame on PoCL)."""
    key = device.int_ptr
    if key not in _simd:
        lanes = None
        if device.type & cl.device_type.CPU:
            lanes = _probe_lanes(device)
        _simd[key] = lanes
    return _simd[key]


def _probe_lanes(device: cl.Device) -> int | None:
    """simd_lanes' answer from lanes.json, else probed and stored there."""
    disk = " | ".join((device.platform.name.strip(), device.name.strip(), device.driver_version.strip(),
                       os.environ.get("POCL_CPU_TARGET", ""), os.environ.get("POCL_DEVICES", "")))
    path = cache_dir() / "lanes.json"
    known = read_json(path)
    if isinstance(known, dict) and disk in known and (known[disk] is None or isinstance(known[disk], int)):
        return known[disk]
    lanes = None
    try:
        ctx = cl.Context([device])
        with first_build_lock("simd", ctx):
            prog = cl.Program(ctx, _SIMD_SOURCE).build()
        out = np.zeros(1, np.int32)
        buf = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, out.nbytes)
        queue = cl.CommandQueue(ctx)
        prog.clss_simd(queue, (1,), None, buf)
        cl.enqueue_copy(queue, out, buf)
        queue.finish()
        lanes = int(out[0]) or None
    except (cl.Error, cl.RuntimeError):
        return None                 # a failed probe is not kept: the next process probes again

    def add(data):
        data = data if isinstance(data, dict) else {}
        data[disk] = lanes
        return data
    try:
        update_json(path, add, indent=1, sort_keys=True)
    except OSError:                 # an unwritable cache costs a probe per process
        pass
    return lanes


def _build_hint(log: str) -> str:
    """What to do about a build failure whose cause is known."""
    if "unknown target CPU" in log:
        return ("; this PoCL's LLVM does not know the processor (pip's PoCL 3.0 has LLVM 14, older than "
                "AMD Zen 5): install a newer PoCL, e.g. Debian's `apt-get install pocl-opencl-icd`")
    return ""


def skipped_defaults() -> list[tuple[int, str]]:
    """(index, why) of the devices the default passed over because they cannot build."""
    return [(i, compiler_problem(d)) for i, (p, d) in enumerate(list_devices())
            if _is_pocl_cpu(p, d) and compiler_problem(d)]


def _pick(spec: str | None) -> cl.Device:
    found = list_devices()
    if not found:
        raise DeviceError("no OpenCL device found")
    names = [f"{p.name.strip()} / {d.name.strip()} ({d.driver_version.strip()})" for p, d in found]
    if spec is None and os.environ.get("CLSS_DEVICE"):
        spec = os.environ["CLSS_DEVICE"]
    if spec is None and os.environ.get("PYOPENCL_CTX"):
        plat, _, dev = os.environ["PYOPENCL_CTX"].partition(":")
        try:
            platform = cl.get_platforms()[int(plat or 0)]
            return platform.get_devices()[int(dev or 0)]
        except (ValueError, IndexError) as e:
            raise DeviceError(f"PYOPENCL_CTX={os.environ['PYOPENCL_CTX']!r} names no device") from e
    if spec is None:
        for rule in (lambda p, d: _is_pocl_cpu(p, d) and is_pip_pocl(p), _is_pocl_cpu,
                     lambda p, d: "oclgrind" not in p.name.lower()):
            for p, d in found:
                if rule(p, d) and not compiler_problem(d):
                    return d
        raise DeviceError("no OpenCL device here can build a kernel:\n  " + "\n  ".join(
            f"{describe(j, p, d)}: {compiler_problem(d)}" for j, (p, d) in enumerate(found)))
    spec = str(spec).strip()
    if spec.isdigit():
        i = int(spec)
        if i >= len(found):
            raise DeviceError(f"device index {i} out of range; devices:\n  " + "\n  ".join(
                describe(j, p, d) for j, (p, d) in enumerate(found)))
        return found[i][1]
    hits = [d for (p, d), name in zip(found, names) if spec.lower() in name.lower()]
    if not hits:
        raise DeviceError(f"no device matches {spec!r}; devices:\n  " + "\n  ".join(
            describe(j, p, d) for j, (p, d) in enumerate(found)))
    return hits[0]


@dataclass(frozen=True)
class DeviceInfo:
    platform: str
    name: str
    version: str
    driver: str
    compute_units: int
    global_mem: int
    max_alloc: int
    fp16: bool

    @classmethod
    def of(cls, d: cl.Device) -> "DeviceInfo":
        return cls(platform=d.platform.name.strip(), name=d.name.strip(), version=d.version.strip(),
                   driver=d.driver_version.strip(), compute_units=d.max_compute_units,
                   global_mem=d.global_mem_size, max_alloc=d.max_mem_alloc_size,
                   fp16="cl_khr_fp16" in d.extensions.split())


class Device:
    """A context and an in-order profiling queue on one OpenCL device, plus a
    program cache keyed by (source hash, build options): the hash covers the source with
    its headers inlined, so that sources of the same stem in two folders, or a changed
    header, are programs of their own."""

    def __init__(self, cl_device: cl.Device):
        self.cl_device = cl_device
        self.info = DeviceInfo.of(cl_device)
        self.context = cl.Context([cl_device])
        self.queue = cl.CommandQueue(
            self.context, properties=cl.command_queue_properties.PROFILING_ENABLE)
        self._programs: dict[tuple[str, str], cl.Program] = {}
        self._kernels: dict[tuple[str, str, str], cl.Kernel] = {}
        self._lock = threading.Lock()
        self.builds = 0     # programs built so far (the first frame's progress line counts them)

    def __repr__(self) -> str:
        return f"<clss.Device {self.info.platform} / {self.info.name}>"

    @property
    def has_fp16(self) -> bool:
        return self.info.fp16

    @property
    def is_cpu(self) -> bool:
        """A CPU device: the fast paths laid out for SIMD lanes (pixel vectors, the
        channel-blocked convs) apply there (clss.selfcheck.FastPath.applies)."""
        return bool(self.cl_device.type & cl.device_type.CPU)

    @property
    def simd_lanes(self) -> int | None:
        """The float lanes of the registers a CPU device's compiler emits (simd_lanes): the
        unit of the CPU register tiles (clss.ops.conv.vector_width). None on a GPU."""
        return simd_lanes(self.cl_device) if self.is_cpu else None

    def require(self, precision: str) -> None:
        check_precision(precision)
        if precision == "fp16-native" and not self.has_fp16:
            raise DeviceError(
                f"precision 'fp16-native' needs cl_khr_fp16, which {self.info.name} does not report; "
                "use 'fp16' (half storage, float arithmetic) instead")

    # -- programs ---------------------------------------------------------
    @staticmethod
    def source(stem: str | os.PathLike) -> str:
        """The source of `stem` (see kernel_path) with its headers (`#include "name.h"`)
        inlined, once each, so that the program hash covers all of it. A header is looked
        for beside the source first (a room's own), then in kernels/
        (the shared ones: common.h, pq.h, ...), as `-I <room> -I kernels` would."""
        path = kernel_path(stem)
        if not path.is_file():
            raise KernelBuildError(f"no kernel source {path}")
        src = path.read_text()
        dirs = dict.fromkeys((path.parent, kernels_dir()))
        done: set = set()
        while True:     # a header's own includes too (warp_taps.h includes inline_math.h)
            names = list(dict.fromkeys(re.findall(r'#include "([\w.]+\.h)"', src)))
            if not names:
                return src
            for name in names:
                if name in done:    # once each: later includes of it are dropped
                    src = src.replace(f'#include "{name}"', "")
                    continue
                header = next((d / name for d in dirs if (d / name).is_file()), None)
                if header is None:
                    raise KernelBuildError(f"{path.name}: no header {name} in "
                                           + " or ".join(str(d) for d in dirs))
                src = src.replace(f'#include "{name}"', header.read_text(), 1)
                src = src.replace(f'#include "{name}"', "")
                done.add(name)

    @staticmethod
    def build_options(precision: str = "fp32", **defines) -> str:
        """The compiler options of a build: precision and kernel -D options, then
        $CLSS_BUILD_OPTIONS."""
        opts = {**_PRECISION_DEFINES[precision], **defines}
        options = " ".join(f"-D{k}={_define_value(v)}" for k, v in sorted(opts.items()))
        # Extra compiler flags for every program, e.g. -cl-opt-disable under oclgrind
        # (its uninitialised-value checker rejects LLVM's `freeze`, which the optimiser emits).
        extra = os.environ.get("CLSS_BUILD_OPTIONS", "").strip()
        return f"{options} {extra}" if extra else options

    def program(self, stem: str | os.PathLike, precision: str = "fp32", **defines) -> cl.Program:
        self.require(precision)
        options = self.build_options(precision, **defines)
        src = self.source(stem)
        key = (hashlib.sha1(src.encode()).hexdigest(), options)
        prog = self._programs.get(key)
        if prog is None:
            with self._lock:
                prog = self._programs.get(key)
                if prog is None:
                    try:
                        prog = self._build(src, options)
                    except cl.RuntimeError:
                        # A compiled-program cache (pyopencl's or the driver's, e.g. PoCL's
                        # kcache) that another process was writing at that moment can hand
                        # back a broken binary or fail the build: build once more around
                        # both caches before reporting anything.
                        prog = cl.Program(self.context, src)
                        try:
                            self._build(src, options, fresh=True, prog=prog)
                        except cl.RuntimeError as e:
                            raise self._build_error(stem, options, _build_log(prog, self.cl_device)
                                                    or str(e)) from None
                    self._programs[key] = prog
                    self.builds += 1
        return prog

    def _build(self, src: str, options: str, fresh: bool = False, prog=None) -> cl.Program:
        """Build; fresh=True bypasses pyopencl's binary cache and the driver's (a define
        no kernel reads changes the driver's cache key, so the entry is this process's
        alone), for a retry. A cached build runs behind an inter-process lock
        (`_build_lock`): processes building the same program at once build it one after
        the other, the first writing the driver's cache entry and the rest reading it.
        PoCL 3.0 and 3.1 replace an entry (program.bc) by removing it and renaming a new
        one in, so two processes writing one entry together fail when the second remove
        finds nothing, and a reader between remove and rename finds nothing to read:
        "Device ... failed to build the program" (issue 52; PoCL 6.0 dropped the remove)."""
        prog = prog or cl.Program(self.context, src)
        if fresh:
            prog.build(options=f"{options} -DCLSS_FRESH_BUILD={os.getpid()}{time.monotonic_ns()}",
                       cache_dir=False)
        else:
            with locked(self._build_lock(src, options), timeout=_BUILD_LOCK_WAIT_S):
                prog.build(options=options)
        return prog

    def _build_lock(self, src: str, options: str) -> Path:
        """The lock file a build of (src, options) on this device takes: one of
        _BUILD_LOCKS stripes, so the cache directory holds a bounded number of them (two
        programs sharing a stripe only build one after the other)."""
        h = hashlib.sha1("\0".join((self.info.platform, self.info.name, self.info.driver,
                                     options, src)).encode()).digest()
        return cache_dir() / "locks" / f"build-{int.from_bytes(h[:4], 'big') % _BUILD_LOCKS:02d}"

    def _build_error(self, stem, options: str, log: str) -> KernelBuildError:
        """The error of a build that failed twice, the second time around every cache: the
        whole log in the message (a Python caller's traceback); one line on the command
        line (`cli`: the log's first error, and where the whole log was written)."""
        where = f"kernel source {kernel_label(stem)} failed to build on {self.info.name} ({self.info.driver})"
        lines = [ln.strip() for ln in log.splitlines() if ln.strip()]
        first = next((ln for ln in lines if "error" in ln.lower()), lines[0] if lines else "no build log")
        saved = _save_build_log(kernel_label(stem), f"{where} with options '{options}':\n{log}")
        e = KernelBuildError(f"{where} with options '{options}':\n{log}{_build_hint(log)}")
        e.cli = f"{where}: {first}{_build_hint(log)}" + (f" (the whole log: {saved})" if saved else "")
        return e

    def _rebuild(self, stem, precision: str, **defines) -> cl.Program:
        """The program of (stem, precision, defines) built again around every cache, and
        remembered in its place: a cached binary that lacks a kernel its source declares
        (a cache entry another process was writing) is not trusted twice."""
        options = self.build_options(precision, **defines)
        src = self.source(stem)
        key = (hashlib.sha1(src.encode()).hexdigest(), options)
        with self._lock:
            prog = self._build(src, options, fresh=True)
            self._programs[key] = prog
        return prog

    def kernel(self, stem: str | os.PathLike, name: str, precision: str = "fp32", **defines) -> cl.Kernel:
        """A kernel object, cached and shared: Device.launch sets all its args on each launch;
        a prepared Launch (Device.prepare) has a kernel object of its own."""
        prog = self.program(stem, precision, **defines)
        key = (id(prog), name, "")
        k = self._kernels.get(key)
        if k is None:
            try:
                k = getattr(prog, name)
            except AttributeError:
                try:    # a broken cached binary (see program): once more around the caches
                    prog = self._rebuild(stem, precision, **defines)
                    k = getattr(prog, name)
                except (AttributeError, cl.RuntimeError):
                    raise KernelBuildError(f"{kernel_label(stem)} has no kernel named {name!r}") from None
                key = (id(prog), name, "")
            self._kernels[key] = k
        return k

    # -- launches and arrays ----------------------------------------------
    def launch(self, kernel: cl.Kernel, global_size, args, local_size=None, wait_for=None) -> cl.Event:
        """Enqueue with the exact global size (kernels guard their own bounds). Without a
        local size from the op, the tuning database's work-group size for this kernel and
        global size on this device (`clss tune`), else the driver's choice."""
        gs = tuple(int(max(1, g)) for g in global_size)
        if local_size is None:
            from . import tuning
            local_size = tuning.local_size(self, kernel.function_name, gs)
        kernel.set_args(*args)
        return cl.enqueue_nd_range_kernel(self.queue, kernel, gs, local_size, wait_for=wait_for)

    def prepare(self, kernel: cl.Kernel, global_size, args, local_size=None) -> "Launch":
        """A launch with its arguments bound once (see Launch), for work enqueued every
        frame: Device.launch pays the tuning lookup and the argument marshalling per call."""
        gs = tuple(int(max(1, g)) for g in global_size)
        if local_size is None:
            from . import tuning
            local_size = tuning.local_size(self, kernel.function_name, gs)
        return Launch(self.queue, kernel, gs, args, local_size)

    def copy(self, dst: cla.Array, src: cla.Array):
        """Enqueue dst <- src (arrays of equal bytes, views at an offset too); None when
        there is nothing to copy."""
        if src.nbytes:
            return cl.enqueue_copy(self.queue, dst.base_data, src.base_data, byte_count=src.nbytes,
                                   src_offset=src.offset, dst_offset=dst.offset)
        return None

    def fill(self, a: cla.Array, value) -> None:
        """Enqueue a <- value everywhere (pyopencl's fill kernel)."""
        if a.size:
            with first_build_lock(f"fill-{a.dtype.str}", self.context):
                a.fill(value, queue=self.queue)

    def zero(self, a: cla.Array):
        """Enqueue a <- 0 with pyopencl's fill kernel, half arrays through their bits (no
        half fill in pyopencl). Not clEnqueueFillBuffer: oclgrind does not count the bytes
        it writes as initialised, so every later read of them was reported. Returns the
        event (None for an empty array)."""
        if not a.size:
            return None
        v = a.view(np.uint16) if a.dtype == np.float16 else a
        with first_build_lock(f"fill-{v.dtype.str}", self.context):
            v.fill(0, queue=self.queue)
        return v.events[-1] if v.events else None

    def empty(self, shape, precision: str = "fp32", dtype=None) -> cla.Array:
        dt = np.dtype(dtype) if dtype is not None else storage_dtype(precision)
        n = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
        if n > self.info.max_alloc:
            raise DeviceError(f"tensor of shape {tuple(shape)} ({n / 2**20:.1f} MiB) exceeds the device's "
                              f"max allocation ({self.info.max_alloc / 2**20:.0f} MiB)")
        return cla.empty(self.queue, tuple(int(s) for s in shape), dt)

    def to_device(self, a: np.ndarray, precision: str = "fp32") -> cla.Array:
        """Host array to device: floats are stored in the precision's storage type,
        other dtypes (indices, masks) as they are."""
        a = np.asarray(a)
        if a.dtype.kind == "f":
            a = a.astype(storage_dtype(precision), copy=False)
        return cla.to_device(self.queue, np.require(a, requirements='C'))  # keeps 0-d shapes

    @staticmethod
    def to_host(a: cla.Array) -> np.ndarray:
        """Device array to host; float storage is returned as float32."""
        h = a.get()
        return h.astype(np.float32) if h.dtype == np.float16 else h


class Launch:
    """One kernel launch prepared once: sizes fixed, arguments bound. It holds a kernel
    object of its own, since an OpenCL kernel keeps the arguments last set on it and two
    launches of one kernel in a prebuilt list need their own. Enqueueing it is one call,
    no per-launch argument marshalling; `bind` re-sets an argument only when it changed
    (the per-frame ones: inputs, jitter, reset, the history's ping-pong). It references
    its arguments, so that no buffer it is bound to is freed under it."""

    __slots__ = ("kernel", "gs", "ls", "args", "queue")

    def __init__(self, queue, kernel: cl.Kernel, global_size, args, local_size=None):
        self.queue = queue
        self.kernel = cl.Kernel(kernel.program, kernel.function_name)
        self.gs, self.ls = tuple(global_size), local_size
        self.args = list(args)
        self.kernel.set_args(*self.args)

    def bind(self, index: int, value) -> None:
        old = self.args[index]
        if old is value or (not isinstance(value, cl.MemoryObjectHolder) and
                            type(old) is type(value) and old == value):
            return
        self.kernel.set_arg(index, value)
        self.args[index] = value

    def __call__(self, wait_for=None) -> cl.Event:
        return cl.enqueue_nd_range_kernel(self.queue, self.kernel, self.gs, self.ls, wait_for=wait_for)


def _define_value(v) -> str:
    if isinstance(v, bool):
        return str(int(v))
    if isinstance(v, float):
        return repr(v) + "f"
    return str(v)


def _save_build_log(label: str, text: str) -> Path | None:
    """Write a failed build's whole log to build-logs/ in clss's cache directory; its path,
    or None where the cache is not writable."""
    path = cache_dir() / "build-logs" / (re.sub(r"[^\w.-]+", "_", label) + ".log")
    try:
        write_atomic(path, text)
        return path
    except OSError:
        return None


def _build_log(prog: cl.Program, dev: cl.Device) -> str:
    try:
        return prog.get_build_info(dev, cl.program_build_info.LOG)
    except cl.Error:
        return ""


_devices: dict[str | None, Device] = {}


def get_device(spec=None) -> Device:
    """The Device for a spec (see module doc); one instance per cl device."""
    if isinstance(spec, Device):
        return spec
    key = None if spec is None else str(spec)
    if key not in _devices:
        d = _pick(key)
        for existing in _devices.values():
            if existing.cl_device == d:
                _devices[key] = existing
                break
        else:
            _devices[key] = Device(d)
    return _devices[key]
