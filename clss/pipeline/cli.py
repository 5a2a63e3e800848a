"""`clss upscale` (an EXR sequence through clss.Upscaler) and `clss demo` (clss.demo).

Both are registered with clss.cli, which imports this module on start."""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from ..cli import DEVICE_HELP, register

PRECISION_CHOICES = ("fp32", "fp16")


def add_upscaler_args(p: argparse.ArgumentParser, scale=True):
    if scale:
        p.add_argument("--scale", "-s", type=float, default=2.0,
                       help="output / render size (default 2; 1.5, 3, 4 ... work)")
    p.add_argument("--device", "-d", default=None, help=DEVICE_HELP)
    p.add_argument("--precision", "-p", default="fp32", choices=PRECISION_CHOICES,
                   help="fp32, or fp16 (half storage of history and network tensors)")


def _pair(text, what):
    try:
        a, b = (float(v) for v in text.split(","))
        return a, b
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what}: expected two numbers 'x,y', got {text!r}")


# ---------------------------------------------------------------- debug views
DEBUG_VIEWS = ("ghost", "ghost_class", "alias_class", "blend_weight", "counter", "depth_difference")
# Class colours: visibility ghosting red, shading ghosting amber, no ghosting dark grey;
# geometry aliasing blue, texture aliasing green, none dark grey.
GHOST_COLOURS = np.array([[0.9, 0.15, 0.1], [1.0, 0.7, 0.1], [0.12, 0.12, 0.12]], np.float32)
ALIAS_COLOURS = np.array([[0.2, 0.4, 1.0], [0.2, 0.85, 0.3], [0.12, 0.12, 0.12]], np.float32)


def _colormap(name, x):
    try:
        from matplotlib import colormaps
        return colormaps[name](np.clip(x, 0, 1))[..., :3].astype(np.float32)
    except Exception:               # no matplotlib: grey levels
        return np.repeat(np.clip(x, 0, 1)[..., None], 3, -1).astype(np.float32)


def render_debug_views(views: dict, cap: float) -> dict:
    """Display images (H x W x 3 in [0, 1]) of Upscaler.debug_views(): ghost white on
    black, classes by colour, blend weight and counter / cap in viridis, depth difference
    in coolwarm over [-0.25, 0.25] (red = disocclusion)."""
    out = {}
    for name, v in views.items():
        if name == "ghost":
            out[name] = np.repeat(v[..., None], 3, -1).astype(np.float32)
        elif name == "ghost_class":
            out[name] = GHOST_COLOURS[v.astype(np.int64)]
        elif name == "alias_class":
            out[name] = ALIAS_COLOURS[v.astype(np.int64)]
        elif name == "blend_weight":
            out[name] = _colormap("viridis", v)
        elif name == "counter":
            out[name] = _colormap("viridis", v / max(cap, 1.0))
        elif name == "depth_difference":
            out[name] = _colormap("coolwarm", 0.5 + 2.0 * v)
    return out


def write_debug_views(directory, up, frame_number, prefix=""):
    from ..io import write_png_ldr
    cap = up._fs.cap if up._fs is not None else 1.0
    paths = []
    for name, img in render_debug_views(up.debug_views(), cap).items():
        p = os.path.join(directory, f"{prefix}{name}.{frame_number:04d}.png")
        write_png_ldr(p, img)
        paths.append(p)
    return paths


def format_stage_table(stages: dict) -> str:
    total = sum(stages.values())
    lines = [f"  {name:12s} {ms:9.2f} ms" for name, ms in stages.items()]
    lines.append(f"  {'total':12s} {total:9.2f} ms")
    return "\n".join(lines)


