"""`clss upscale`: an EXR sequence through any method's clss.Upscaler, per-stage times."""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from .. import selfcheck
from ..errors import cli_message
from .args import ArgParser, UsageError, positive_int, prepare_output_dir, start_output
from .upscaler_common import (WEIGHTS_HELP, FrameFiles, add_contract_args, add_upscaler_args,
                              check_weights_mode, contract_of_args, format_stage_table,
                              precision_label, write_debug_views)


# ---------------------------------------------------------------- clss upscale
# What a run writes into OUT: replaced as a whole by --overwrite.
OUTPUT_SET = ("frame.*.exr", "frame.*.png", "debug/*.png")


def parse_channels(text):
    """--channels 'color=R,G,B;depth=depth.Z' -> {buffer: names}; unknown buffers refused."""
    from ..io import check_channels
    if text is None:
        return None
    channels = {}
    for item in (kv.strip() for kv in text.split(";")):
        if not item:
            continue
        key, sep, names = item.partition("=")
        if not sep or not key.strip() or not names.strip():
            raise UsageError(f"--channels: expected 'buffer=A,B,C;...' (e.g. "
                             f"'color=R,G,B;depth=depth.Z'), got {item!r} in {text!r}")
        channels[key.strip()] = names.strip()
    if not channels:
        raise UsageError(f"--channels: expected 'buffer=A,B,C;...', got {text!r}")
    check_channels(channels)
    return channels


def format_sanitized(report: list, frames: int) -> str:
    """--sanitize's account: how many values it replaced, in which frames."""
    if not report:
        return f"--sanitize: no value needed replacing in {frames} frames"
    total = sum(sum(r.values()) for _, r in report)
    each = [f"frame {n} (" + ", ".join(f"{k} {v}" for k, v in r.items()) + ")"
            for n, r in report[:10]]
    more = f", and {len(report) - 10} more frames" if len(report) > 10 else ""
    return (f"--sanitize: replaced {total} non-finite values in {len(report)} of {frames} frames: "
            + ", ".join(each) + more)


def _parser() -> ArgParser:
    p = ArgParser(
        prog="clss upscale",
        description="Upscale a rendered EXR sequence with one of clss's methods (`clss methods` "
                    "lists them; default clss, CLSS's trained networks). INPUT is "
                    "a directory of EXR frames (one multichannel file per frame, or color.* / "
                    "depth.* / motion.* files), a glob or a numbered pattern; jitter comes from "
                    "jitter.json / jitter.csv beside the frames, else the Halton(2,3) sequence. "
                    "Outputs are named by the input frame numbers. The input contract (units, "
                    "signs, sidecars, engine conventions) is in docs/input-contract.md.",
        epilog="examples:\n  clss upscale shots/ -o out/ --png\n"
               "  clss upscale shots/ -o out/ --method clss-rules --scale 3\n"
               "  clss upscale 'shots/frame.####.exr' -o out/ --method jbicubic --frames 10",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", help="directory, glob ('shots/*.exr') or numbered pattern "
                                 "('shots/frame.%%04d.exr', 'shots/frame.####.exr')")
    p.add_argument("-o", "--out", required=True,
                   help="output directory: created if missing; refused if it holds input files, "
                        "or if it is not empty (unless --overwrite)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a previous run's output in OUT (its frame.* and debug/ files)")
    return add_upscale_options(p)


def add_upscale_options(p: ArgParser) -> ArgParser:
    """Every option of `clss upscale` but its input and output (`clss batch` takes the same)."""
    add_upscaler_args(p)
    p.add_argument("--method", default=None,
                   help="the method (`clss methods` lists them: bicubic, jbicubic, clss-rules, "
                        "clss); default clss")
    p.add_argument("--mode", "-m", default=None, choices=("net", "rules"),
                   help="older spelling: net = --method clss, rules = --method clss-rules")
    p.add_argument("--weights", "-w", default=None, help=WEIGHTS_HELP)
    p.add_argument("--debug-views", action="store_true",
                   help="also write ghosting/aliasing class maps, blend weight, sample counter "
                        "and depth difference PNGs per frame (OUT/debug/)")
    p.add_argument("--png", action="store_true", help="also write tone-mapped PNGs")
    p.add_argument("--channels", default=None,
                   help="channel names, e.g. 'color=R,G,B;depth=depth.Z;motion=mv.x,mv.y' "
                        "(buffers: color, depth, motion, reference and the G-buffers of "
                        "docs/input-contract.md, e.g. albedo, normal)")
    p.add_argument("--jitter", default=None,
                   help="jitter sidecar (JSON/CSV) or a pattern: halton, zero, 2x2, halton8, "
                   "halton16, r2 (docs/input-contract.md; default: sidecar, else halton)")
    p.add_argument("--frames", "-n", type=positive_int, default=None, help="only the first N frames")
    add_contract_args(p)
    p.add_argument("--sanitize", action="store_true",
                   help="replace NaN/Inf inputs and report how many, in which frames "
                        "(default: refuse such frames and stop)")
    for ext in _method_options():
        ext.add_arguments(p)
    return p


