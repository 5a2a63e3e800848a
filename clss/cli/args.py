"""Argument checking shared by every `clss` subcommand: a parser whose mistakes end in
one line, value types that name the flag, and checks of output paths that run
before any work starts (so an hour-long run cannot end in "cannot write")."""
from __future__ import annotations

import argparse
import glob
import math
import os
import re
import tempfile

from ..errors import UserError


# The --device help, the same in every subcommand that runs on a device.
DEVICE_HELP = ("OpenCL device: an index from `clss devices` or a substring of "
               "'platform / device (driver)' (default: $CLSS_DEVICE, $PYOPENCL_CTX, else pip's PoCL CPU device, or the next PoCL CPU device that builds kernels)")


class UsageError(UserError):
    """A command-line mistake; the message names the flag."""


class ArgParser(argparse.ArgumentParser):
    """argparse, but a mistake prints one line (what was wrong, and where to read
    more) instead of the usage block, and exits with status 2."""

    dash_values: tuple = ()

    def error(self, message):
        self.exit(2, f"{self.prog}: {message} (see `{self.prog} --help`)\n")

    def parse_known_args(self, args=None, namespace=None):
        # argparse takes '-1,-1' or '-W,H' after a flag for another flag; the flags in
        # `dash_values` take their next word as the value whatever it starts with.
        if args is not None and self.dash_values:
            args, out = list(args), []
            while args:
                tok = args.pop(0)
                if tok in self.dash_values and args:
                    tok = f"{tok}={args.pop(0)}"
                out.append(tok)
            args = out
        return super().parse_known_args(args, namespace)


# ---------------------------------------------------------------- value types
# argparse prefixes their messages with "argument --flag:", so they say only what is wanted.

def positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        v = 0
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return v


def positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return v


SCALE_RANGE = (1.0, 16.0)       # as clss.Upscaler accepts


def scale(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    lo, hi = SCALE_RANGE
    if not (math.isfinite(v) and lo <= v <= hi):
        raise argparse.ArgumentTypeError(f"expected the output / render size ratio, a number in "
                                         f"[{lo:g}, {hi:g}] (e.g. 2), got {text!r}")
    return v


def device_spec(text: str) -> str:
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a device index or name from `clss devices`, "
                                         "got an empty string")
    return text


_SIZE_FACTOR = re.compile(r"([+-]?)(\d+\.?\d*|\.\d+)?\*?([WH])", re.IGNORECASE)


def motion_scale(text: str) -> tuple:
    """'sx,sy': each a number, or a multiple of W / H (the render width / height, for
    motion stored in UV or NDC units): '1,1', '-1,-1', 'W,H', '-W,H', '-0.5W,0.5H'.
    Returns (sx, sy) with W / H kept as (factor, 'W' or 'H') until the size is known."""
    parts = [p.strip() for p in text.split(",")]
    out = []
    for p in parts:
        m = _SIZE_FACTOR.fullmatch(p)
        if m:
            factor = float(m.group(2)) if m.group(2) else 1.0
            out.append((-factor if m.group(1) == "-" else factor, m.group(3).upper()))
            continue
        try:
            v = float(p)
        except ValueError:
            v = math.nan
        if not math.isfinite(v):
            break
        out.append(v)
    if len(out) != 2 or len(parts) != 2:
        raise argparse.ArgumentTypeError(f"expected 'sx,sy': numbers, or multiples of W and H "
                                         f"(the render width and height), e.g. '-1,-1', 'W,H' or "
                                         f"'-0.5W,0.5H'; got {text!r}")
    return tuple(out)


def resolve_motion_scale(pair, render_hw) -> tuple[float, float]:
    """motion_scale()'s result with W and H replaced by the render size (h, w)."""
    h, w = render_hw
    return tuple(v if isinstance(v, float) else v[0] * (w if v[1] == "W" else h) for v in pair)


# ---------------------------------------------------------------- output paths

