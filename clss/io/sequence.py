"""A frame sequence in and out: `read_sequence` opens one (the files from
clss.io.discovery, the channels from clss.io.channels, the jitter from clss.io.jitter)
as a lazy `FrameSequence` of `Frame` (clss.io.frame); `write_sample_sequence` writes frames
in the layout it reads back."""
from __future__ import annotations

import os

import numpy as np

from ..pipeline.contract import GBUFFERS, output_size
from .channels import _extract, check_channels
from .discovery import (_describe, _detect_gbuffer_files, _detect_layout, _pattern_files,
                        _without_gbuffer_files)
from .errors import InputError
from .frame import Frame
from .images import read_exr, write_exr, write_json
from .jitter import _resets, _resolve_jitter


def write_sample_sequence(frames, directory, half=True, gbuffers=False):
    """Write frames (clss.io.Frame or dicts with color, depth, motion, jitter and
    optionally reference) as ``frame.%04d.exr`` (R, G, B [half], Z, mv.x, mv.y [float]),
    ``reference.%04d.exr`` and ``jitter.json``, which `read_sequence(directory)` reads
    back. gbuffers=True also writes the frames' G-buffers (`Frame.gbuffers`, or a dict's
    G-buffer keys): the render-size ones as channels of the frame file (albedo.R,G,B
    [half when `half`], normal.X,Y,Z [float]), the output-size ones as
    ``<name>.%04d.exr`` (float) with the contract's channel names. Returns the list of
    paths written."""
    os.makedirs(directory, exist_ok=True)
    paths, jit, numbers, resets, meta = [], [], [], [], {}
    for pos, f in enumerate(frames):
        n = int(f["index"]) if _has(f, "index") else pos
        gbs = _frame_gbuffers(f) if gbuffers else {}
        parts = [f["color"], f["depth"][..., None], f["motion"]]
        names, halves = ["R", "G", "B", "Z", "mv.x", "mv.y"], [half] * 3 + [False] * 3
        for name, g in GBUFFERS.items():
            if g.resolution == "render" and name in gbs:
                parts.append(np.asarray(gbs[name], np.float32).reshape(
                    gbs[name].shape[:2] + (g.channels,)))
                names += list(g.exr_channels)
                halves += [half and name == "albedo"] * g.channels
        img = np.concatenate(parts, -1)
        p = os.path.join(directory, f"frame.{n:04d}.exr")
        write_exr(p, img, half=halves, channel_names=names)
        paths.append(p)
        for name, g in GBUFFERS.items():
            if g.resolution == "output" and name in gbs:
                p = os.path.join(directory, f"{name}.{n:04d}.exr")
                write_exr(p, gbs[name], half=False, channel_names=g.exr_channels)
                paths.append(p)
        ref = f["reference"] if _has(f, "reference") else None
        if ref is not None:
            p = os.path.join(directory, f"reference.{n:04d}.exr")
            write_exr(p, ref, half=half)
            paths.append(p)
        jit.append([float(f["jitter"][0]), float(f["jitter"][1])])
        numbers.append(n)
        if _has(f, "reset") and f["reset"]:
            resets.append(n)
        if _has(f, "meta") and f["meta"]:
            meta = {k: v for k, v in f["meta"].items() if isinstance(v, (int, float, str))}
    side = {"frames": numbers, "jitter": jit, "resets": resets,
            "conventions": {"depth": "reversed-Z (near=1)",
                            "motion": "render pixels, prev = p + motion, +y down",
                            "jitter": "sample of pixel (i,j) at (j+0.5+jx, i+0.5+jy)"},
            **meta}
    p = os.path.join(directory, "jitter.json")
    write_json(p, side)
    paths.append(p)
    return paths


def _has(f, key):
    if isinstance(f, dict):
        return key in f
    return hasattr(f, key)


def _frame_gbuffers(f):
    """{name: array} of the G-buffers a frame (Frame or dict) carries."""
    if isinstance(f, dict):
        found = dict(f.get("gbuffers") or {})
        found.update({k: f[k] for k in GBUFFERS if f.get(k) is not None})
        return found
    return {k: v for k, v in (getattr(f, "gbuffers", None) or {}).items() if v is not None}


