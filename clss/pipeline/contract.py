"""The CLSS frame input contract: validation and conventions (docs/input-contract.md).

Layout of one frame as the caller hands it in (render resolution h x w):

    color     h x w x 3   float16/float32, linear (HDR or LDR), divided by `exposure`
    depth     h x w       float16/float32 in [0, 1]; reversed-Z (near = 1) by default
    motion    h x w x 2   render pixels, previous position = p + motion * motion_scale, +y down
    jitter    2 floats    render pixels in [-0.5, 0.5]; sample (i, j) was taken at
                          (j + 0.5 + jx, i + 0.5 + jy)
    reactive  h x w       optional, in [0, 1]

Non-finite policy: by default any NaN/Inf refuses the frame (FrameInputError naming the
input, the count and the first bad pixel), because one NaN blended into the history
stays there for every later frame.  `sanitize=True` instead replaces non-finite colour
by 0, depth by the far plane, motion by 0 (static) and reactive by 0, and reports the
counts under "sanitized".  Jitter is never sanitized: a wrong jitter silently blurs
everything.  Out-of-range depth/reactive/jitter is always refused.  Negative colour is
accepted and clamped to 0 by the transfer function.

Internal conventions (`to_internal`, what the frame graphs consume): NCHW float32,
colour / exposure, depth reversed-Z (near = 1, far = 0, so "nearest" is max and zero
padding is "far"), motion multiplied by motion_scale (render pixels).
"""
from __future__ import annotations

import dataclasses
import functools
import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ..errors import UserError

ACCEPTED_DTYPES = (np.float16, np.float32)

# SMPTE ST 2084 (PQ) constants, exact rationals from the standard.
PQ_M1 = 2610.0 / 16384.0          # 0.1593017578125
PQ_M2 = 2523.0 / 4096.0 * 128.0   # 78.84375
PQ_C1 = 3424.0 / 4096.0           # 0.8359375
PQ_C2 = 2413.0 / 4096.0 * 32.0    # 18.8515625
PQ_C3 = 2392.0 / 4096.0 * 32.0    # 18.6875
PQ_PEAK_NITS = 10000.0
# Linear 1.0 = 100 nits (SDR reference white, ITU-R BT.2408 uses 203 for HDR graphics
# white; 100 keeps LDR content in the well-resolved lower half of the PQ curve and
# linear 100.0 at the PQ peak).  Values above 10000 nits clip.
PQ_NITS = 100.0


class FrameInputError(UserError):
    """A frame input that breaks the contract; the message names the input."""


def output_size(h: int, w: int, scale) -> tuple[int, int]:
    """(H, W) = (round(h*scale), round(w*scale)), halves rounded up (not to even)."""
    s = float(scale)
    if not math.isfinite(s) or s < 1.0:
        raise FrameInputError(f"scale: expected a finite number >= 1, got {scale!r}")
    if int(h) < 1 or int(w) < 1:
        raise FrameInputError(f"render_size: expected positive sizes, got {h}x{w}")
    return int(math.floor(h * s + 0.5)), int(math.floor(w * s + 0.5))


def halton(index: int, base: int) -> float:
    """Radical inverse of `index` in `base` (halton(0, b) = 0)."""
    f, r, i = 1.0, 0.0, int(index)
    while i > 0:
        f /= base
        r += f * (i % base)
        i //= base
    return r


def jitter_phase_count(scale) -> int:
    """ceil(8 * scale^2), the FSR2 phase count (32 at scale 2)."""
    s = float(scale)
    # The epsilon keeps 8*1.5^2 = 18.000000000000004-style float noise from adding a phase.
    return int(math.ceil(8.0 * s * s - 1e-9))


def jitter_at(index: int, scale) -> tuple[float, float]:
    """(jx, jy) in [-0.5, 0.5) render pixels for frame `index`, as Python floats (the
    sample scene traces at these positions): Halton(2,3) starting at 1 (as FSR2),
    cycling with length jitter_phase_count(scale)."""
    k = int(index) % jitter_phase_count(scale) + 1
    return (halton(k, 2) - 0.5, halton(k, 3) - 0.5)


def jitter_sequence(scale) -> np.ndarray:
    """[n, 2] float32 (jx, jy) in render pixels: Halton(2,3) from index 1, minus 0.5."""
    n = jitter_phase_count(scale)
    return np.array([jitter_at(i, scale) for i in range(n)], np.float32)