def _method_options() -> list:
    """The modules of the options some methods add to `clss upscale` (MethodSpec.cli: the
    MLP's online training), each once."""
    import importlib
    from .. import methods
    return [importlib.import_module(m)
            for m in dict.fromkeys(s.cli for s in methods.specs() if s.cli)]


def cmd_upscale(argv) -> int:
    p = _parser()
    a = p.parse_args(argv)
    from ..io import read_sequence
    name, spec = check_method(p, a)
    channels = parse_channels(a.channels)
    seq = read_sequence(a.input, channels=channels, jitter=a.jitter, scale=a.scale)
    n = len(seq) if a.frames is None else min(len(seq), a.frames)
    first = seq[0]
    check_inputs(a, name, spec, first)      # before anything is written
    inputs = seq.files + ([a.jitter] if a.jitter and os.path.isfile(a.jitter) else [])
    stale = prepare_output_dir(a.out, "-o", inputs, a.overwrite, OUTPUT_SET)
    with selfcheck.deferring():     # the first frame waits for its builds, no self-check
        first_frame = FirstFrame(a.device)
        try:
            return _run(a, seq, n, first, name, stale, first_frame)
        finally:
            first_frame.done()


class FirstFrame:
    """The first frame builds the kernels its method needs (and, on a cold cache, every
    one): a line on stderr while it does, counting the programs built, then how long it
    took. `done` is the frame loop's on_frame hook (called after every frame)."""

    def __init__(self, device):
        from ..device import get_device
        from ..progress import Waiting
        self.dev, self.t0 = get_device(device), time.perf_counter()
        self.wait = Waiting(lambda: f"clss upscale: building kernels for the first frame: "
                                    f"{self.dev.builds} programs, {self.seconds():.0f} s")

    def seconds(self) -> float:
        return time.perf_counter() - self.t0

    def done(self, *_frame) -> None:
        if self.wait is not None:
            self.wait.done(f"clss upscale: first frame in {self.seconds():.1f} s "
                           f"({self.dev.builds} kernel programs built)" if _frame else None)
            self.wait = None


def _run(a, seq, n, first, name, stale, first_frame) -> int:
    up = build_upscaler(a, name, first)
    start_output(a.out, stale)
    print(f"clss upscale: {n} frames from {a.input}, method {name}, x{a.scale:g}, "
          f"{precision_label(a.precision, [up.precision])}, device {up.dev.info.name}", file=sys.stderr)
    if getattr(up, "trained", None) is False:
        print("clss upscale: note: the networks are untrained (seeded init)", file=sys.stderr)
    scores, sanitized = [], []
    t0 = time.perf_counter()
    files = FrameFiles()

    def written():
        return f"{files.done_frames} frames written to {a.out}"
    try:
        _upscale_frames(a, seq, first, n, up, files, scores, sanitized, written,
                        on_frame=first_frame.done)
    except KeyboardInterrupt:
        files.discard()
        print(f"\nclss upscale: interrupted; {written()}", file=sys.stderr)
        return 130
    except (ValueError, OSError) as e:
        files.discard()
        if isinstance(e, UsageError):
            raise
        raise UsageError(f"{cli_message(e)}; {written()}") from None
    done = files.done_frames
    dt = time.perf_counter() - t0
    _print_summary(a, up, done, dt, sanitized, scores)
    for ext in _method_options():
        ext.finish(a, up)
    return 0


def check_method(p, a):
    """(name, spec) of the method the options name, once its weights and debug views are
    known to fit (before any file is read or written)."""
    from .. import methods
    from ..upscaler import method_name
    try:
        name = method_name(a.method, a.mode)
    except ValueError as e:
        p.error(f"--method: {e}" if a.method is not None else str(e))
    spec = methods.spec(name)
    check_weights_mode(a.weights, spec.weights() != "none needed")
    spec.resolve_weights(a.weights, a.scale)    # a scale it ships no weights for: now
    if a.debug_views and "debug" not in (spec.parameters() or ()):
        have = [s.name for s in methods.specs() if "debug" in (s.parameters() or ())]
        raise UsageError(f"--debug-views: the method {name} has no debug views "
                         f"({', '.join(have)} have them)")
    return name, spec