class FrameSequence:
    """Lazily read frames: len(), indexing and iteration give clss.io.Frame with
    meta {"frame": file number, "files": {buffer: path}} plus sidecar metadata."""

    def __init__(self, entries, channels, jitter, resets, meta, single, scale=None):
        self._entries = entries            # [(number, {buffer: path})]
        self._scale = scale
        self._channels = channels
        self._jitter = jitter              # list of (jx, jy), aligned with entries
        self._resets = resets
        self.meta = meta
        self._single = single
        self._size = None

    def __len__(self):
        return len(self._entries)

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    @property
    def frame_numbers(self):
        return [n for n, _ in self._entries]

    @property
    def files(self):
        """Every file the sequence reads (frames, per-buffer files, references)."""
        return sorted({p for _, files in self._entries for p in files.values()})

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(i)
        number, files = self._entries[i]
        bufs, cache = {}, {}
        for b in ("color", "depth", "motion", "reference") + tuple(GBUFFERS):
            if b in files:
                p = files[b]
                single = self._single or b not in ("color", "depth", "motion")
            elif GBUFFERS.get(b) is not None and GBUFFERS[b].resolution == "render":
                # Render-size G-buffers may be channels of the frame (or colour) file; the
                # search there is by the names that say what they hold (not R,G,B), and
                # finding none is no error unless `channels` named them.
                p, single = files["color"], False
            else:
                continue
            if p not in cache:
                cache[p] = read_exr(p)
            data, names = cache[p]
            optional = b in GBUFFERS and b not in files
            got = _extract(p, data, names, b, self._channels, single, optional)
            if got is not None:
                bufs[b] = got
        h, w = bufs["color"].shape[:2]
        for b in ("depth", "motion"):
            if bufs[b].shape[:2] != (h, w):
                raise InputError(f"{files[b]}: {b} is {bufs[b].shape[1]}x{bufs[b].shape[0]}, "
                                 f"colour ({files['color']}) is {w}x{h}")
        if self._size is None:
            self._size = (h, w, files["color"])
        elif self._size[:2] != (h, w):
            raise InputError(f"{files['color']}: frame is {w}x{h}, the sequence's first "
                             f"frame ({self._size[2]}) is {self._size[1]}x{self._size[0]}")
        gbuffers = {b: bufs[b] for b in GBUFFERS if b in bufs}
        self._check_gbuffer_sizes(gbuffers, files, (h, w), bufs.get("reference"))
        return Frame(index=i, color=bufs["color"], depth=bufs["depth"], motion=bufs["motion"],
                     jitter=self._jitter[i], reset=(i == 0) or number in self._resets,
                     reference=bufs.get("reference"),
                     meta={"frame": number, "files": dict(files), **self.meta},
                     gbuffers=gbuffers)

    def _check_gbuffer_sizes(self, gbuffers, files, hw, reference):
        """Render-size G-buffers are h x w; output-size ones agree with each other, with
        the reference, and with the scale when the sequence knows it."""
        out_hw, out_from = None, None
        if self._scale is not None:
            out_hw, out_from = output_size(hw[0], hw[1], self._scale), f"scale {self._scale:g}"
        elif reference is not None:
            out_hw, out_from = reference.shape[:2], f"the reference ({files['reference']})"
        for b, a in gbuffers.items():
            where = files.get(b, files["color"])
            if GBUFFERS[b].resolution == "render":
                if a.shape[:2] != tuple(hw):
                    raise InputError(f"{where}: {b} is {a.shape[1]}x{a.shape[0]}, colour "
                                     f"({files['color']}) is {hw[1]}x{hw[0]}")
                continue
            if out_hw is None:
                out_hw, out_from = a.shape[:2], f"{where}"
            elif a.shape[:2] != tuple(out_hw):
                raise InputError(f"{where}: {b} is {a.shape[1]}x{a.shape[0]}, the output size "
                                 f"({out_from}) is {out_hw[1]}x{out_hw[0]}")