def jitter_for_frame(frame_index: int, scale) -> np.ndarray:
    seq = jitter_sequence(scale)
    return seq[int(frame_index) % len(seq)]


def pq_encode(linear, nits: float = PQ_NITS) -> np.ndarray:
    """Linear (1.0 = `nits` cd/m^2) -> PQ code value in [0, 1]; negatives clamp to 0."""
    y = np.clip(np.asarray(linear, np.float32) * np.float32(nits / PQ_PEAK_NITS), 0.0, 1.0)
    ym = np.power(y, np.float32(PQ_M1))
    return np.power((PQ_C1 + PQ_C2 * ym) / (1.0 + PQ_C3 * ym), np.float32(PQ_M2)).astype(np.float32)


def pq_decode(encoded, nits: float = PQ_NITS) -> np.ndarray:
    """PQ code value -> linear (1.0 = `nits`); the input is clamped to [0, 1] first."""
    ep = np.power(np.clip(np.asarray(encoded, np.float32), 0.0, 1.0), np.float32(1.0 / PQ_M2))
    y = np.power(np.maximum(ep - PQ_C1, 0.0) / (PQ_C2 - PQ_C3 * ep), np.float32(1.0 / PQ_M1))
    return (y * np.float32(PQ_PEAK_NITS / nits)).astype(np.float32)


def _fail(name, expected, got):
    raise FrameInputError(f"{name}: expected {expected}, got {got}")


def _check_array(name, a, shape_tail, hw):
    if not isinstance(a, np.ndarray):
        _fail(name, "a numpy array", type(a).__name__)
    if a.dtype not in ACCEPTED_DTYPES:
        _fail(name, "dtype float16 or float32", f"{a.dtype} (convert explicitly; integer "
              "and float64 inputs are refused so a wrong unit cannot slip through)")
    layout = "h x w" + "".join(f" x {c}" for c in shape_tail)
    if hw is None:
        _fail(name, f"a {layout} array", f"shape {a.shape}")
    want = tuple(hw) + tuple(shape_tail)
    got = a.shape
    # Single-channel planes may come as h x w x 1.
    if not shape_tail and a.ndim == 3 and a.shape[2] == 1:
        got = a.shape[:2]
    if tuple(got) != want:
        _fail(name, f"shape {want} ({layout})", f"{a.shape}")
    return a.reshape(want)


def _where(mask):
    """'(row=r, col=c[, channel=k])' of the first True in C order."""
    idx = np.unravel_index(int(np.argmax(mask)), mask.shape)
    s = f"row={idx[0]}, col={idx[1]}"
    return s + (f", channel={idx[2]}" if len(idx) > 2 else "")


def _nonfinite(name, a, sanitize, fill, report):
    bad = ~np.isfinite(a)
    n = int(bad.sum())
    if n == 0:
        return a
    if not sanitize:
        what = (f"{name}: expected finite values, got {n} non-finite (NaN/Inf) of {a.size}; "
                f"first at pixel ({_where(bad)})")
        raise FrameInputError(f"{what}; pass sanitize=True to replace them",
                              cli=f"{what}; pass --sanitize to replace them")
    a = a.copy()
    a[bad] = fill
    report[name] = n
    return a


def _range(name, a, lo, hi):
    bad = (a < lo) | (a > hi)
    n = int(bad.sum())
    if n:
        first = _where(bad)
        v = float(a[np.unravel_index(int(np.argmax(bad)), bad.shape)])
        raise FrameInputError(f"{name}: expected values in [{lo}, {hi}], got {n} outside; "
                              f"first at pixel ({first}) = {v!r}")


