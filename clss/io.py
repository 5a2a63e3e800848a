"""Frame sequences in and out: EXR through OpenImageIO, tone-mapped PNG, jitter sidecars.

Reading (`read_sequence`) accepts
  * one multichannel EXR per frame: a directory, a glob (``shots/*.exr``) or a numbered
    pattern (``shot.%04d.exr``, ``shot.####.exr``); colour, depth and motion are found
    by channel name (`CHANNEL_CANDIDATES`) unless `channels=` names them;
  * one file per buffer: ``{"color": "color.%04d.exr", "depth": "depth.%04d.exr",
    "motion": "motion.%04d.exr"}`` (optionally "reference"); a directory holding
    ``color.*.exr`` / ``depth.*.exr`` / ``motion.*.exr`` is recognised as this layout.
Optional G-buffers (`clss.pipeline.contract.GBUFFERS`: albedo, normal at render size;
albedo_hr, depth_hr, normal_hr at output size) come as channels of the frame file
(render-size ones; `GBUFFER_CANDIDATES` lists the names tried, `channels=` names others)
or as per-buffer files ``<name>.NNNN.exr`` beside the frames (``albedo.0003.exr``,
``depth_hr.0003.exr``; also ``gbuffers={name: pattern}`` or the per-buffer `source`
dict). Frames expose those they have as `Frame.gbuffers` ({name: array}); a G-buffer
the sequence lacks is not an error here (a method that needs it says so).
Pixels outside an EXR's data window are 0; the data window is placed inside the display
window. Jitter comes from a sidecar (``jitter.json`` or ``jitter.csv`` next to the
frames), an explicit file or array, or the Halton(2,3) sequence (`jitter="halton"`
with `scale`). No unit conversion happens here: motion and depth are returned as stored
(the pipeline's `motion_scale` / `depth_inverted` describe them).

Every failure to read raises `InputError` (a ValueError) naming the file, and the
channel or buffer where one is at fault. Writes go to a temporary file in the same
directory and are renamed into place, so frames already written stay valid.
"""
from __future__ import annotations

import csv
import glob
import json
import os
import re
import tempfile

import numpy as np

from .errors import UserError
from .filemode import current_umask, new_file_mode  # noqa: F401 (also clss.io API)
from .pipeline.contract import GBUFFERS, output_size
from .scene import Frame, halton_jitter

try:
    import OpenImageIO as oiio
except ImportError:     # pragma: no cover - OpenImageIO is a hard dependency
    oiio = None


class InputError(UserError):
    """An input file is missing, unreadable, lacks a channel or has the wrong size."""


