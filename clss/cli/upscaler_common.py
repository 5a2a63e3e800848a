"""What `clss upscale` and `clss demo` share: the upscaler's options (scale, device,
precision, weights), the input's conventions (clss.Contract's flags), whole-frame output
files, debug views and the stage-time table."""
from __future__ import annotations

import argparse
import os

import numpy as np

from .args import (DEVICE_HELP, UsageError, device_spec, motion_scale, positive_float,
                   resolve_motion_scale)
from .args import scale as scale_arg

PRECISION_CHOICES = ("auto", "fp32", "fp16")
PRECISION_HELP = ("auto (default): fp32 on a CPU; on a GPU fp16 storage (half tensors and history, float "
                  "arithmetic) where the method's fp16 frame step verifies against fp32 on that device (a "
                  "check run once and cached, listed by clss verify), else fp32; fp32; or fp16")
WEIGHTS_HELP = ("network weights for --mode net: a directory from `python -m weights_tools build` "
                "or a .safetensors file (default: the trained weights shipped in the package); "
                "'untrained' for the seeded, untrained networks")


def add_upscaler_args(p: argparse.ArgumentParser, scale=True):
    if scale:
        p.add_argument("--scale", "-s", type=scale_arg, default=2.0,
                       help="output / render size (default 2; 1.5, 3, 4 ... work)")
    p.add_argument("--device", "-d", default=None, type=device_spec, help=DEVICE_HELP)
    p.add_argument("--precision", "-p", default="auto", choices=PRECISION_CHOICES, help=PRECISION_HELP)


def precision_label(asked: str, resolved) -> str:
    """What the run prints: the precisions the upscalers resolved to, "(auto)" when chosen."""
    got = ",".join(dict.fromkeys(resolved))
    return f"{got} (auto)" if asked == "auto" else got


def add_contract_args(p: argparse.ArgumentParser):
    """The flags of clss.Contract's parameters (Contract.FLAGS names them in messages):
    every method takes them, or refuses a value it cannot honour by the flag's name."""
    p.add_argument("--depth-standard", action="store_true",
                   help="depth is standard Z (near = 0); default reversed-Z (near = 1)")
    p.add_argument("--motion-scale", type=motion_scale, default=(1.0, 1.0), metavar="SX,SY",
                   help="factors that turn the stored motion into render pixels pointing to the "
                        "previous position, e.g. '-1,-1', or 'W,H' (the render width and height) "
                        "for motion stored in UV units (default 1,1)")
    p.add_argument("--jitter-scale", type=motion_scale, default=(1.0, 1.0), metavar="SX,SY",
                   help="factors that turn the given jitter into render pixels, the sample's "
                        "offset from the pixel centre (+y down): '-1,-1' for FSR2/DLSS jitter "
                        "offsets, 'W,H' for jitter in UV units (default 1,1)")
    p.add_argument("--exposure", type=positive_float, default=1.0,
                   help="the exposure the colour was rendered with: colour is divided by it on "
                        "the way in and multiplied by it on the way out (default 1)")
    p.add_argument("--nits", type=positive_float, default=None,
                   help="cd/m2 of linear colour 1.0, the PQ transfer's scale (default 100)")
    p.add_argument("--ldr", action="store_true",
                   help="LDR input in [0,1] (no PQ transfer; refused by methods that need HDR)")
    p.dash_values = tuple(getattr(p, "dash_values", ())) + ("--motion-scale", "--jitter-scale")


def contract_of_args(a, render_hw):
    """The clss.Contract of add_contract_args' flags; W and H are the render size (h, w)."""
    from ..pipeline.contract import Contract
    return Contract(depth_inverted=not a.depth_standard,
                    motion_scale=resolve_motion_scale(a.motion_scale, render_hw),
                    jitter_scale=resolve_motion_scale(a.jitter_scale, render_hw),
                    hdr=not a.ldr, exposure=a.exposure,
                    **({} if a.nits is None else {"nits": a.nits}))


def check_weights_mode(weights, net: bool) -> None:
    """--weights only means something to the networks: refuse it without them rather
    than ignore it (a user who passes it expects it to be used)."""
    if weights is not None and not net:
        raise UsageError("--weights applies to the net mode only (rules mode runs no networks); "
                         "drop --weights or run the net mode")
    if weights is not None and not weights.strip():
        raise UsageError("--weights: expected a directory, a .safetensors file or 'untrained', "
                         "got an empty string")


class FrameFiles:
    """The files of the frame being written. A frame counts once all its files are
    written (`done`); an interruption removes the files of the frame in progress
    (`discard`), so an output directory only ever holds whole frames."""

    def __init__(self):
        self.pending: list[str] = []
        self.done_frames = 0

    def add(self, *paths):
        self.pending += paths

    def done(self):
        self.pending = []
        self.done_frames += 1

    def discard(self):
        for p in self.pending:
            if os.path.isfile(p):
                os.unlink(p)
        self.pending = []


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


def write_debug_views(directory, up, frame_number, prefix="", paths=None):
    """Write the debug views of the last frame; each path is appended to `paths` before
    its file is written (so that an interruption knows what to clean up)."""
    from ..io import write_png_ldr
    cap = up._fs.cap if up._fs is not None else 1.0
    paths = [] if paths is None else paths
    for name, img in render_debug_views(up.debug_views(), cap).items():
        p = os.path.join(directory, f"{prefix}{name}.{frame_number:04d}.png")
        paths.append(p)
        write_png_ldr(p, img)
    return paths


def format_stage_table(stages: dict) -> str:
    total = sum(stages.values())
    lines = [f"  {name:12s} {ms:9.2f} ms" for name, ms in stages.items()]
    lines.append(f"  {'total':12s} {total:9.2f} ms")
    return "\n".join(lines)