def validate_frame(color, depth, motion, jitter, reactive=None, *, render_size=None,
                   sanitize: bool = False, depth_inverted: bool = True,
                   values: bool = True) -> dict:
    """Check one frame against the contract; return float32 copies in the caller's layout.

    Returns {"color", "depth", "motion", "jitter", "reactive" (None if not given),
    "sanitized": {input: count replaced}}.  `render_size` = (h, w) when the caller
    has fixed it; otherwise the colour's shape defines it.  `depth_inverted` only tells
    sanitize where "far" is (0 when inverted, 1 otherwise).

    values=False checks the layout only (shapes, dtypes, jitter) and leaves the values
    (finite, depth and reactive in [0, 1]) to the caller: clss.Upscaler's prepare kernel
    checks them on the device for both of its paths, and calls this again with
    values=True only to explain a frame it refused.
    """
    if render_size is not None:
        hw = (int(render_size[0]), int(render_size[1]))
    elif isinstance(color, np.ndarray) and color.ndim == 3:
        hw = color.shape[:2]
    else:
        hw = None
    color = _check_array("color", color, (3,), hw)
    depth = _check_array("depth", depth, (), hw)
    motion = _check_array("motion", motion, (2,), hw)
    if reactive is not None:
        reactive = _check_array("reactive", reactive, (), hw)

    jitter = check_jitter(jitter)

    report = {}
    out = {}
    if not values:
        out.update(color=color.astype(np.float32, copy=False),
                   depth=depth.astype(np.float32, copy=False),
                   motion=motion.astype(np.float32, copy=False),
                   reactive=None if reactive is None else reactive.astype(np.float32, copy=False),
                   jitter=jitter, sanitized=report)
        return out
    far = 0.0 if depth_inverted else 1.0
    out["color"] = _nonfinite("color", color.astype(np.float32), sanitize, 0.0, report)
    out["depth"] = _nonfinite("depth", depth.astype(np.float32), sanitize, far, report)
    out["motion"] = _nonfinite("motion", motion.astype(np.float32), sanitize, 0.0, report)
    _range("depth", out["depth"], 0.0, 1.0)
    if reactive is not None:
        r = _nonfinite("reactive", reactive.astype(np.float32), sanitize, 0.0, report)
        _range("reactive", r, 0.0, 1.0)
        out["reactive"] = r
    else:
        out["reactive"] = None
    out["jitter"] = jitter
    out["sanitized"] = report
    return out


