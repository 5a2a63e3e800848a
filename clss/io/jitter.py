"""The jitter of a sequence: a sidecar beside the frames (`SIDECARS`: jitter.json or
jitter.csv, with the frames' numbers, camera cuts in `resets` and metadata), an explicit
file or array, or one of the named patterns engines send (`PATTERNS`: zero, 2x2,
Halton(2,3) of 8, 16 or the contract's ceil(8 scale^2) phases, R2); every value within
[-0.5, 0.5]. `as_sent` gives a pattern as an engine sends it (negated, NDC or UV units)
with the contract's `jitter_scale` that converts it back (docs/input-contract.md)."""
from __future__ import annotations

import csv
import json
import os

import numpy as np

from ..pipeline.contract import halton
from ..pipeline.contract import jitter_at as halton_jitter
from .errors import InputError

SIDECARS = ("jitter.json", "jitter.csv")

# ---- the patterns engines send (issue 53) -----------------------------------------------
# Each is (jx, jy) in the contract's units (render pixels, the sample's offset from the
# pixel centre, +y down) for frame `index` of a sequence at `scale`. Engines differ in
# the pattern, its length, its sign and its units; the last two are conventions the
# contract converts (`as_sent`), the first two change where the samples fall.

_G = 1.32471795724474602596           # the plastic number: R2's generator (Roberts 2018)
_R2 = (1.0 / _G, 1.0 / (_G * _G))
# the 2x2 ordered grid, diagonals alternating (the four output pixel centres at 2x)
_GRID2 = ((-0.25, -0.25), (0.25, 0.25), (0.25, -0.25), (-0.25, 0.25))


def _halton_n(n):
    return lambda i, scale: (halton(i % n + 1, 2) - 0.5, halton(i % n + 1, 3) - 0.5)


def _r2(i, scale):
    # frac(0.5 + n alpha) - 0.5, from n = 1: never repeats; within [-0.5, 0.5)
    return tuple(float((0.5 + (i + 1) * a) % 1.0) - 0.5 for a in _R2)


PATTERNS = {
    "zero": (lambda i, scale: (0.0, 0.0), "no jitter: every sample at the pixel centre"),
    "2x2": (lambda i, scale: _GRID2[i % 4], "the 2x2 ordered grid, +-0.25 px, 4 phases"),
    "halton8": (_halton_n(8), "Halton(2,3) from index 1, 8 phases"),
    "halton16": (_halton_n(16), "Halton(2,3) from index 1, 16 phases"),
    "halton": (halton_jitter, "Halton(2,3) from index 1, ceil(8 scale^2) phases "
               "(FSR2's; 32 at 2x): the default"),
    "r2": (_r2, "the R2 sequence (plastic-number Kronecker), never repeating"),
}
PATTERN_ALIASES = {"none": "zero"}
UNITS = ("pixel", "ndc", "uv")


def pattern_name(name) -> str:
    """The pattern's canonical name; ValueError naming the known ones."""
    key = PATTERN_ALIASES.get(str(name).lower(), str(name).lower())
    if key not in PATTERNS:
        raise ValueError(f"unknown jitter pattern {name!r} (known: "
                         f"{', '.join(list(PATTERNS) + list(PATTERN_ALIASES))})")
    return key


def pattern_jitter(name, frames, scale=2.0, *, flip=(1, 1), phase=0) -> np.ndarray:
    """[frames, 2] float64 (jx, jy) of pattern `name` in the contract's units, from phase
    `phase` (an engine's frame counter rarely starts at 0), each axis times `flip` (+-1:
    the mirrored pattern of an engine whose y axis or sign differs)."""
    fn = PATTERNS[pattern_name(name)][0]
    sx, sy = (float(f) for f in flip)
    if {abs(sx), abs(sy)} != {1.0}:
        raise ValueError(f"flip: expected +-1 per axis, got {tuple(flip)}")
    out = np.array([fn(int(phase) + i, scale) for i in range(int(frames))], np.float64)
    return out.reshape(-1, 2) * (sx, sy)


def as_sent(jitter, units="pixel", *, negate=False, render_size=None):
    """(values, jitter_scale): `jitter` ([n, 2], the contract's render pixels) as an engine
    sends it, and the contract's jitter_scale that turns those values back into it
    (clss.Contract(jitter_scale=...)). units: "pixel"; "ndc" (2 units per screen, +y up,
    the projection matrix's offset); "uv" (1 unit per screen, +y down); negate: the
    offset FSR2 and DLSS take (the sample is at centre - offset)."""
    if units not in UNITS:
        raise ValueError(f"units: expected one of {', '.join(UNITS)}, got {units!r}")
    if units != "pixel" and render_size is None:
        raise ValueError(f"units {units!r} need render_size (h, w)")
    h, w = render_size if render_size is not None else (1, 1)
    scale = {"pixel": (1.0, 1.0), "ndc": (w / 2.0, -h / 2.0), "uv": (float(w), float(h))}[units]
    scale = tuple(-s for s in scale) if negate else scale
    values = np.asarray(jitter, np.float64).reshape(-1, 2) / scale
    return values, scale