def read_sequence(source, channels=None, jitter=None, scale=None, reference=None,
                  gbuffers=None):
    """Open a frame sequence (see the module docstring); frames are read on access.

    source: directory, glob, numbered pattern, list of files, or {buffer: pattern} with
      color, depth, motion (and optionally reference and G-buffers).
    channels: {buffer: "A,B,C" or (names)} overriding the channel search.
    jitter: None (sidecar jitter.json / jitter.csv beside the frames, else Halton when
      `scale` is given), a pattern's name (clss.io.jitter.PATTERNS: "halton" needs
      scale; "zero", "2x2", "halton8", "halton16", "r2"), a path to a JSON/CSV sidecar,
      or an (n, 2) array.
    reference: optional numbered pattern of reference images (R, G, B).
    gbuffers: optional {G-buffer name: numbered pattern} of per-buffer G-buffer files
      (a directory source finds ``<name>.NNNN.exr`` beside the frames by itself).
      Render-size G-buffers are also searched among the frame file's channels.
    """
    check_channels(channels)
    unknown = [b for b in (gbuffers or {}) if b not in GBUFFERS]
    if unknown:
        raise InputError(f"gbuffers: unknown G-buffer {unknown[0]!r}; the G-buffers are "
                         f"{', '.join(GBUFFERS)}")
    single = isinstance(source, dict)
    ref_pat = reference
    gb_pats, gb_dir = {}, None
    if single:
        pats = dict(source)
    elif isinstance(source, (list, tuple)):
        pats = {"frame": [os.fspath(p) for p in source]}
    elif os.path.isdir(os.fspath(source)):
        layout = _detect_layout(os.fspath(source))
        if isinstance(layout, dict):
            pats, single = layout, True
        else:
            pats = {"frame": layout[0]}
            ref_pat = ref_pat or layout[1]
        gb_dir = os.fspath(source)
    else:
        pats = {"frame": _without_gbuffer_files(os.fspath(source))}
        gb_dir = os.path.dirname(os.fspath(source)) or "."
    if ref_pat is not None:
        pats["reference"] = ref_pat
    # Per-buffer G-buffer files: named (gbuffers=, or the source dict), or found beside
    # the frames of a directory, glob or numbered pattern (never an error when absent).
    explicit = {b for b in pats if b in GBUFFERS} | set(gbuffers or {})
    pats.update(gbuffers or {})
    if gb_dir is not None and os.path.isdir(gb_dir):
        for b, found in _detect_gbuffer_files(gb_dir).items():
            pats.setdefault(b, found)
    lost = [b for b in (channels or {}) if b in GBUFFERS
            and GBUFFERS[b].resolution == "output" and b not in pats]
    if lost:
        b = lost[0]
        raise InputError(f"channels names {b}, but there are no {b} files (an output-size "
                         f"buffer comes in its own files, {b}.NNNN.exr beside the frames, or "
                         f"read_sequence(gbuffers={{{b!r}: pattern}}))",
                         cli=f"--channels names {b}, but there are no {b} files ({b}.NNNN.exr "
                             "beside the frames)")
    missing = [b for b in ("color", "depth", "motion") if single and b not in pats]
    if missing:
        raise InputError(f"per-buffer source lacks {', '.join(missing)}: {pats}")
    listed = {b: dict(_pattern_files(p)) for b, p in pats.items()}
    key = "color" if single else "frame"
    if not listed[key]:
        raise InputError(f"{_describe(pats[key])}: no files match")
    for b in sorted(explicit):
        if not listed[b]:
            raise InputError(f"{_describe(pats[b])}: no {b} files match")
    entries = []
    for n in sorted(listed[key]):
        files = {}
        for b, found in listed.items():
            if n not in found:
                if b == "reference":
                    continue
                raise InputError(f"{_describe(pats[b])}: no {b} file for frame {n} "
                                 f"(have {listed[key][n]})")
            if b == "frame":
                files.update(color=found[n], depth=found[n], motion=found[n])
            else:
                files[b] = found[n]
        entries.append((n, files))
    numbers = [n for n, _ in entries]
    first_dir = os.path.dirname(os.path.abspath(entries[0][1]["color"]))
    jit, meta = _resolve_jitter(jitter, scale, numbers, first_dir)
    resets = _resets(meta.get("resets", []), meta.get("sidecar", "jitter sidecar"))
    return FrameSequence(entries, channels, jit, resets, meta, single, scale)
