"""`clss info` and `clss run`: inspect and run an ONNX model on a device,
optionally side by side with onnxruntime; `clss model info`: check a model's ops
against clss's op table from the file alone; `clss model` groups them."""
from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time

import numpy as np

from ..errors import cli_message
from .args import DEVICE_HELP, ArgParser, check_output_file, device_spec, positive_int

# Defaults of --atol/--rtol for --compare-ort (|d| <= atol*max|ref| + rtol*|ref|):
# fp16 stores every intermediate tensor with an 11-bit mantissa, and the
# reference is fp32 throughout, so whole networks differ by ~1e-3 of their range.
COMPARE_TOL = {"fp32": (1e-4, 1e-3), "fp16": (2e-2, 2e-2), "fp16-native": (5e-2, 5e-2)}


def _shapes(specs) -> dict:
    out = {}
    for s in specs or ():
        name, sep, shape = s.rpartition("=")
        if not sep or not name:
            raise ValueError(f"--input-shape wants NAME=SHAPE like x=1x3x64x64, got {s!r}")
        dims = shape.lower().replace(",", "x").split("x")
        if not all(d.strip().isdigit() and int(d) > 0 for d in dims):
            raise ValueError(f"--input-shape {s}: expected sizes >= 1 separated by 'x', "
                             "like x=1x3x64x64")
        out[name] = shape
    return out


def _load(path, device, precision, input_shapes, prog):
    from ..device import DeviceError
    from ..model import Model, ModelError
    try:
        return Model(path, device=device, precision=precision, input_shapes=input_shapes or None)
    except (ModelError, DeviceError) as e:
        print(f"{prog}: {cli_message(e)}", file=sys.stderr)
        return None