def _read_jitter_file(path):
    """(per-frame dict or list of (jx, jy), metadata dict) from a JSON or CSV sidecar."""
    try:
        if path.lower().endswith(".json"):
            with open(path) as fh:
                obj = json.load(fh)
            meta = {}
            if isinstance(obj, dict):
                meta = {k: v for k, v in obj.items() if k not in ("jitter", "frames")}
                jit = obj.get("jitter")
                if jit is None:
                    raise ValueError("no 'jitter' key")
                frames = obj.get("frames")
                if isinstance(jit, dict):
                    return {int(k): tuple(map(float, v)) for k, v in jit.items()}, meta
                pairs = [tuple(map(float, v)) for v in jit]
                if frames is not None:
                    return dict(zip((int(n) for n in frames), pairs)), meta
                return pairs, meta
            return [tuple(map(float, v)) for v in obj], meta
        with open(path, newline="") as fh:
            rows = [r for r in csv.reader(fh) if r and not r[0].lstrip().startswith("#")]
        if rows and not _is_number(rows[0][0]):
            head = [c.strip().lower() for c in rows[0]]
            rows = rows[1:]
            if "frame" in head:
                i, x, y = head.index("frame"), head.index("jx"), head.index("jy")
                return {int(float(r[i])): (float(r[x]), float(r[y])) for r in rows}, {}
            x, y = head.index("jx"), head.index("jy")
            return [(float(r[x]), float(r[y])) for r in rows], {}
        if rows and len(rows[0]) >= 3:
            return {int(float(r[0])): (float(r[1]), float(r[2])) for r in rows}, {}
        return [(float(r[0]), float(r[1])) for r in rows], {}
    except (OSError, ValueError, KeyError, IndexError, TypeError) as e:
        raise InputError(f"{path}: cannot read jitter ({e})") from None


def _is_number(s):
    try:
        float(s)
        return True
    except ValueError:
        return False


def _resets(value, where):
    """The sidecar's `resets`: a list of frame numbers."""
    try:
        if isinstance(value, (str, bytes)) or not all(float(r) == int(r) for r in value):
            raise ValueError
        return {int(r) for r in value}
    except (TypeError, ValueError):
        raise InputError(f"{where}: 'resets' must be a list of frame numbers, got {value!r}") from None


def _resolve_jitter(jitter, scale, numbers, directory):
    meta = {}
    src = jitter
    if jitter is None:
        for name in SIDECARS:
            p = os.path.join(directory, name)
            if os.path.isfile(p):
                src = p
                break
        else:
            if scale is None:
                raise InputError(f"{directory}: no jitter sidecar ({' or '.join(SIDECARS)}); "
                                 "pass jitter= or scale= for the Halton sequence")
            src = "halton"
    named = isinstance(src, str) and (src.lower() in PATTERNS or src.lower() in PATTERN_ALIASES)
    if named:
        name = pattern_name(src)
        if scale is None and name == "halton":
            raise InputError("jitter='halton' needs scale=")
        jit = pattern_jitter(name, len(numbers), 2.0 if scale is None else scale)
        return [tuple(map(float, j)) for j in jit], dict(meta, pattern=name)
    if isinstance(src, (str, os.PathLike)):
        path = os.fspath(src)
        table, meta = _read_jitter_file(path)
        meta = dict(meta, sidecar=path)
        if isinstance(table, dict):
            lost = [n for n in numbers if n not in table]
            if lost:
                raise InputError(f"{path}: no jitter for frame {lost[0]}")
            out = [table[n] for n in numbers]
        else:
            if len(table) < len(numbers):
                raise InputError(f"{path}: {len(table)} jitter values for {len(numbers)} frames")
            out = list(table[:len(numbers)])
    else:
        arr = np.asarray(src, np.float64)
        if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) < len(numbers):
            raise InputError(f"jitter: expected an (n >= {len(numbers)}, 2) array, got {arr.shape}")
        out = [tuple(map(float, r)) for r in arr[:len(numbers)]]
        path = "jitter"
    for n, (jx, jy) in zip(numbers, out):
        if not (abs(jx) <= 0.5 and abs(jy) <= 0.5):
            raise InputError(f"{path}: jitter of frame {n} ({jx}, {jy}) is outside [-0.5, 0.5]")
    return [(float(a), float(b)) for a, b in out], meta