def build_upscaler(a, name, first):
    """The Upscaler the options describe, for a sequence whose first frame is `first`
    (`clss batch` builds one per sequence the same way)."""
    from .. import methods
    from ..upscaler import Upscaler
    # The contract goes to every method; the other options to those that take them (the
    # options methods add check themselves).
    kw = dict(contract=contract_of_args(a, first.color.shape[:2]), sanitize=a.sanitize,
              profile=True, weights=a.weights, debug=a.debug_views)
    for ext in _method_options():
        kw.update(ext.check(a, name, UsageError))
    up = Upscaler(method=name, scale=a.scale, device=a.device, precision=a.precision,
                  **methods.options(name, **kw))
    return up


def check_inputs(a, name, spec, first):
    """What a sequence must give the method, checked on its first frame before anything is
    written: its G-buffers, and the input's conventions (each flag reaches every method, or
    is refused by name). `clss batch` checks each sequence the same way."""
    from .. import methods
    _check_gbuffers(name, spec, first, a.scale)
    methods.check_contract(name, contract_of_args(a, first.color.shape[:2]))


def _check_gbuffers(name, spec, first, scale):
    """A method's G-buffers must be in the sequence: say which and where they are read
    from before any file is written."""
    if not spec.gbuffers:
        return
    from ..pipeline import contract
    from ..pipeline.contract import output_size
    h, w = first.color.shape[:2]
    given = dict(getattr(first, "gbuffers", None) or {})
    try:
        contract.validate_gbuffers(name, spec.gbuffers, spec.optional, given, (h, w),
                                   output_size(h, w, scale))
    except contract.FrameInputError as e:
        raise UsageError(f"{cli_message(e)}; nothing was written") from None


def _upscale_frames(a, seq, first, n, up, files, scores, sanitized, written,
                    indices=None, keep=(), on_frame=None):
    """Upscale and write frames 0..n-1 (or those at `indices`); a refused frame ends the
    run with a UsageError. `clss batch` resumes with `keep`: the numbers of frames already
    written, stepped only for the history; `on_frame(number, paths)` once a frame's files
    are all written."""
    from ..io import write_exr, write_png
    from ..pipeline.contract import FrameInputError
    from ..progress import progress
    exts = _method_options()
    dbg_dir = os.path.join(a.out, "debug")
    indices = range(n) if indices is None else indices
    for i in progress(indices, desc="upscale", unit="frame", total=len(indices)):
        f = first if i == 0 else seq[i]
        number = f.meta.get("frame", i)
        try:
            extra = {}
            for ext in exts:
                extra.update(ext.step_kwargs(a, i, f))
            out = up.step(f.color, f.depth, f.motion, f.jitter, reset=f.reset,
                          **(getattr(f, "gbuffers", None) or {}), **extra)
        except FrameInputError as e:
            where = f.meta.get("files", {}).get("color", "?")
            raise UsageError(f"frame {number} ({where}): {cli_message(e)}; {written()}") from None
        if number in keep:
            continue
        for ext in exts:
            ext.report(a, up, number)
        if up.last_report:
            sanitized.append((number, dict(up.last_report)))
        stem = os.path.join(a.out, f"frame.{number:04d}")
        files.add(stem + ".exr")
        write_exr(stem + ".exr", out)
        if a.png:
            files.add(stem + ".png")
            write_png(stem + ".png", out)
        if a.debug_views:
            write_debug_views(dbg_dir, up, number, paths=files.pending)
        paths = files.pending
        files.done()
        if on_frame is not None:
            on_frame(number, paths)
        if f.reference is not None and f.reference.shape == out.shape:
            from ..metrics import psnr, ssim
            scores.append((psnr(out, f.reference), ssim(out, f.reference)))


def _print_summary(a, up, done, dt, sanitized, scores):
    print(f"\n{done} frames {up.render_size[1]}x{up.render_size[0]} -> "
          f"{up.output_size[1]}x{up.output_size[0]} in {dt:.1f} s ({done / dt:.2f} frames/s) "
          f"-> {a.out}")
    if a.sanitize:
        print(format_sanitized(sanitized, done))
    backend = getattr(up, "classifier_backend_name", None)     # a method with a classifier
    if backend is not None:
        print(f"classifier: {backend}")
    stages = up.stage_ms()
    if stages:
        print("per-stage time per frame (OpenCL events; classifier: wall time):")
        print(format_stage_table(stages))
    if scores:
        ps, ss = np.array(scores).T
        print(f"against the reference frames: PSNR {ps.mean():.2f} dB, SSIM {ss.mean():.4f}")