# ---------------------------------------------------------------- clss upscale
def cmd_upscale(argv) -> int:
    p = argparse.ArgumentParser(
        prog="clss upscale",
        description="Upscale a rendered EXR sequence with CLSS temporal supersampling. INPUT is "
                    "a directory of EXR frames (one multichannel file per frame, or color.* / "
                    "depth.* / motion.* files), a glob or a numbered pattern; jitter comes from "
                    "jitter.json / jitter.csv beside the frames, else the Halton(2,3) sequence.",
        epilog="example:\n  clss upscale shots/ -o out/ --mode rules --png",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input")
    p.add_argument("-o", "--out", required=True, help="output directory")
    add_upscaler_args(p)
    p.add_argument("--mode", "-m", default="net", choices=("net", "rules"),
                   help="net (classifier + composition networks) or rules (no networks)")
    p.add_argument("--weights", "-w", default=None,
                   help="directory from `python -m weights_tools build` or a .safetensors file "
                        "(default: seeded, untrained networks)")
    p.add_argument("--debug-views", action="store_true",
                   help="also write ghosting/aliasing class maps, blend weight, sample counter "
                        "and depth difference PNGs per frame (OUT/debug/)")
    p.add_argument("--png", action="store_true", help="also write tone-mapped PNGs")
    p.add_argument("--channels", default=None,
                   help="channel names, e.g. 'color=R,G,B;depth=depth.Z;motion=mv.x,mv.y'")
    p.add_argument("--jitter", default=None,
                   help="jitter sidecar (JSON/CSV), 'halton' or 'zero' (default: sidecar, else halton)")
    p.add_argument("--frames", "-n", type=int, default=None, help="only the first N frames")
    p.add_argument("--depth-standard", action="store_true",
                   help="depth is standard Z (near = 0); default reversed-Z (near = 1)")
    p.add_argument("--motion-scale", type=lambda s: _pair(s, "--motion-scale"), default=(1.0, 1.0),
                   help="factors that turn the stored motion into render pixels pointing to the "
                        "previous position, e.g. '-1,-1' or 'W,H' for UV motion (default 1,1)")
    p.add_argument("--exposure", type=float, default=1.0)
    p.add_argument("--ldr", action="store_true", help="LDR input in [0,1] (no PQ transfer)")
    p.add_argument("--sanitize", action="store_true",
                   help="replace NaN/Inf inputs (default: refuse such frames and stop)")
    a = p.parse_args(argv)
    from ..io import InputError, read_sequence, write_exr, write_png
    from ..progress import progress
    from .contract import FrameInputError
    from .upscaler import Upscaler

    def fail(msg):
        print(f"clss upscale: {msg}", file=sys.stderr)
        return 2

    channels = None
    if a.channels:
        try:
            channels = dict(kv.split("=", 1) for kv in a.channels.split(";") if kv.strip())
        except ValueError:
            return fail(f"--channels: expected 'buffer=A,B,C;...', got {a.channels!r}")
    try:
        seq = read_sequence(a.input, channels=channels, jitter=a.jitter, scale=a.scale)
        up = Upscaler(a.scale, mode=a.mode, weights=a.weights, device=a.device,
                      precision=a.precision, depth_inverted=not a.depth_standard,
                      motion_scale=a.motion_scale, hdr=not a.ldr, exposure=a.exposure,
                      sanitize=a.sanitize, profile=True, debug=a.debug_views)
    except (InputError, ValueError, OSError) as e:
        return fail(e)
    n = len(seq) if a.frames is None else min(len(seq), max(a.frames, 0))
    os.makedirs(a.out, exist_ok=True)
    dbg_dir = os.path.join(a.out, "debug")
    print(f"clss upscale: {n} frames from {a.input}, mode {a.mode}, x{a.scale:g}, "
          f"{a.precision}, device {up.dev.info.name}", file=sys.stderr)
    if a.mode == "net" and not up.trained:
        print("clss upscale: note: no --weights given, the networks are untrained (seeded init)",
              file=sys.stderr)
    scores = []
    t0 = time.perf_counter()
    done = 0
    try:
        for i in progress(range(n), desc="upscale", unit="frame", total=n):
            f = seq[i]
            number = f.meta.get("frame", i)
            try:
                out = up.step(f.color, f.depth, f.motion, f.jitter, reset=f.reset)
            except FrameInputError as e:
                files = f.meta.get("files", {})
                return fail(f"frame {number} ({files.get('color', '?')}): {e}; "
                            f"{done} frames written to {a.out}")
            write_exr(os.path.join(a.out, f"frame.{number:04d}.exr"), out)
            if a.png:
                write_png(os.path.join(a.out, f"frame.{number:04d}.png"), out)
            if a.debug_views:
                write_debug_views(dbg_dir, up, number)
            if f.reference is not None and f.reference.shape == out.shape:
                from ..metrics import psnr, ssim
                scores.append((psnr(out, f.reference), ssim(out, f.reference)))
            done += 1
    except (InputError, ValueError, OSError) as e:
        return fail(f"{e}; {done} frames written to {a.out}")
    dt = time.perf_counter() - t0
    print(f"\n{done} frames {up.render_size[1]}x{up.render_size[0]} -> "
          f"{up.output_size[1]}x{up.output_size[0]} in {dt:.1f} s ({done / dt:.2f} frames/s) "
          f"-> {a.out}")
    if a.mode == "net":
        print(f"classifier: {up.classifier_backend_name}")
    print("per-stage time per frame (OpenCL events; classifier: wall time):")
    print(format_stage_table(up.stage_ms()))
    if scores:
        ps, ss = np.array(scores).T
        print(f"against the reference frames: PSNR {ps.mean():.2f} dB, SSIM {ss.mean():.4f}")
    return 0


def cmd_demo(argv) -> int:
    from ..demo import main
    return main(argv)


register("upscale", cmd_upscale, "upscale an EXR sequence with CLSS (net or rules), per-stage times")
register("demo", cmd_demo, "render the built-in sample scene, upscale it, write pictures and metrics")
