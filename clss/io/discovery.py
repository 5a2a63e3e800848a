"""Which files are the frames: a directory (one multichannel EXR per frame, or color.* /
depth.* / motion.* files), a glob, a numbered pattern or a list of files, each file
numbered by its own name; the per-buffer G-buffer files beside the frames. Stray files
and frames given twice are refused by name."""
from __future__ import annotations

import glob
import os
import re

from ..pipeline.contract import GBUFFERS
from .errors import InputError

# Per-buffer G-buffer files: <name>.NNNN.exr or <name>_NNNN.exr, exactly (albedo_hr.* is
# not an albedo file, nor depth_hr.* a depth file).
_GBUFFER_FILE = re.compile(r"^(" + "|".join(sorted(GBUFFERS, key=len, reverse=True))
                           + r")[._](\d+)\.exr$")


_NUMBERED = re.compile(r"%0?(\d*)d|#+|\{frame(?::0?(\d+)d)?\}")


def _pattern_files(pattern):
    """Sorted [(frame number, path)] of a numbered pattern, a glob or a list of paths;
    every file's number is its own (never its position), see `_number_files`."""
    if isinstance(pattern, (list, tuple)):
        dirs = {os.path.dirname(os.fspath(p)) for p in pattern}
        return _number_files(sorted(pattern), dirs.pop() if len(dirs) == 1 else "the frame list")
    pattern = os.fspath(pattern)
    m = _NUMBERED.search(pattern)
    if not m:
        return _number_files(sorted(glob.glob(pattern)), pattern)
    head, tail = pattern[:m.start()], pattern[m.end():]
    rx = re.compile(re.escape(head) + r"(-?\d+)" + re.escape(tail) + "$")
    out = []
    for p in glob.glob(glob.escape(head) + "*" + glob.escape(tail)):
        mm = rx.match(p)
        if mm:
            out.append((int(mm.group(1)), p))
    _refuse_duplicates(out, pattern)
    return sorted(out)


_LAST_NUMBER = re.compile(r"(\d+)(?=\D*$)")


def _number_files(files, where):
    """[(number, path)] for files that share one numbering pattern (name = head,
    digits, tail; the number is the last run of digits). Stray files (another head or
    tail, or no number) are refused with their names: silently taking them as frames
    would renumber every later output against its input. A single file needs no
    number (frame 0)."""
    if len(files) == 1 and not _LAST_NUMBER.search(os.path.basename(files[0])):
        return [(0, files[0])]
    groups, unnumbered = {}, []
    for p in files:
        d, base = os.path.split(p)
        m = _LAST_NUMBER.search(base)
        if m is None:
            unnumbered.append(p)
            continue
        key = (d, base[:m.start()], base[m.end():])
        groups.setdefault(key, []).append((int(m.group(1)), p))
    if not groups:
        return []
    main = max(groups, key=lambda k: len(groups[k]))
    strays = unnumbered + [p for k, g in groups.items() if k != main for _, p in g]
    if strays:
        d, head, tail = main
        widths = {len(m) for m in (_LAST_NUMBER.search(os.path.basename(p)).group(1)
                                   for _, p in groups[main])}
        width = widths.pop() if len(widths) == 1 else 1
        example = os.path.join(d, f"{head}%0{width}d{tail}" if width > 1 else f"{head}%d{tail}")
        shown = ", ".join(os.path.basename(p) for p in sorted(strays)[:6])
        more = f" and {len(strays) - 6} more" if len(strays) > 6 else ""
        raise InputError(f"{where}: {len(strays)} file(s) do not follow the frames' numbering "
                         f"{head}{'#' * width}{tail} ({len(groups[main])} frames): {shown}{more}; move them "
                         f"away, or name the frames exactly with a pattern such as {example!r}")
    out = sorted(groups[main])
    _refuse_duplicates(out, where)
    return out


def _refuse_duplicates(numbered, where):
    seen = {}
    for n, p in numbered:
        if n in seen:
            raise InputError(f"{where}: frame {n} is given twice ({os.path.basename(seen[n])} and "
                             f"{os.path.basename(p)}); keep one")
        seen[n] = p


def _detect_layout(directory):
    """{buffer: [files]} if `directory` holds color.* / depth.* / motion.* EXRs, else
    ([frame files], [reference files] or None) for one multichannel EXR per frame."""
    per = {}
    for b, stems in (("color", ("color", "colour", "beauty")), ("depth", ("depth",)),
                     ("motion", ("motion", "mv", "velocity")), ("reference", ("reference",))):
        for s in stems:
            hits = [p for p in glob.glob(os.path.join(glob.escape(directory), s + "[._]*[0-9].exr"))
                    if not _is_gbuffer_file(p)]
            if hits:
                per[b] = sorted(hits)
                break
    if all(b in per for b in ("color", "depth", "motion")):
        return per
    refs = set(per.get("reference", []))
    files = [p for p in glob.glob(os.path.join(glob.escape(directory), "*.exr"))
             if p not in refs and not _is_gbuffer_file(p)]
    if not files:
        raise InputError(f"{directory}: no .exr files")
    return sorted(files), (sorted(refs) if refs else None)


def _is_gbuffer_file(path):
    return _GBUFFER_FILE.match(os.path.basename(path)) is not None


def _detect_gbuffer_files(directory):
    """{G-buffer name: [files]} of the per-buffer G-buffer files in `directory`."""
    found = {}
    for p in glob.glob(os.path.join(glob.escape(directory), "*.exr")):
        m = _GBUFFER_FILE.match(os.path.basename(p))
        if m:
            found.setdefault(m.group(1), []).append(p)
    return {k: sorted(v) for k, v in found.items()}


def _without_gbuffer_files(pattern):
    """A glob source (``shots/*.exr``) less the per-buffer G-buffer files it matches
    (``albedo.0003.exr`` beside the frames is not a frame); the pattern itself when it
    matches none of them (or is a numbered pattern, which selects exactly)."""
    if _NUMBERED.search(pattern):
        return pattern
    hits = glob.glob(pattern)
    if not any(_is_gbuffer_file(p) for p in hits):
        return pattern
    return sorted(p for p in hits if not _is_gbuffer_file(p))


def _describe(pattern):
    """A pattern, or a list of files by its first one, for messages."""
    if isinstance(pattern, (list, tuple)):
        if not pattern:
            return "the frame list"
        return f"{pattern[0]} and {len(pattern) - 1} more" if len(pattern) > 1 else str(pattern[0])
    return str(pattern)