# Channel names tried in order when `channels=` does not name them.
CHANNEL_CANDIDATES = {
    "color": [("R", "G", "B"), ("rgba.R", "rgba.G", "rgba.B"), ("color.R", "color.G", "color.B"),
              ("Color.R", "Color.G", "Color.B"), ("beauty.R", "beauty.G", "beauty.B"),
              ("Combined.R", "Combined.G", "Combined.B")],
    "depth": [("Z",), ("depth.Z",), ("depth.R",), ("depth.V",), ("depth.Y",), ("Depth.Z",),
              ("Depth.R",), ("D",), ("depth",), ("Depth",)],
    "motion": [("mv.x", "mv.y"), ("mv.X", "mv.Y"), ("mv.R", "mv.G"),
               ("velocity.R", "velocity.G"), ("velocity.x", "velocity.y"),
               ("velocity.X", "velocity.Y"), ("motion.x", "motion.y"), ("motion.R", "motion.G"),
               ("motion.X", "motion.Y"), ("MotionVector.R", "MotionVector.G"),
               ("MotionVectors.R", "MotionVectors.G"), ("motionvector.x", "motionvector.y")],
}
# In a file that holds one buffer only, these generic names are accepted as well.
SINGLE_BUFFER_CANDIDATES = {
    "color": [("R", "G", "B")],
    "depth": [("Z",), ("R",), ("Y",), ("V",)],
    "motion": [("R", "G"), ("x", "y"), ("X", "Y"), ("u", "v"), ("U", "V")],
    "reference": [("R", "G", "B")],
}
# G-buffers: the contract's default names first, then names renderers use for the same
# thing. Only names that say what they hold: Blender's DiffCol and GlossCol are each half
# of the albedo (their sum is; add them before writing, or let
# weights_tools/blender/convert.py do it), and Blender's Normal pass is in world space,
# which the contract's camera-space `normal` is not (docs/input-contract.md section 5).
GBUFFER_CANDIDATES = {
    "albedo": [GBUFFERS["albedo"].exr_channels, ("Albedo.R", "Albedo.G", "Albedo.B"),
               ("albedo.r", "albedo.g", "albedo.b"), ("albedo.X", "albedo.Y", "albedo.Z"),
               ("BaseColor.R", "BaseColor.G", "BaseColor.B"),
               ("basecolor.R", "basecolor.G", "basecolor.B")],
    "normal": [GBUFFERS["normal"].exr_channels, ("normal.x", "normal.y", "normal.z"),
               ("normal.R", "normal.G", "normal.B"), ("Normal.X", "Normal.Y", "Normal.Z"),
               ("Normal.R", "Normal.G", "Normal.B"), ("N.X", "N.Y", "N.Z"),
               ("N.x", "N.y", "N.z")],
    "albedo_hr": [GBUFFERS["albedo_hr"].exr_channels, GBUFFERS["albedo"].exr_channels,
                  ("Albedo.R", "Albedo.G", "Albedo.B")],
    "depth_hr": [GBUFFERS["depth_hr"].exr_channels, ("depth_hr.R",), ("depth.Z",),
                 ("Depth.Z",)],
    "normal_hr": [GBUFFERS["normal_hr"].exr_channels, GBUFFERS["normal"].exr_channels,
                  ("Normal.X", "Normal.Y", "Normal.Z")],
}
CHANNEL_CANDIDATES.update(GBUFFER_CANDIDATES)
_GENERIC_XYZ = [("X", "Y", "Z"), ("x", "y", "z"), ("R", "G", "B")]
SINGLE_BUFFER_CANDIDATES.update({
    "albedo": [("R", "G", "B")], "normal": _GENERIC_XYZ, "albedo_hr": [("R", "G", "B")],
    "depth_hr": [("Z",), ("R",), ("Y",), ("V",)], "normal_hr": _GENERIC_XYZ})
BUFFER_CHANNELS = {"color": 3, "depth": 1, "motion": 2, "reference": 3,
                   **{name: g.channels for name, g in GBUFFERS.items()}}
SIDECARS = ("jitter.json", "jitter.csv")
# Per-buffer G-buffer files: <name>.NNNN.exr or <name>_NNNN.exr, exactly (albedo_hr.* is
# not an albedo file, nor depth_hr.* a depth file).
_GBUFFER_FILE = re.compile(r"^(" + "|".join(sorted(GBUFFERS, key=len, reverse=True))
                           + r")[._](\d+)\.exr$")


# ---------------------------------------------------------------- tone mapping