def check_jitter(jitter) -> np.ndarray:
    """(jx, jy) as float32, refused unless 2 finite floats in [-0.5, 0.5] render pixels."""
    try:
        j = np.asarray(jitter, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        _fail("jitter", "2 floats (jx, jy) in render pixels", repr(jitter))
    if j.shape != (2,):
        _fail("jitter", "2 floats (jx, jy) in render pixels", f"{j.size} values")
    if not np.all(np.isfinite(j)) or np.any(np.abs(j) > 0.5):
        _fail("jitter", "2 finite floats in [-0.5, 0.5] render pixels", f"{j.tolist()}")
    return j.astype(np.float32)


def check_motion_scale(motion_scale) -> np.ndarray:
    """motion_scale as float32 (sx, sy), checked as Contract checks it."""
    return np.asarray(Contract(motion_scale=motion_scale).motion_scale, np.float32)


def check_exposure(exposure) -> float:
    """exposure as a float, checked as Contract checks it."""
    return Contract(exposure=exposure).exposure


# ---------------------------------------------------------------- the caller's conventions
# What a method does with each of the Contract's parameters (MethodSpec.conventions, the
# table of docs/input-contract.md section 6): its frame step takes the value (HONOURS); the
# shared template or the method turns it into what the frame step takes (CONVERTS); the
# method reads no input the parameter describes, so no value changes its output
# (NOT_READ); or only the default can be taken (CANNOT: any other value is refused with
# an error naming the method and the parameter, never dropped).
HONOURS, CONVERTS, NOT_READ, CANNOT = "honours", "converts", "not read", "cannot honour"
HANDLINGS = (HONOURS, CONVERTS, NOT_READ, CANNOT)


class ContractError(UserError):
    """A contract parameter with a wrong value, given twice, or with a value that a
    method cannot honour; the message names the parameter (and the method)."""


@dataclass(frozen=True)
class Contract:
    """The caller's conventions for its frames (docs/input-contract.md), one object for
    every method: clss.Upscaler(method=NAME, contract=clss.Contract(...)), or the same
    parameters as keywords. Validated once, here; each error names the parameter.

    depth_inverted  True: reversed-Z depth (near = 1, far = 0); False: standard Z. Also
                    the convention of the G-buffer depth_hr.
    motion_scale    (sx, sy): the stored motion times these is render pixels pointing to
                    the previous position, +y down ((W, H) for UV motion, (-1, -1) for
                    current - previous).
    jitter_scale    (sx, sy): the given jitter times these is render pixels, the sample's
                    offset from the pixel centre, +y down ((-1, -1) for FSR2's and DLSS's
                    jitter offsets; (W, H) for jitter in UV units).
    hdr             True: linear HDR colour through the PQ transfer; False: LDR in [0, 1],
                    no transfer (clamped in and out).
    exposure        the colour was rendered with this exposure (> 0): divided on the way
                    in, multiplied on the way out.
    nits            cd/m2 of linear 1.0 (> 0), the PQ transfer's scale (default 100).
    """
    depth_inverted: bool = True
    motion_scale: tuple = (1.0, 1.0)
    jitter_scale: tuple = (1.0, 1.0)
    hdr: bool = True
    exposure: float = 1.0
    nits: float = PQ_NITS

    # The command-line flag of each parameter (clss upscale), for messages.
    FLAGS = {"depth_inverted": "--depth-standard", "motion_scale": "--motion-scale",
             "jitter_scale": "--jitter-scale", "hdr": "--ldr", "exposure": "--exposure",
             "nits": "--nits"}
    # The frame inputs each parameter describes: a method that reads none of them takes
    # any value of it unchanged (NOT_READ).
    DESCRIBES = {"depth_inverted": ("depth", "depth_hr"), "motion_scale": ("motion",),
                 "jitter_scale": ("jitter",), "hdr": ("color",), "exposure": ("color",),
                 "nits": ("color",)}

    def __post_init__(self):
        set_ = functools.partial(object.__setattr__, self)
        for name in ("depth_inverted", "hdr"):
            v = getattr(self, name)
            if not isinstance(v, (bool, np.bool_)):
                self._refuse(name, "True or False", v)
            set_(name, bool(v))
        set_("motion_scale", self._pair("motion_scale", "2 finite numbers (sx, sy)"))
        set_("jitter_scale", self._pair("jitter_scale", "2 finite non-zero numbers (sx, sy)",
                                        nonzero=True))
        for name in ("exposure", "nits"):
            v = getattr(self, name)
            try:
                f = float(v)
            except (TypeError, ValueError):
                f = math.nan
            if isinstance(v, (bool, np.bool_)) or not math.isfinite(f) or f <= 0:
                self._refuse(name, "a finite number > 0", v)
            set_(name, f)

    @classmethod
    def _refuse(cls, name, expected, got):
        raise ContractError(f"{name}: expected {expected}, got {got!r}",
                            cli=f"{cls.FLAGS[name]}: expected {expected}, got {got!r}")

    def _pair(self, name, expected, nonzero=False):
        v = getattr(self, name)
        try:
            m = np.asarray(v, np.float64).reshape(-1)
        except (TypeError, ValueError):
            m = np.full(1, np.nan)
        if m.shape != (2,) or not np.all(np.isfinite(m)) or (nonzero and np.any(m == 0)):
            self._refuse(name, expected, v)
        return (float(m[0]), float(m[1]))

    @classmethod
    def names(cls) -> tuple:
        """The parameters, in the order of the fields."""
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def of(cls, contract=None, **params) -> "Contract":
        """The contract of a caller that gave `contract` (a Contract, or None) or its
        parameters as keywords (not both: a parameter given twice is refused)."""
        if contract is None:
            return cls(**params)
        if not isinstance(contract, cls):
            raise ContractError(f"contract: expected a clss.Contract, got "
                                f"{type(contract).__name__}")
        if params:
            raise ContractError(f"contract: given as contract= and as keyword(s) "
                                f"{', '.join(params)}; give one or the other")
        return contract

    def changed(self) -> dict:
        """{parameter: value} of those that differ from the default."""
        base = Contract()
        return {n: getattr(self, n) for n in self.names() if getattr(self, n) != getattr(base, n)}

    def jitter(self, jitter) -> np.ndarray:
        """The caller's jitter in the contract's units (render pixels, the sample's offset
        from the pixel centre): times jitter_scale, then checked (check_jitter)."""
        if self.jitter_scale == (1.0, 1.0):
            return check_jitter(jitter)
        try:
            j = np.asarray(jitter, np.float64).reshape(-1)
            scaled = j * np.asarray(self.jitter_scale) if j.shape == (2,) else jitter
        except (TypeError, ValueError):
            scaled = jitter
        try:
            return check_jitter(scaled)
        except FrameInputError as e:
            raise FrameInputError(f"{e} (the jitter given times jitter_scale "
                                  f"{self.jitter_scale})") from None


def to_reversed_z(depth: np.ndarray, depth_inverted: bool) -> np.ndarray:
    """Internal depth is reversed-Z (near = 1, far = 0); standard Z becomes 1 - d."""
    return depth if depth_inverted else (1.0 - depth).astype(np.float32)


def apply_motion_scale(motion: np.ndarray, motion_scale) -> np.ndarray:
    """Motion in render pixels pointing to the previous position (+y down)."""
    m = check_motion_scale(motion_scale)
    if np.all(m == 1.0):
        return motion
    return (motion * m).astype(np.float32)


def to_internal(frame: dict, *, depth_inverted: bool = True, motion_scale=(1.0, 1.0),
                exposure: float = 1.0) -> dict:
    """validate_frame's dict -> NCHW float32 arrays in internal conventions.

    Keys: color [1,3,h,w] (/ exposure), depth [1,1,h,w] (reversed-Z), motion [1,2,h,w]
    (render pixels, scaled), jitter [2], reactive [1,1,h,w] (zeros when absent).
    """
    e = check_exposure(exposure)
    color = frame["color"] if e == 1.0 else frame["color"] * np.float32(1.0 / e)
    depth = to_reversed_z(frame["depth"], depth_inverted)
    motion = apply_motion_scale(frame["motion"], motion_scale)
    h, w = depth.shape
    reactive = frame.get("reactive")
    if reactive is None:
        reactive = np.zeros((h, w), np.float32)
    return {
        "color": np.ascontiguousarray(color.transpose(2, 0, 1)[None], np.float32),
        "depth": np.ascontiguousarray(depth[None, None], np.float32),
        "motion": np.ascontiguousarray(motion.transpose(2, 0, 1)[None], np.float32),
        "jitter": np.asarray(frame["jitter"], np.float32).reshape(2),
        "reactive": np.ascontiguousarray(reactive[None, None], np.float32),
    }


# ---------------------------------------------------------------- G-buffers
# Optional per-frame inputs beyond colour, depth, motion and jitter (issue 19). A method
# declares the ones it needs (and the ones it can use) by these names; clss.Upscaler.step
# takes them as keywords (`step(..., albedo=a, normal=n)`), `.npz` sequences
# (weights_tools/DATA.md) under the same keys, EXR sequences (clss.io) as channels or
# per-buffer files. docs/input-contract.md section 5 is the long form of this table.
#
# Not a G-buffer: NSRD's occlusion-aware motion mask. It comes from a reprojected-depth
# test against the previous frame's depth, which the method keeps itself (it has seen
# that frame), so it needs no input beyond depth and motion.

GBUFFER_RESOLUTIONS = ("render", "output")


@dataclass(frozen=True)
class GBuffer:
    """One optional frame input: its name (the Python keyword, the `.npz` key, the
    `--channels` key and the stem of its per-buffer EXR files), the resolution it comes
    at ("render": h x w like colour; "output": H x W like the upscaled frame), its
    channel count, the EXR channel names it is found under by default, and what it is."""
    name: str
    resolution: str
    channels: int
    exr_channels: tuple
    meaning: str

    @property
    def layout(self) -> str:
        hw = "h x w" if self.resolution == "render" else "H x W"
        return hw + (f" x {self.channels}" if self.channels > 1 else "")

    def shape(self, render_size, output_size) -> tuple:
        """The array shape this buffer must have for a frame of these sizes."""
        hw = render_size if self.resolution == "render" else output_size
        hw = (int(hw[0]), int(hw[1]))
        return hw + ((self.channels,) if self.channels > 1 else ())


def _gb(name, resolution, channels, exr, meaning):
    return name, GBuffer(name, resolution, channels, tuple(exr), meaning)


# Order: render resolution first, then output resolution; a method's message lists
# missing inputs in this order.
GBUFFERS = OrderedDict([
    _gb("albedo", "render", 3, ("albedo.R", "albedo.G", "albedo.B"),
        "material component: diffuse + specular albedo (or a pre-integrated BRDF), "
        "linear, >= 0; 0 where nothing was hit (sky)"),
    _gb("normal", "render", 3, ("normal.X", "normal.Y", "normal.Z"),
        "unit surface normal in camera space (+x right, +y up, +z toward the camera); "
        "0 where nothing was hit (sky)"),
    _gb("albedo_hr", "output", 3, ("albedo_hr.R", "albedo_hr.G", "albedo_hr.B"),
        "the albedo at output resolution, one sample at each output pixel centre "
        "(unjittered)"),
    _gb("depth_hr", "output", 1, ("depth_hr.Z",),
        "depth at output resolution, same convention as depth (reversed-Z by default), "
        "one sample at each output pixel centre"),
    _gb("normal_hr", "output", 3, ("normal_hr.X", "normal_hr.Y", "normal_hr.Z"),
        "the normal at output resolution, one sample at each output pixel centre"),
])


class MissingInputError(FrameInputError):
    """A method needs a G-buffer the frame does not carry; the message names the method,
    every missing input, and where each is read from."""


def gbuffer_sources(name: str, cli: bool = False) -> str:
    """Where G-buffer `name` is read from, in words (for messages): the Python keyword,
    the .npz key, the EXR channels or per-buffer file and the --channels flag."""
    g = GBUFFERS[name]
    names = ",".join(g.exr_channels)
    if g.resolution == "render":
        exr = (f"EXR channels {names} in each frame file (or a per-buffer file "
               f"{name}.NNNN.exr)")
    else:
        exr = (f"a per-buffer file {name}.NNNN.exr at output resolution (channels "
               f"{names}, or {','.join(_GENERIC[g.channels])})")
    flag = f"clss upscale --channels '{name}={','.join(_EXAMPLE[g.channels])}'"
    if cli:
        return f"{name} ({g.layout}): {exr}, or name its channels with {flag[13:]}"
    return f"{name} ({g.layout}): keyword {name}=, .npz key '{name}', {exr}, or {flag}"


# Placeholder channel names in messages, and the generic names a per-buffer file may use.
_EXAMPLE = {1: ("A",), 3: ("A", "B", "C")}
_GENERIC = {1: ("Z",), 3: ("R", "G", "B")}


def _gb_array(name, a, want):
    """One G-buffer checked for type, dtype and shape; returned as float32 of shape want."""
    if not isinstance(a, np.ndarray):
        _fail(name, "a numpy array", type(a).__name__)
    if a.dtype not in ACCEPTED_DTYPES:
        _fail(name, "dtype float16 or float32", f"{a.dtype} (convert explicitly; integer "
              "and float64 inputs are refused so a wrong unit cannot slip through)")
    got = a.shape
    # One-channel buffers may come as H x W x 1, like depth.
    if len(want) == 2 and a.ndim == 3 and a.shape[2] == 1:
        got = a.shape[:2]
    if tuple(got) != tuple(want):
        g = GBUFFERS[name]
        res = "render" if g.resolution == "render" else "output"
        _fail(name, f"shape {tuple(want)} ({g.layout}, {res} resolution)", f"{a.shape}")
    return np.ascontiguousarray(a.reshape(want), np.float32)


def validate_gbuffers(method: str, needs: tuple, optional: tuple, given: dict,
                      render_size, output_size, *, sanitize: bool = False,
                      report: dict | None = None) -> dict:
    """The G-buffers `method` needs (`needs`) and can use (`optional`) out of `given`
    ({name: array}; None counts as absent), checked against the contract: returns
    {name: C-contiguous float32 array of GBUFFERS[name].shape(...)} for those present.

    Raises MissingInputError naming the method, every missing needed buffer and where
    each comes from; FrameInputError naming the buffer for a wrong type, dtype or shape,
    or non-finite values (with sanitize=True these become 0 instead: 0 albedo and 0
    normal are what the contract writes where nothing was hit, and 0 depth is far in
    reversed-Z; `report`, a dict, receives {name: count replaced}, as validate_frame's
    "sanitized").
    A buffer given that the method neither needs nor uses is left out of the result
    without an error (the caller may warn). Values are not range-checked: albedo may
    exceed 1 (specular), and a depth_hr in standard Z is the caller's convention.
    """
    needs, optional = tuple(needs or ()), tuple(optional or ())
    unknown = [n for n in needs + optional if n not in GBUFFERS]
    if unknown:
        raise ValueError(f"{method}: unknown G-buffer name(s) {', '.join(unknown)}; the "
                         f"names are {', '.join(GBUFFERS)}")
    given = {k: v for k, v in (given or {}).items() if v is not None}
    missing = [n for n in GBUFFERS if n in needs and n not in given]
    if missing:
        names = ", ".join(missing)
        raise MissingInputError(
            f"method {method!r} needs {names}, which the frame does not carry; pass "
            + "; ".join(gbuffer_sources(n) for n in missing),
            cli=f"method {method!r} needs {names}, which the input does not carry; give "
                + "; ".join(gbuffer_sources(n, cli=True) for n in missing))
    out = {}
    report = {} if report is None else report
    for name in GBUFFERS:
        if name not in given or (name not in needs and name not in optional):
            continue
        a = _gb_array(name, given[name], GBUFFERS[name].shape(render_size, output_size))
        out[name] = _nonfinite(name, a, sanitize, 0.0, report)
    return out

