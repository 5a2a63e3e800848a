"""The `clss` command line: the command table and the error policy. Each subcommand is
a function fn(argv) -> status in the module of its command group (devices.py, model.py,
upscale.py, demo.py; bench/cli.py for bench and tune) and parses its own arguments, so
`clss X --help` teaches X alone."""
from __future__ import annotations

import os
import sys
import warnings

from . import demo, devices, methods, model, upscale


# The one upward edge from the runtime: `clss bench` and `clss tune` live in the top-level
# bench package (which imports clss). It is imported only when one of them runs, so
# `import clss` never loads it; .importlinter names this as the only allowed exception.
def _bench(argv) -> int:
    from bench.cli import bench_main
    return bench_main(argv)


def _tune(argv) -> int:
    from bench.cli import tune_main
    return tune_main(argv)


# `clss batch` needs Ray (the [batch] extra), which its module imports only when it runs.
def _batch(argv) -> int:
    from .batch import cmd_batch
    return cmd_batch(argv)


# name: (function, one-line summary for `clss --help`), in the order --help lists them.
COMMANDS = {
    "devices": (devices.cmd_devices, "list OpenCL platforms and devices"),
    "verify": (devices.cmd_verify, "diff every kernel against onnxruntime on a device (PASS/FAIL table)"),
    "info": (model.cmd_info, "ops, parameters, FLOPs and planned device memory of an ONNX model"),
    "run": (model.cmd_run, "run an ONNX model on a device (--compare-ort: diff and time vs onnxruntime)"),
    "model": (model.cmd_model, "ONNX models: `model info` (can clss run it? from the file alone), `model run`"),
    "methods": (methods.cmd_methods, "list the upscaling methods: inputs, scales, precisions, weights"),
    "upscale": (upscale.cmd_upscale, "upscale an EXR sequence with a method (--method), per-stage times"),
    "batch": (_batch, "upscale many sequences on Ray, one worker per OpenCL device; resumes a killed run"),
    "demo": (demo.main, "render the built-in sample scene, upscale it with every method, write pictures and metrics"),
    "eval": (methods.cmd_eval, "score methods on your own sequences against their references (PSNR, SSIM, tPSNR, FLIP)"),
    "bench": (_bench, "benchmark kernels/networks/frame step against onnxruntime (table, JSON, roofline)"),
    "tune": (_tune, "search work-group sizes and kernel tunables per device; store the best"),
}


# Command groups: `clss GROUP SUB ...` runs SUB's function under the prog "clss GROUP SUB";
# the group's own entry in COMMANDS answers --help, a missing or unknown SUB.
GROUPS = {"model": model.MODEL_COMMANDS}


def _version() -> str:
    from .. import __version__
    return __version__


# What a user's mistake raises (a bad flag value, file, device, model or frame, an option a
# method does not take), or a device that cannot run clss (none usable, a kernel its
# compiler refuses even around every cache: the line names the kernel, the compiler's first
# error and the file holding the whole log); each ends the command with one line and exit
# status 2. Anything else is a bug in clss and keeps its traceback. CLSS_TRACEBACK=1 shows
# the traceback of these too.
USER_ERRORS = (ValueError, OSError)


def _user_errors():
    from ..device import DeviceError, KernelBuildError
    from ..errors import ArgumentError
    return USER_ERRORS + (DeviceError, KernelBuildError, ArgumentError)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] == "--version":
        print(f"clss {_version()}")
        return 0
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: clss COMMAND [options]   (clss COMMAND --help for each)\n\n"
              "clss runs neural temporal supersampling networks on any OpenCL 1.2 device.\n\ncommands:")
        for name, (_, summary) in COMMANDS.items():
            print(f"  {name:10s} {summary}")
        print("\n  --version  print the version and exit")
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    # pyopencl warns about any compiler output (PoCL prints notes for valid kernels); a
    # build that fails raises KernelBuildError with the whole log instead.
    warnings.filterwarnings("ignore", message="Non-empty compiler output")
    if name not in COMMANDS:
        print(f"clss: unknown command {name!r}; try `clss --help`", file=sys.stderr)
        return 2
    if name in GROUPS and rest and rest[0] in GROUPS[name]:
        return run_command(f"clss {name} {rest[0]}", GROUPS[name][rest[0]][0], rest[1:])
    return run_command(f"clss {name}", COMMANDS[name][0], rest)


def run_command(prog: str, fn, argv) -> int:
    """fn(argv) with the command line's error policy: a user's mistake is one line on
    stderr and status 2, Ctrl-C is status 130 (commands that write files say first how
    far they got), `--help` and parser errors return their status instead of exiting."""
    from ..errors import cli_message
    try:
        return fn(argv) or 0
    except SystemExit as e:             # argparse: --help (0), or a mistake already printed (2)
        if isinstance(e.code, int) or e.code is None:
            return e.code or 0
        print(e.code, file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\n{prog}: interrupted", file=sys.stderr)
        return 130
    except _user_errors() as e:
        if os.environ.get("CLSS_TRACEBACK"):
            raise
        print(f"{prog}: {cli_message(e)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
