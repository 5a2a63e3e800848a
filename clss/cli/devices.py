"""`clss devices` (the OpenCL devices and the default) and `clss verify` (every kernel
against onnxruntime on one device: the command a kernel porter runs first)."""
from __future__ import annotations

import argparse
import json
import sys
import time

from .args import DEVICE_HELP, ArgParser, check_output_file, device_spec


def _add_device(p: argparse.ArgumentParser, precision: bool = True) -> None:
    p.add_argument("--device", "-d", default=None, type=device_spec, help=DEVICE_HELP)
    if precision:
        p.add_argument("--precision", "-p", default="fp32", choices=("fp32", "fp16", "fp16-native", "all"),
                       help="fp32; fp16 = half storage, float arithmetic (every device); "
                            "fp16-native = half arithmetic (needs cl_khr_fp16); all = every one the device supports")


def cmd_devices(argv) -> int:
    p = ArgParser(prog="clss devices", description="List OpenCL platforms and devices.")
    p.add_argument("--json", metavar="FILE", help="also write the list as JSON")
    a = p.parse_args(argv)
    if a.json is not None:
        check_output_file(a.json, "--json")
    from ..device import DeviceError, DeviceInfo, compiler_problem, get_device, list_devices
    found = list_devices()
    try:
        default = get_device().cl_device
    except DeviceError:   # none builds: list them with the reasons, then fail
        default = None
    rows = []
    for i, (plat, dev) in enumerate(found):
        info = DeviceInfo.of(dev)
        problem = compiler_problem(dev)
        rows.append(info.__dict__ | {"index": i, "default": dev == default, "builds_kernels": problem is None,
                                     "build_problem": problem})
        mark = "*" if dev == default else " "
        print(f"{mark}[{i}] {info.platform} / {info.name}")
        print(f"      OpenCL {info.version}; driver {info.driver}; {info.compute_units} compute units; "
              f"{info.global_mem / 2**30:.1f} GiB global memory (max alloc {info.max_alloc / 2**30:.1f} GiB); "
              f"fp16 arithmetic (cl_khr_fp16): {'yes' if info.fp16 else 'no'}")
        if problem:
            print(f"      cannot build kernels: {problem}")
    from ..device import default_reason
    if default is None:
        print("clss devices: no device here can build kernels (see above)", file=sys.stderr)
    else:
        print(f"* = default device: {default_reason()}; choose another with --device or $CLSS_DEVICE")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=2)
    return 0 if default is not None else 2


def cmd_verify(argv) -> int:
    p = ArgParser(
        prog="clss verify",
        description="Run every kernel on the chosen device and diff it against onnxruntime "
                    "(the ONNX twin of each op, fed the same inputs). Prints one row per op variant "
                    "and precision; exits non-zero if any row fails. This is the command to run "
                    "when porting clss to a new OpenCL device.",
        epilog="examples:\n  clss verify\n  clss verify --device 1 --precision all --json verify.json\n"
               "  clss verify --filter conv --level full",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_device(p)
    p.add_argument("--json", metavar="FILE", help="write every row (and the device) as JSON")
    p.add_argument("--filter", "-k", default=None, help="only ops whose name contains this substring")
    p.add_argument("--family", default=None,
                   help="only one family of cases (conv, resize, warp, mlp, ...: an unknown "
                        "name lists them; the MLP upscaler's kernels are in mlp)")
    p.add_argument("--level", default="quick", choices=("tiny", "quick", "full"),
                   help="case set: tiny (smallest shapes, used under oclgrind), quick (default), "
                        "full (odd shapes and parameter sweeps, as the tests)")
    p.add_argument("--failures-only", action="store_true", help="print only failing rows")
    a = p.parse_args(argv)
    if a.json is not None:
        check_output_file(a.json, "--json")
    from ..device import DeviceError, get_device
    from ..verify.cases import all_cases
    from ..verify.conformance import check, format_table
    try:
        dev = get_device(a.device)
    except DeviceError as e:
        print(f"clss verify: {e}", file=sys.stderr)
        return 2
    if a.precision == "all":
        precs = ["fp32", "fp16"] + (["fp16-native"] if dev.has_fp16 else [])
    else:
        precs = [a.precision]
        try:
            dev.require(a.precision)
        except DeviceError as e:
            print(f"clss verify: {e}", file=sys.stderr)
            return 2
    from ..ops import FAMILIES
    if a.family and a.family not in FAMILIES:
        print(f"clss verify: unknown family {a.family!r}; families: {', '.join(FAMILIES)}", file=sys.stderr)
        return 2
    cases = [c for c in all_cases(a.level, [a.family] if a.family else None)
             if not a.filter or a.filter in c.op]
    if not cases:
        print(f"clss verify: --filter {a.filter!r} matches no op (see `clss verify --level tiny` "
              "for the list)", file=sys.stderr)
        return 2
    print(f"device: {dev.info.platform} / {dev.info.name} (driver {dev.info.driver}); "
          f"{len(cases)} cases x {len(precs)} precision(s)", file=sys.stderr)
    t0 = time.perf_counter()
    rows = []
    from ..progress import progress
    for case in progress(cases, desc="verify", unit="case"):
        for prec in precs:
            rows.append(check(case, dev, prec))
    shown = [r for r in rows if not r.passed] if a.failures_only else rows
    print(format_table(shown))
    fails = sum(not r.passed for r in rows)
    print(f"\n{len(rows) - fails} passed, {fails} failed ({len(rows)} rows, {time.perf_counter() - t0:.1f} s)")
    from ..verify.conformance import format_fast_paths
    from ..selfcheck_runner import check_all
    fast = check_all(dev, precs, [a.family] if a.family else None)
    print("\n" + format_fast_paths(fast))
    if not a.family or a.family in ("conv", "conv_gemm"):
        from ..verify.conformance import format_variants
        print("\n" + format_variants(dev, precs, fast))
    if not a.family:
        from ..verify.conformance import format_device_choices
        print("\n" + format_device_choices(dev))
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"device": dev.info.__dict__, "rows": [r.as_dict() for r in rows],
                       "fast_paths": [v.as_dict() for v in fast]}, f, indent=2, default=float)
    return 1 if fails else 0