def _same_or_inside(path: str, directory: str) -> bool:
    try:
        return os.path.commonpath([path, directory]) == directory
    except ValueError:      # different drives
        return False


def check_output_file(path: str, flag: str, inputs=()) -> str:
    """Refuse, before any work, an output file that cannot be written or that is one of
    `inputs`. Returns the path."""
    if not path:
        raise UsageError(f"{flag}: expected a file name, got an empty string")
    real = os.path.realpath(path)
    if os.path.isdir(real):
        raise UsageError(f"{flag} {path}: is a directory, expected a file name")
    for p in inputs:
        if p and os.path.realpath(p) == real:
            raise UsageError(f"{flag} {path}: is an input file; choose another name")
    parent = os.path.dirname(real)
    if not os.path.isdir(parent):
        raise UsageError(f"{flag} {path}: the directory {os.path.dirname(path) or '.'} does not exist")
    if not os.access(parent, os.W_OK) or (os.path.exists(real) and not os.access(real, os.W_OK)):
        raise UsageError(f"{flag} {path}: not writable (permission denied)")
    return path


def prepare_output_dir(path: str, flag: str, inputs=(), overwrite: bool = False,
                       outputs=()) -> list[str]:
    """Check, before any work, that directory `path` can receive a new set of outputs
    (`start_output` creates it when the run starts). Refused: a path that is a file; a
    directory that is, or holds, one of the `inputs` (a run must never overwrite its
    own frames); one that cannot be created or written; one that is not empty, unless
    `overwrite`.

    With `overwrite`, returns the files of a previous set (those matching the glob
    patterns `outputs`, relative to `path`): the caller removes them with
    `start_output` once the run is about to write, so that the directory then holds
    one set only. Other files are left alone."""
    if not path:
        raise UsageError(f"{flag}: expected a directory, got an empty string")
    real = os.path.realpath(path)
    if os.path.exists(real) and not os.path.isdir(real):
        raise UsageError(f"{flag} {path}: is a file, expected a directory")
    held = sorted(p for p in inputs if _same_or_inside(os.path.realpath(p), real))
    if held:
        names = ", ".join(os.path.basename(p) for p in held[:3]) + (", ..." if len(held) > 3 else "")
        raise UsageError(f"{flag} {path}: holds the input files ({names}); writing there would "
                         "overwrite them, choose another output directory")
    stale = []
    if os.path.isdir(real):
        entries = sorted(os.listdir(real))
        if entries and not overwrite:
            shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
            raise UsageError(f"{flag} {path}: not empty ({len(entries)} entries: {shown}); pass "
                             "--overwrite to replace a previous run's output, or choose another directory")
        for pat in outputs:
            stale += [p for p in glob.glob(os.path.join(glob.escape(real), pat)) if os.path.isfile(p)]
        try:
            with tempfile.TemporaryFile(dir=real):
                pass
        except OSError as e:
            raise UsageError(f"{flag} {path}: cannot write there ({e.strerror.lower()})") from None
    else:
        # Created only when the run starts (start_output), so a refused run leaves nothing.
        parent = os.path.dirname(real)
        while not os.path.exists(parent):
            parent = os.path.dirname(parent)
        if not os.path.isdir(parent):
            raise UsageError(f"{flag} {path}: cannot create the directory ({parent} is a file)")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise UsageError(f"{flag} {path}: cannot create the directory ({parent} is not "
                             "writable)")
    return sorted(set(stale))


def start_output(path: str, stale) -> None:
    """Create the output directory checked by prepare_output_dir, and remove the files
    of the previous output set (with the directories below it that they leave empty)."""
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as e:
        raise UsageError(f"{path}: cannot create the directory ({e.strerror.lower()})") from None
    keep = os.path.realpath(path)
    dirs = set()
    for p in stale:
        if os.path.isfile(p):
            os.unlink(p)
            dirs.add(os.path.dirname(p))
    for d in sorted(dirs, key=len, reverse=True):
        if os.path.realpath(d) != keep and not os.listdir(d):
            os.rmdir(d)