def tonemap(linear, exposure=1.0):
    """Linear HDR -> display values in [0, 1], float32: colour times `exposure`, the
    ACES filmic curve as fitted by K. Narkowicz (2015), then the sRGB OETF. Used for
    PNGs and for the image metrics. NaN and negative values become 0."""
    x = np.nan_to_num(np.asarray(linear, np.float32) * np.float32(exposure), nan=0.0,
                      posinf=1e4, neginf=0.0)
    x = np.maximum(x, 0)
    y = np.clip((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0, 1)
    return np.where(y <= 0.0031308, 12.92 * y,
                    1.055 * np.power(y, 1 / 2.4) - 0.055).astype(np.float32)


# ---------------------------------------------------------------- writing

def _require_oiio():
    if oiio is None:
        raise RuntimeError("OpenImageIO (python module OpenImageIO) is not installed")


def _atomic_write(path, write):
    """Call write(tmp_path) then rename onto path. The temporary name keeps the
    extension, which is how OpenImageIO picks the format. The file gets the mode a
    plain open() would give (the umask's), not mkstemp's private 0600."""
    path = os.fspath(path)
    d, base = os.path.split(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    ext = os.path.splitext(base)[1]
    fd, tmp = tempfile.mkstemp(prefix="." + base + ".", suffix=".tmp" + ext, dir=d)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, new_file_mode())      # after writing: a writer may recreate the file
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _write_oiio(path, pixels, fmt, names=None, channelformats=None):
    def write(tmp):
        h, w, c = pixels.shape
        spec = oiio.ImageSpec(w, h, c, fmt)
        if names is not None:
            spec.channelnames = tuple(names)
        if channelformats is not None:
            spec.channelformats = tuple(oiio.TypeDesc(f) for f in channelformats)
        if fmt in ("half", "float"):
            spec.attribute("compression", "zip")
        out = oiio.ImageOutput.create(tmp)
        if out is None:
            raise OSError(f"{path}: cannot create ({oiio.geterror()})")
        try:
            if not out.open(tmp, spec) or not out.write_image(pixels):
                raise OSError(f"{path}: cannot write ({out.geterror()})")
        finally:
            out.close()
    _atomic_write(path, write)


def default_channel_names(n):
    return {1: ["Y"], 2: ["x", "y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}.get(
        n, [f"c{i}" for i in range(n)])


def write_exr(path, image, half=True, channel_names=None):
    """Write an h x w or h x w x c image as EXR. `half`: True/False for all channels,
    or one bool per channel (e.g. half colour, float depth). Channel names default to
    Y / x,y / R,G,B / R,G,B,A."""
    _require_oiio()
    a = np.asarray(image, np.float32)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3:
        raise ValueError(f"{path}: expected an h x w or h x w x c image, got shape {a.shape}")
    c = a.shape[2]
    names = list(channel_names) if channel_names is not None else default_channel_names(c)
    if len(names) != c:
        raise ValueError(f"{path}: {len(names)} channel names for {c} channels")
    halves = [bool(half)] * c if isinstance(half, (bool, np.bool_, int)) else list(half)
    if len(halves) != c:
        raise ValueError(f"{path}: {len(halves)} half flags for {c} channels")
    fmts = ["half" if h else "float" for h in halves]
    _write_oiio(path, np.ascontiguousarray(a), "float" if "float" in fmts else "half",
                names, fmts if len(set(fmts)) > 1 else None)


def to_uint8(linear_rgb, exposure=1.0):
    return (tonemap(linear_rgb, exposure) * 255 + 0.5).astype(np.uint8)


def write_png(path, linear_rgb, exposure=1.0):
    """8-bit sRGB PNG of a linear image (h x w or h x w x 3) through `tonemap`."""
    _require_oiio()
    a = np.asarray(linear_rgb, np.float32)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, -1)
    if a.ndim != 3 or a.shape[2] not in (1, 3):
        raise ValueError(f"{path}: expected h x w or h x w x 3, got shape {a.shape}")
    _write_oiio(path, np.ascontiguousarray(to_uint8(a, exposure)), "uint8")


def write_png_ldr(path, display_rgb):
    """8-bit PNG of values already in display space [0, 1] (no tone mapping)."""
    _require_oiio()
    a = np.clip(np.nan_to_num(np.asarray(display_rgb, np.float32)), 0, 1)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, -1)
    _write_oiio(path, np.ascontiguousarray((a * 255 + 0.5).astype(np.uint8)), "uint8")