def cmd_info(argv) -> int:
    p = ArgParser(
        prog="clss info",
        description="Load an ONNX model for a device and report its ops (as written, and as clss runs "
                    "them after fusion), parameter count, FLOPs per inference at the given input shapes, "
                    "and the planned peak device memory.",
        epilog="example:\n  clss info classifier.onnx --input-shape x=1x23x1088x1920 --precision fp16",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", help="ONNX file")
    p.add_argument("--input-shape", action="append", metavar="NAME=SHAPE",
                   help="shape of an input with symbolic dimensions, e.g. x=1x3x64x64 (repeatable)")
    p.add_argument("--precision", "-p", default="fp32", choices=("fp32", "fp16", "fp16-native"))
    p.add_argument("--device", "-d", default=None, type=device_spec, help=DEVICE_HELP)
    p.add_argument("--json", metavar="FILE", help="also write the report as JSON")
    a = p.parse_args(argv)
    if a.json is not None:
        check_output_file(a.json, "--json", inputs=[a.model])
    try:
        shapes = _shapes(a.input_shape)
    except ValueError as e:
        print(f"clss info: {e}", file=sys.stderr)
        return 2
    m = _load(a.model, a.device, a.precision, shapes, "clss info")
    if m is None:
        return 2
    from ..model.info import format_summary, summary
    s = summary(m)
    print(format_summary(s, os.path.basename(a.model)))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(s, f, indent=2)
    return 0


MODEL_INFO_HELP = """\
examples:
  clss model info net.onnx                  # can clss run it? ops, opsets, inputs, verdict
  clss model info net.onnx --json net.json  # the same report as JSON
  clss model info net.onnx && clss info net.onnx --input-shape x=1x3x540x960

how it differs from `clss info`:
  clss model info reads the ONNX file and nothing else: no device, no shape resolution, no
  kernel build, external data (.onnx.data) not loaded; symbolic dimensions need no sizes. It
  checks each op type against clss's op table (docs/model.md, "Supported ops and opsets"):
  supported, with the limits that apply; folded at load (its inputs are constants or
  shapes); unsupported, with why: no clss kernel, a custom domain, an op that changed after
  the last opset clss knows; or refused for some nodes: a value clss needs when it plans
  (Resize scales, a Reshape shape) that only the running model computes.
  `clss info` loads the model for a device (give symbolic sizes with --input-shape), runs
  clss's passes and plans memory: parameters, FLOPs, kernels and peak device memory, and
  the node-level refusals of the dry run (attribute values a kernel does not cover).

exit status: 0 every op type supported, 1 something is not, 2 a bad file or flag."""


def cmd_model_info(argv) -> int:
    p = ArgParser(
        prog="clss model info",
        description="Can clss run this ONNX model? Lists its op types (count, supported or not and why,\n"
                    "the limits that apply), its opsets, IR version and producer, the graph inputs and\n"
                    "outputs with their declared shapes, whether it keeps external data, and a one-line\n"
                    "verdict, from the file alone: nothing is built.",
        epilog=MODEL_INFO_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", help="ONNX file")
    p.add_argument("--json", metavar="FILE", help="also write the report as JSON")
    a = p.parse_args(argv)
    if a.json is not None:
        check_output_file(a.json, "--json", inputs=[a.model])
    from ..model.optable import format_report, support_report
    r = support_report(a.model)
    print(format_report(r))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(r, f, indent=2)
    return 0 if r["supported"] else 1


def _model_run(argv) -> int:
    return cmd_run(argv)


# `clss model SUB`: name -> (function, one-line summary).
MODEL_COMMANDS = {
    "info": (cmd_model_info, "ops supported or not (and why), opsets, inputs: from the file alone, nothing built"),
    "run": (_model_run, "run an ONNX model on a device, optionally against onnxruntime (= `clss run`)"),
}


def cmd_model(argv) -> int:
    """`clss model SUB ...`: the model commands as a group."""
    if not argv:
        print(f"clss model: give a subcommand: {', '.join(MODEL_COMMANDS)} (see `clss model --help`)",
              file=sys.stderr)
        return 2
    if argv[0] in ("-h", "--help"):
        print("usage: clss model SUBCOMMAND [options]   (clss model SUBCOMMAND --help for each)\n\n"
              "ONNX models with clss.Model.\n\nsubcommands:")
        for name, (_, summary) in MODEL_COMMANDS.items():
            print(f"  {name:6s} {summary}")
        print("\n`clss info` (load and plan for a device: parameters, FLOPs, memory) and `clss run` stay\n"
              "top-level commands; `clss model run` is `clss run`.\n\n"
              "example:\n  clss model info net.onnx")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in MODEL_COMMANDS:
        print(f"clss model: unknown subcommand {name!r}; one of {', '.join(MODEL_COMMANDS)} "
              "(see `clss model --help`)", file=sys.stderr)
        return 2
    return MODEL_COMMANDS[name][0](rest)   # (clss.cli.main dispatches the group itself)


def _declared_symbolic(path, shapes: dict) -> dict:
    """Shapes from the .npy files are passed for symbolic inputs only, so a
    file of the wrong shape for a static input is reported as a bad input."""
    import onnx
    try:
        g = onnx.load(path, load_external_data=False).graph
    except Exception:
        return shapes
    static = {}
    for vi in g.input:
        t = vi.type.tensor_type
        if t.HasField("shape") and all(d.HasField("dim_value") for d in t.shape.dim):
            static[vi.name] = True
    return {k: v for k, v in shapes.items() if not static.get(k) or isinstance(v, str)}


def _check_output_dir(path, inputs):
    """--output-dir: a directory (created if missing) that can be written, checked before
    the model runs."""
    from .args import UsageError
    if os.path.exists(path) and not os.path.isdir(path):
        raise UsageError(f"--output-dir {path}: is a file, expected a directory")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as e:
        raise UsageError(f"--output-dir {path}: cannot create the directory "
                         f"({e.strerror.lower()})") from None
    check_output_file(os.path.join(path, "output.npy"), "--output-dir", inputs)


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name) or "output"


def _median_ms(fn, repeat: int) -> float:
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


def cmd_run(argv) -> int:
    p = ArgParser(
        prog="clss run",
        description="Run an ONNX model on an OpenCL device. Inputs come from .npy files (their shapes "
                    "resolve symbolic dimensions). With --compare-ort the same inputs also go through "
                    "onnxruntime (CPU): per output the max abs / relative error and PASS/FAIL, and both "
                    "timings (warm: after one run, median of --repeat). Exit status 1 if any output fails.",
        epilog="example:\n  clss run composition.onnx --input x=x.npy --compare-ort --precision fp16",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", help="ONNX file")
    p.add_argument("--input", "-i", action="append", metavar="NAME=FILE.npy", default=[],
                   help="an input array (repeatable)")
    p.add_argument("--random-inputs", action="store_true",
                   help="fill inputs not given with seeded uniform [0,1) data (needs static shapes or "
                        "--input-shape)")
    p.add_argument("--input-shape", action="append", metavar="NAME=SHAPE",
                   help="shape of an input with symbolic dimensions, e.g. x=1x3x64x64")
    p.add_argument("--output-dir", "-o", metavar="D", help="write each output to D/<name>.npy")
    p.add_argument("--compare-ort", action="store_true", help="diff against onnxruntime and time both")
    p.add_argument("--repeat", type=positive_int, default=10, help="timed runs for --compare-ort (default 10)")
    p.add_argument("--atol", type=float, default=None, help="error bound relative to max|ref| "
                   "(default 1e-4 fp32, 2e-2 fp16)")
    p.add_argument("--rtol", type=float, default=None, help="error bound relative to |ref| per element "
                   "(default 1e-3 fp32, 2e-2 fp16)")
    p.add_argument("--precision", "-p", default="fp32", choices=("fp32", "fp16", "fp16-native"))
    p.add_argument("--device", "-d", default=None, type=device_spec, help=DEVICE_HELP)
    p.add_argument("--json", metavar="FILE", help="write the comparison and timings as JSON")
    a = p.parse_args(argv)
    inputs = [a.model] + [s.partition("=")[2] for s in a.input]
    if a.json is not None:
        check_output_file(a.json, "--json", inputs=inputs)
    if a.output_dir is not None:
        _check_output_dir(a.output_dir, inputs)

    feeds = {}
    for spec in a.input:
        name, sep, path = spec.partition("=")
        if not sep or not name or not path:
            print(f"clss run: --input {spec}: expected NAME=FILE.npy (an input name of the model, "
                  "'=', a .npy file)", file=sys.stderr)
            return 2
        if name in feeds:
            print(f"clss run: --input {spec}: input {name!r} is given twice", file=sys.stderr)
            return 2
        try:
            feeds[name] = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as e:
            why = "no such file" if isinstance(e, FileNotFoundError) else f"not a .npy array ({e})"
            print(f"clss run: --input {spec}: {path}: {why}", file=sys.stderr)
            return 2
    try:
        shapes = _shapes(a.input_shape)
    except ValueError as e:
        print(f"clss run: {cli_message(e)}", file=sys.stderr)
        return 2
    for k, v in feeds.items():
        shapes.setdefault(k, tuple(v.shape))
    m = _load(a.model, a.device, a.precision, _declared_symbolic(a.model, shapes), "clss run")
    if m is None:
        return 2
    from ..model import InputError, ModelError
    missing = [k for k in m.input_names if k not in feeds]
    if missing and a.random_inputs:
        # Inputs whose values decide shapes (Resize scales, a Reshape shape): random
        # values would make up a model; they come from --input.
        values = [k for k in missing if k in m.value_inputs]
        if values:
            print(f"clss run: --random-inputs: the values of {', '.join(map(repr, values))} decide shapes in this "
                  f"model ({m.value_inputs[values[0]][0].describe()}); give them with "
                  + " ".join(f"--input {k}=FILE.npy" for k in values), file=sys.stderr)
            return 2
        g = np.random.default_rng(0)
        for k in missing:
            dt = m._in_dtypes[k]
            feeds[k] = (g.random(m.input_shapes[k]).astype(dt) if dt.kind == "f"
                        else np.zeros(m.input_shapes[k], dt))
    try:
        outs = m.run(feeds)   # plans for the values of the inputs that decide shapes, if any
    except (InputError, ModelError) as e:
        print(f"clss run: {cli_message(e)}", file=sys.stderr)
        return 2
    report = {"model": a.model, "precision": a.precision, "device": m.device.info.name, "outputs": {}}
    for k, v in outs.items():
        line = f"{k}: {v.dtype} {list(v.shape)}"
        if v.size and v.dtype.kind == "f":
            line += f"  min {v.min():.6g} max {v.max():.6g} mean {v.mean():.6g}"
        print(line)
        report["outputs"][k] = {"shape": list(v.shape), "dtype": str(v.dtype)}
    if a.output_dir:
        os.makedirs(a.output_dir, exist_ok=True)
        for k, v in outs.items():
            np.save(os.path.join(a.output_dir, _safe(k) + ".npy"), v)
        print(f"wrote {len(outs)} output(s) to {a.output_dir}")
    rc = 0
    if a.compare_ort:
        rc = _compare(a, m, feeds, outs, report)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(report, f, indent=2, default=float)
    return rc


def _compare(a, m, feeds, outs, report) -> int:
    from ..tolerance import Tolerance, compare
    from ..verify.twin import session
    atol, rtol = COMPARE_TOL[a.precision]
    tol = Tolerance(a.atol if a.atol is not None else atol, a.rtol if a.rtol is not None else rtol)
    import onnx
    model = onnx.load(a.model)
    if model.ir_version > 10:
        model.ir_version = 10      # onnxruntime <= 1.31 rejects newer IRs; IR 10 carries opsets 11-25
    sess = session(model)
    ref_list = sess.run(None, feeds)
    refs = dict(zip([o.name for o in sess.get_outputs()], ref_list))
    fails = 0
    print(f"\ncompare with onnxruntime {_ort_version()} (CPU), tolerance {tol}:")
    for k, v in outs.items():
        r = refs[k]
        if r.dtype.kind in "biu":
            same = np.array_equal(v.astype(r.dtype), r)
            print(f"  {k}: {'exact' if same else 'DIFFERS'}  {'PASS' if same else 'FAIL'}")
            fails += not same
            report["outputs"][k].update(passed=bool(same))
            continue
        c = compare(v, r.astype(np.float32), tol)
        fails += not c.passed
        print(f"  {k}: max abs err {c.max_abs:.3g}, max rel err {c.max_rel:.3g} (of max|ref| "
              f"{float(np.abs(r).max()) if r.size else 0:.3g}), err/tol {c.ratio:.3g}  "
              f"{'PASS' if c.passed else 'FAIL ' + c.detail}")
        report["outputs"][k].update(max_abs=c.max_abs, max_rel=c.max_rel, ratio=c.ratio, passed=c.passed)
    dev = m.device
    dfeeds = m.upload(feeds)

    def device_run():
        m.run_device(dfeeds)
        dev.queue.finish()
    device_run()
    n = max(1, a.repeat)
    t_host = _median_ms(lambda: m.run(feeds), n)
    t_dev = _median_ms(device_run, n)
    t_ort = _median_ms(lambda: sess.run(None, feeds), n)
    print(f"timings (warm, median of {n}): clss {m.precision} {t_dev:.2f} ms device-resident, "
          f"{t_host:.2f} ms with host transfers | onnxruntime CPU {t_ort:.2f} ms")
    report["timings_ms"] = {"clss_device": t_dev, "clss_host": t_host, "onnxruntime": t_ort}
    report["passed"] = fails == 0
    print("PASS" if fails == 0 else f"FAIL ({fails} output(s) out of tolerance)")
    return 1 if fails else 0


def _ort_version() -> str:
    import onnxruntime
    return onnxruntime.__version__
