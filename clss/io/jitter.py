"""The jitter of a sequence: a sidecar beside the frames (`SIDECARS`: jitter.json or
jitter.csv, with the frames' numbers, camera cuts in `resets` and metadata), an explicit
file or array, zero, or the Halton(2,3) sequence; every value within [-0.5, 0.5]."""
from __future__ import annotations

import csv
import json
import os

import numpy as np

from ..pipeline.contract import jitter_at as halton_jitter
from .errors import InputError

SIDECARS = ("jitter.json", "jitter.csv")


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
    if isinstance(src, str) and src == "halton":
        if scale is None:
            raise InputError("jitter='halton' needs scale=")
        return [halton_jitter(i, scale) for i in range(len(numbers))], meta
    if isinstance(src, str) and src == "zero":
        return [(0.0, 0.0)] * len(numbers), meta
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