def write_sample_sequence(frames, directory, half=True, gbuffers=False):
    """Write frames (clss.scene.Frame or dicts with color, depth, motion, jitter and
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


def write_json(path, obj):
    """JSON file, written atomically (a temporary name, then renamed)."""
    def dump(tmp):
        with open(tmp, "w") as fh:
            json.dump(obj, fh, indent=1)
    _atomic_write(path, dump)


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


# ---------------------------------------------------------------- reading

def read_exr(path):
    """(pixels h x w x c float32 over the display window, channel names)."""
    _require_oiio()
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError(f"{path}: no such file")
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise InputError(f"{path}: cannot read ({oiio.geterror()})")
    try:
        spec = inp.spec()
        data = inp.read_image(0, 0, 0, spec.nchannels, "float")
        if data is None:
            raise InputError(f"{path}: cannot read pixels ({inp.geterror()})")
    finally:
        inp.close()
    data = np.asarray(data, np.float32).reshape(spec.height, spec.width, spec.nchannels)
    names = list(spec.channelnames)
    fw, fh = spec.full_width, spec.full_height
    if (spec.x, spec.y, spec.width, spec.height) == (spec.full_x, spec.full_y, fw, fh):
        return data, names
    full = np.zeros((fh, fw, spec.nchannels), np.float32)
    # Data window relative to the display window, clipped to it.
    x0, y0 = spec.x - spec.full_x, spec.y - spec.full_y
    cx0, cy0 = max(x0, 0), max(y0, 0)
    cx1, cy1 = min(x0 + spec.width, fw), min(y0 + spec.height, fh)
    if cx1 > cx0 and cy1 > cy0:
        full[cy0:cy1, cx0:cx1] = data[cy0 - y0:cy1 - y0, cx0 - x0:cx1 - x0]
    return full, names


def _as_names(spec):
    if isinstance(spec, str):
        return tuple(s.strip() for s in spec.split(","))
    return tuple(spec)


def _layer_candidates(names, n):
    """Prefixed R,G,B (or R,G) layers, e.g. 'ViewLayer.Combined.' -> names."""
    comps = ("R", "G", "B")[:n]
    found = []
    for nm in names:
        if nm.endswith("." + comps[0]):
            pre = nm[:-len(comps[0])]
            if all(pre + c in names for c in comps):
                found.append(tuple(pre + c for c in comps))
    return found


def _pick(path, names, buffer, channels, single, optional=False):
    """Channel names of `buffer` in a file with channel list `names`; with `optional`,
    None when the search (not an explicit `channels` entry) finds nothing."""
    n = BUFFER_CHANNELS[buffer]
    if channels and buffer in channels:
        want = _as_names(channels[buffer])
        if len(want) != n:
            what = f"names {len(want)} channels, {buffer} has {n}"
            raise InputError(f"{path}: channels[{buffer!r}] {what}",
                             cli=f"{path}: --channels {buffer}={','.join(want)} {what}")
        for c in want:
            if c not in names:
                raise InputError(f"{path}: channel {c!r} for {buffer} not found "
                                 f"(file has {', '.join(names)})")
        return want
    cands = list(CHANNEL_CANDIDATES.get(buffer, []))
    if single:
        cands += SINGLE_BUFFER_CANDIDATES[buffer]
    for c in cands:
        if all(x in names for x in c):
            return c
    if buffer == "color":
        layers = [c for c in _layer_candidates(names, 3)
                  if re.search(r"combined|colou?r|beauty|rgba", c[0], re.I)]
        if len(layers) == 1:
            return layers[0]
    if single and len(names) == n:
        return tuple(names)
    if optional:
        return None
    tried = "; ".join(",".join(c) for c in cands)
    what = f"{path}: no {buffer} channel found (tried {tried}; file has {', '.join(names)})"
    example = ",".join(names[:n])
    raise InputError(f"{what}; name it with channels={{{buffer!r}: {example!r}}}",
                     cli=f"{what}; name it with --channels '{buffer}={example}'")


def _extract(path, data, names, buffer, channels, single, optional=False):
    sel = _pick(path, names, buffer, channels, single, optional)
    if sel is None:
        return None
    idx = [names.index(c) for c in sel]
    out = data[..., idx]
    return out[..., 0] if BUFFER_CHANNELS[buffer] == 1 else np.ascontiguousarray(out)


def read_frame(path, channels=None, buffers=("color", "depth", "motion")):
    """color, depth, motion (dict) from one multichannel EXR."""
    data, names = read_exr(path)
    return {b: _extract(path, data, names, b, channels, single=False) for b in buffers}


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


class FrameSequence:
    """Lazily read frames: len(), indexing and iteration give clss.scene.Frame with
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
      `scale` is given), "halton" (needs scale), "zero", a path to a JSON/CSV sidecar,
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


def _resets(value, where):
    """The sidecar's `resets`: a list of frame numbers."""
    try:
        if isinstance(value, (str, bytes)) or not all(float(r) == int(r) for r in value):
            raise ValueError
        return {int(r) for r in value}
    except (TypeError, ValueError):
        raise InputError(f"{where}: 'resets' must be a list of frame numbers, got {value!r}") from None


def check_channels(channels):
    """Refuse a `channels` mapping that names a buffer there is none of (a typo such as
    'colour' would otherwise be ignored and the channel search would pick another)."""
    if not channels:
        return
    unknown = [k for k in channels if k not in BUFFER_CHANNELS]
    if unknown:
        known = ", ".join(BUFFER_CHANNELS)
        raise InputError(f"channels: unknown buffer {unknown[0]!r}; the buffers are {known}",
                         cli=f"--channels: unknown buffer {unknown[0]!r}; the buffers are {known} "
                             "(e.g. 'color=R,G,B;depth=Z;motion=mv.x,mv.y')")


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
