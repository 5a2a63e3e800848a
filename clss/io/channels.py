"""Which channels of an EXR hold which buffer: the names tried for colour, depth, motion,
the reference and the G-buffers (`CHANNEL_CANDIDATES`, `GBUFFER_CANDIDATES`, and the
generic names a one-buffer file may use, `SINGLE_BUFFER_CANDIDATES`), the `channels=`
mapping that names them instead (`check_channels`), and the pick itself."""
from __future__ import annotations

import re

import numpy as np

from ..pipeline.contract import GBUFFERS
from .errors import InputError
from .images import read_exr


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
