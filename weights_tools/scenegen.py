"""Varied animated scenes with classification labels: the training data of CLSS.

Each sequence is a random scene rendered by clss's numpy ray caster (clss/scene.py) and
written as one .npz in the format of weights_tools/DATA.md. A seed fixes everything:
the same (seed, sequence index, size, frames, scale, spp) gives the same arrays.

What is randomised per sequence (`SceneSpec.random`):
  * thin geometry: fences of poles and sub-pixel wires (along x or receding along z),
    alpha-tested cut-out panels (slats, diagonal lattices, chain-link mesh, foliage-like
    leaf cells), some of them moving or turning;
  * solid objects (spheres, boxes) with solid textures (stripes, checkers) at random
    frequencies (0.5 to 40 cycles per metre) and orientations, random specular
    highlights, moving (with bounces) and turning: disocclusions in every direction;
  * emissive lamps (HDR 3-40) that are steady, blink or pulse; the sun moves, dims or
    flickers (moving shadows), its colour and the ambient term vary;
  * the ground's texture colours, scale (tiles of 1 to 8 m) and striped path, the sky's
    colours (clear, dusk, overcast) and brightness; a backdrop wall and a textured floor
    slab, sometimes;
  * the camera: static, pan, truck, dolly, orbit or a mix, at random speeds, and a cut
    (a second camera path, `reset`) in about a third of the sequences;
  * jitter: one of the patterns engines send, drawn from --jitter-mix
    (weights_tools/jitter_mix.py: zero, 2x2, Halton 8 / 16 / 32 phases, R2, mirrored,
    from a random phase; meta["content"]["jitter"] records the draw). Its own random
    stream: the same seed gives the same content whatever the mix.

Per frame (DATA.md): colour (one point sample per render pixel at the jittered
position), reversed-Z depth, motion (render pixels, prev = p + motion) and jitter from
clss.scene's `_trace`; the reference is clss.scene's stratified box-filtered render at
output resolution (`spp` samples per pixel); the labels follow these rules
(LABEL_RULES_VERSION), all at output resolution:

Ghosting (label_ghost; 0 visibility, 1 shading, 2 none), from one ray through each
output pixel centre. Its hit point P on primitive k (ground and sky count as
primitives) is reprojected with the previous frame's object transform and camera to
(u', v') at view depth z'; the previous frame is then ray cast at exactly (u', v').
  * visibility: the frame is a reset (first frame or camera cut); or (u', v') is off
    screen; or the previous frame's ray hits another primitive; or it hits primitive k
    at a view depth differing from z' by more than DEPTH_TOL (relative): P was hidden
    (by another object or by k itself);
  * shading: otherwise, when the point's radiance changed, i.e. the largest per-channel
    difference of x / (1 + x) (a tone map, so HDR values do not dominate) between the
    two frames exceeds SHADING_TOL. Both radiances are of the same surface point under
    each frame's sun, shadows, emission and view direction (specular), so texture does
    not trigger it;
  * none: otherwise.
Aliasing (label_alias; 0 geometry, 1 texture, 2 none), from the reference's spp
sub-samples of each output pixel:
  * geometry: the sub-samples hit more than one primitive (an object edge, a wire, the
    holes of a cut-out, the horizon). The primitives are convex or planar, so a depth
    edge inside one primitive cannot occur and the primitive ids find every depth edge;
  * texture: one primitive, but the standard deviation of the sub-samples' tone-mapped
    luminance y / (1 + y) exceeds TEXTURE_TOL;
  * none: otherwise.
"""
from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass, field

import numpy as np

from clss.demo import scene

from . import jitter_mix
from clss.pipeline.contract import output_size
from clss.demo.scene import (NEAR, Box, Camera, Cylinder, Ground, Light, Sphere, _box_corners, _Rigid,
                        _trace, _View, frame_gbuffers, halton_jitter, render_reference,
                        trace_points)

LABEL_RULES_VERSION = 1
DEPTH_TOL = 0.01        # relative view-depth difference: the same surface point or not
SHADING_TOL = 0.02      # tone-mapped radiance change that counts as shading ghosting
TEXTURE_TOL = 0.025     # std of tone-mapped luminance inside a pixel: texture aliasing
GHOST_VISIBILITY, GHOST_SHADING, GHOST_NONE = 0, 1, 2
ALIAS_GEOMETRY, ALIAS_TEXTURE, ALIAS_NONE = 0, 1, 2
GHOST_NAMES = ("visibility", "shading", "none")
ALIAS_NAMES = ("geometry", "texture", "none")

_F = np.float32
_LUMA = np.array([0.2126, 0.7152, 0.0722], _F)


def tonemap(x):
    """x / (1 + x): the compressive map the label thresholds are stated in."""
    return x / (1 + x)


# ---------------------------------------------------------------- materials

class SolidTexture:
    """Albedo from a primitive's local coordinates: `plain`, `stripes` (along axis 0
    of the rotation `basis`) or `checker` (cells of 1/freq along all three axes).
    freq in cycles per metre."""

    def __init__(self, kind, freq, basis, c0, c1, duty=0.5):
        self.kind, self.freq, self.duty = kind, float(freq), float(duty)
        self.basis = np.asarray(basis, np.float64)
        self.c0, self.c1 = np.asarray(c0, _F), np.asarray(c1, _F)

    def __call__(self, L):
        n = len(L[0])
        if self.kind == "plain":
            return np.broadcast_to(self.c0, (n, 3))
        B = (self.basis * self.freq).tolist()
        a = [B[m][0] * L[0] + B[m][1] * L[1] + B[m][2] * L[2] for m in range(3)]
        if self.kind == "stripes":
            on = (a[0] - np.floor(a[0])) < self.duty
        else:
            on = (np.floor(a[0]) + np.floor(a[1]) + np.floor(a[2])) % 2 == 1
        return np.where(on[:, None], self.c1, self.c0)


class TexturedSphere(Sphere):
    def __init__(self, rigid, radius, texture, spec, emission=None):
        super().__init__(rigid, radius, texture.c0, spec=spec, emission=emission)
        self.texture = texture

    def surface(self, P, d):
        n, _ = super().surface(P, d)
        return n, self.texture(self.rigid.to_local(P))


class TexturedBox(Box):
    def __init__(self, rigid, half, texture, spec, emission=None):
        super().__init__(rigid, half)
        self.texture, self.spec = texture, spec
        self.emission = None if emission is None else np.asarray(emission, _F)

    def surface(self, P, d):
        n, _ = super().surface(P, d)
        return n, self.texture(self.rigid.to_local(P))


class Wire(Cylinder):
    """Poles and wires: clss.scene's Cylinder with the float32-safe hit and normal
    for radii of millimetres (see Cylinder.thin_safe)."""
    thin_safe = True


def _hash01(ix, iy, salt):
    """Deterministic per-cell pseudo-random numbers in [0, 1) (int64 arithmetic)."""
    h = ((ix * 73856093) ^ (iy * 19349663) ^ salt) & 0xFFFFFF
    return ((h * 2654435761) & 0xFFFFFFFF) * (1.0 / 2 ** 32)


class Cutout:
    """Alpha-tested rectangle in its local plane z = 0, |x| <= hx, |y| <= hy, moving
    and turning with `rigid`. Patterns (in local x, y rotated by `angle`): `slats`
    (bars `width` wide every `period`, plus a frame), `lattice` (two bar families at
    +-45 degrees), `mesh` (a square grid of thin wires), `leaves` (one disc of random
    size and position per cell of `period`, about half the cells filled)."""
    emission = None

    def __init__(self, rigid, half, pattern, period, width, angle, color, salt=0):
        self.rigid, self.hx, self.hy = rigid, float(half[0]), float(half[1])
        self.pattern, self.period, self.width = pattern, float(period), float(width)
        self.ca, self.sa = math.cos(angle), math.sin(angle)
        self.color = np.asarray(color, _F)
        self.salt = int(salt)
        self.spec = (0.05, 8.0)

    def corners(self):
        return _box_corners(self.rigid.c, (self.hx, self.hy, 0.0), self.rigid.R)

    def _mask(self, x, y):
        a = self.ca * x + self.sa * y
        b = -self.sa * x + self.ca * y
        p, w = self.period, self.width
        if self.pattern == "leaves":
            fa, fb = a * (1 / p), b * (1 / p)
            ia, ib = np.floor(fa), np.floor(fb)
            cell_a, cell_b = ia.astype(np.int64), ib.astype(np.int64)
            ox = 0.25 + 0.5 * _hash01(cell_a, cell_b, self.salt)
            oy = 0.25 + 0.5 * _hash01(cell_b, cell_a, self.salt + 1)
            r = 0.5 * _hash01(cell_a, cell_b, self.salt + 2) + 0.1
            return ((fa - ia - ox) ** 2 + (fb - ib - oy) ** 2) < r * r

        def bars(s):
            f = s * (1 / p)
            return (f - np.floor(f)) < w / p
        if self.pattern == "slats":
            m = bars(a)
        elif self.pattern == "lattice":
            r = math.sqrt(0.5)
            m = bars(r * (a + b)) | bars(r * (a - b))
        else:   # mesh
            m = bars(a) | bars(b)
        frame = 2 * w
        return m | (np.abs(x) > self.hx - frame) | (np.abs(y) > self.hy - frame)

    def _local_hit(self, o, d):
        lo = [_F(v) for v in self.rigid.to_local(o)]
        ld = self.rigid.dir_to_local(d)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -lo[2] / ld[2]
        return t, lo[0] + t * ld[0], lo[1] + t * ld[1]

    def hit(self, o, d):
        t, x, y = self._local_hit(o, d)
        inside = (np.abs(x) <= self.hx) & (np.abs(y) <= self.hy) & (t > NEAR)
        ok = np.zeros(t.shape, bool)
        ok[inside] = self._mask(x[inside], y[inside])
        return np.where(ok, t, _F(np.inf))

    def surface(self, P, d):
        nz = self.rigid.R[:, 2].astype(_F)
        facing = d[0] * nz[0] + d[1] * nz[1] + d[2] * nz[2] < 0
        n = np.where(facing[:, None], nz, -nz)
        L = self.rigid.to_local(P)
        if self.pattern == "leaves":   # per-leaf shade variation
            p = self.period
            a = self.ca * L[0] + self.sa * L[1]
            b = -self.sa * L[0] + self.ca * L[1]
            v = _hash01(np.floor(a / p).astype(np.int64), np.floor(b / p).astype(np.int64),
                        self.salt + 3)
            return n, self.color * (0.6 + 0.8 * v[:, None]).astype(_F)
        return n, np.broadcast_to(self.color, n.shape)

    def to_prev(self, P):
        return self.rigid.to_prev(P)


# ---------------------------------------------------------------- random scenes

def _random_rotation(rng):
    q = rng.normal(size=4)
    a, b, c, d = q / np.linalg.norm(q)
    return np.array([[a*a + b*b - c*c - d*d, 2*(b*c - a*d), 2*(b*d + a*c)],
                     [2*(b*c + a*d), a*a - b*b + c*c - d*d, 2*(c*d - a*b)],
                     [2*(b*d - a*c), 2*(c*d + a*b), a*a - b*b - c*c + d*d]])


def _random_color(rng, lo=0.05, hi=0.9):
    return rng.uniform(lo, hi, 3).round(3).tolist()


def _random_texture(rng, fine=False):
    kind = rng.choice(["plain", "stripes", "checker"], p=[0.2, 0.45, 0.35])
    freq = math.exp(rng.uniform(math.log(4 if fine else 0.5), math.log(40)))
    return dict(kind=str(kind), freq=freq, basis=_random_rotation(rng).tolist(),
                c0=_random_color(rng), c1=_random_color(rng), duty=rng.uniform(0.25, 0.75))


def _motion(rng, moving, speed=0.12):
    """Trajectory parameters: velocity (m/frame), bounce, yaw rate (rad/frame)."""
    if not moving:
        return dict(vel=[0.0, 0.0, 0.0], bounce=0.0, freq=0.0, phase=0.0, spin=0.0)
    v = rng.normal(size=3) * [1.0, 0.25, 0.6]
    v = v / np.linalg.norm(v) * rng.uniform(0.01, speed)
    return dict(vel=v.tolist(), bounce=float(rng.uniform(0, 0.8) * (rng.random() < 0.3)),
                freq=float(rng.uniform(0.1, 0.5)), phase=float(rng.uniform(0, 6.3)),
                spin=float(rng.normal() * 0.08 * (rng.random() < 0.6)))


def _pose(obj, t):
    m = obj["motion"]
    c = np.asarray(obj["pos"]) + np.asarray(m["vel"]) * t
    c[1] += m["bounce"] * abs(math.sin(m["freq"] * t + m["phase"]))
    c[1] = max(c[1], obj.get("min_y", -1e9))
    return c, obj["yaw"] + m["spin"] * t


def _random_camera_path(rng):
    kind = str(rng.choice(["static", "pan", "truck", "dolly", "orbit", "mixed"],
                          p=[0.1, 0.2, 0.2, 0.15, 0.15, 0.2]))
    speed = rng.uniform(0.02, 0.15) * (3 if rng.random() < 0.15 else 1)
    pos = [rng.uniform(-3, 3), rng.uniform(0.4, 3.0), rng.uniform(4.0, 8.0)]
    target = [rng.uniform(-2, 2), rng.uniform(-0.5, 1.5), rng.uniform(-8, -2)]
    side = rng.normal(size=2)
    side = (side / np.linalg.norm(side)).tolist()
    return dict(kind=kind, speed=float(speed), pos=pos, target=target, side=side,
                bob=float(rng.uniform(0, 0.1)), radius=float(rng.uniform(5, 9)))


def _camera(path, t, aspect):
    p, g, s, v = (np.array(path["pos"]), np.array(path["target"]),
                  path["side"], path["speed"])
    k = path["kind"]
    if k in ("pan", "mixed"):           # the aim point sweeps sideways and up/down
        g = g + np.array([s[0], 0.3 * s[1], 0]) * (v * 12 * t)
    if k in ("truck", "mixed"):          # the camera slides sideways
        p = p + np.array([s[0], 0.2 * s[1], 0]) * (v * t)
    if k in ("dolly", "mixed"):          # the camera moves toward / away from the aim
        p = p + (g - p) / np.linalg.norm(g - p) * (v * t * s[1])
    if k == "orbit":
        a = math.atan2(p[0] - g[0], p[2] - g[2]) + v * t / path["radius"] * 1.5
        r = path["radius"]
        p = np.array([g[0] + r * math.sin(a), p[1], g[2] + r * math.cos(a)])
    p = p + np.array([0.0, path["bob"] * math.sin(0.7 * t), 0.0])
    p[1] = max(p[1], 0.25)
    return Camera.look_at(p, g, aspect)


@dataclass
class SceneSpec:
    """Everything random about one sequence (JSON-serialisable: it goes into `meta`)."""
    seed: int
    index: int
    frames: int
    jittered: bool
    cut: int                       # frame index of the camera cut, or 0 for none
    cameras: list
    light: dict
    objects: list = field(default_factory=list)
    ground: dict = field(default_factory=dict)     # empty: clss.scene's ground
    # jitter_mix.draw's {"pattern", "flip", "phase"}; empty: `jittered`'s Halton or zero
    jitter: dict = field(default_factory=dict)

    @staticmethod
    def random(seed, index, frames, mix=jitter_mix.DEFAULT_MIX):
        rng = np.random.default_rng([seed, index, 0x5CE2E])
        cut = int(rng.integers(2, frames)) if frames > 3 and rng.random() < 0.35 else 0
        light = dict(elev=float(rng.uniform(0.3, 1.2)), azim=float(rng.uniform(0, 6.28)),
                     sun=(np.array([1.0, rng.uniform(0.8, 1.0), rng.uniform(0.6, 1.0)])
                          * rng.uniform(0.8, 3.0)).round(3).tolist(),
                     ambient=(np.array(_random_color(rng, 0.4, 1.0))
                              * rng.uniform(0.08, 0.35)).round(3).tolist(),
                     anim=str(rng.choice(["static", "moving", "flicker", "pulse"],
                                         p=[0.45, 0.25, 0.15, 0.15])),
                     rate=float(rng.uniform(0.02, 0.1) * rng.choice([-1, 1])),
                     pulse=float(rng.uniform(0.3, 1.2)),
                     change_at=int(rng.integers(1, frames)) if frames > 1 else 0,
                     dim=float(rng.uniform(0.2, 0.6)))
        spec = SceneSpec(seed=seed, index=index, frames=frames,
                         jittered=bool(rng.random() > 0.2), cut=cut,
                         cameras=[_random_camera_path(rng),
                                  _random_camera_path(rng)],
                         light=light)
        _random_environment(np.random.default_rng([seed, index, 0x6A0D]), spec)
        if not jitter_mix.is_legacy(mix):      # legacy: `jittered`'s draw, as before
            spec.jitter = jitter_mix.draw(mix, np.random.default_rng([seed, index, 0x717]))
            spec.jittered = spec.jitter["pattern"] != "zero"
        objs = spec.objects
        if rng.random() < 0.5:      # backdrop wall
            objs.append(dict(type="box", pos=[rng.uniform(-3, 3), 2.5, rng.uniform(-16, -9)],
                             half=[rng.uniform(4, 10), 2.5, 0.2], yaw=float(rng.normal() * 0.3),
                             tex=_random_texture(rng), spec=[0.05, 10.0], emission=None,
                             motion=_motion(rng, False)))
        if rng.random() < 0.4:      # textured floor slab
            objs.append(dict(type="box", pos=[rng.uniform(-3, 3), 0.01, rng.uniform(-6, 0)],
                             half=[rng.uniform(2, 8), 0.01, rng.uniform(2, 6)],
                             yaw=float(rng.uniform(0, 3.14)), tex=_random_texture(rng, fine=True),
                             spec=[float(rng.uniform(0, 0.5)), 30.0], emission=None,
                             motion=_motion(rng, False)))
        for _ in range(int(rng.integers(3, 10))):   # solid objects
            size = float(np.exp(rng.uniform(math.log(0.15), math.log(1.2))))
            shape = str(rng.choice(["sphere", "box"]))
            half = (rng.uniform(0.3, 1.0, 3) * size).tolist()
            y = size if shape == "sphere" else half[1]
            y += float(rng.uniform(0, 1.5) * (rng.random() < 0.3))
            objs.append(dict(type=shape, pos=[rng.uniform(-4, 4), y, rng.uniform(-9, 2)],
                             radius=size, half=half, yaw=float(rng.uniform(0, 6.28)),
                             min_y=size if shape == "sphere" else half[1],
                             tex=_random_texture(rng),
                             spec=[float(rng.uniform(0, 1.0)),
                                   float(np.exp(rng.uniform(math.log(8), math.log(400))))],
                             emission=None, motion=_motion(rng, rng.random() < 0.6)))
        for _ in range(int(rng.choice([0, 1, 1, 2, 3]))):   # lamps
            size = float(rng.uniform(0.05, 0.3))
            objs.append(dict(type=str(rng.choice(["sphere", "box"])),
                             pos=[rng.uniform(-4, 4), rng.uniform(0.3, 3), rng.uniform(-9, 2)],
                             radius=size, half=[size] * 3, yaw=0.0, min_y=size,
                             tex=_random_texture(rng), spec=[0.0, 1.0],
                             emission=(np.array(_random_color(rng, 0.3, 1.0))
                                       * rng.uniform(3, 40)).round(2).tolist(),
                             blink=str(rng.choice(["steady", "blink", "pulse"])),
                             period=int(rng.integers(2, 7)),
                             motion=_motion(rng, rng.random() < 0.5, 0.2)))
        if rng.random() < 0.3:      # an emissive billboard that blinks or pulses
            objs.append(dict(type="box", pos=[rng.uniform(-4, 4), rng.uniform(0.6, 2.5),
                                              rng.uniform(-10, -2)],
                             half=[rng.uniform(0.3, 1.5), rng.uniform(0.2, 0.8), 0.05],
                             yaw=float(rng.uniform(-0.8, 0.8)), min_y=0.3,
                             tex=_random_texture(rng), spec=[0.0, 1.0],
                             emission=(np.array(_random_color(rng, 0.3, 1.0))
                                       * rng.uniform(1.5, 12)).round(2).tolist(),
                             blink=str(rng.choice(["blink", "pulse"])),
                             period=int(rng.integers(1, 5)), motion=_motion(rng, False)))
        for k in range(int(rng.choice([1, 1, 2, 2, 3]))):   # cut-out panels
            pattern = str(rng.choice(["slats", "lattice", "mesh", "leaves"]))
            period = float(np.exp(rng.uniform(math.log(0.04), math.log(0.4))))
            width = period * rng.uniform(0.08, 0.4)
            hy = float(rng.uniform(0.5, 1.6))
            color = ([rng.uniform(0.05, 0.3), rng.uniform(0.3, 0.7), rng.uniform(0.05, 0.25)]
                     if pattern == "leaves" else _random_color(rng))
            objs.append(dict(type="cutout", pos=[rng.uniform(-4, 4), hy + rng.uniform(0, 0.8),
                                                 rng.uniform(-9, 3)],
                             half=[rng.uniform(0.6, 3.0), hy], yaw=float(rng.uniform(-1.2, 1.2)),
                             pattern=pattern, period=period, width=float(width),
                             angle=float(rng.uniform(0, 3.14) * (rng.random() < 0.5)),
                             color=color, salt=int(rng.integers(1 << 20)),
                             motion=_motion(rng, rng.random() < 0.3, 0.08)))
        for _ in range(int(rng.choice([0, 1, 1, 2]))):   # fences: poles and wires
            along_z = bool(rng.random() < 0.5)
            objs.append(dict(type="fence", along_z=along_z,
                             start=[rng.uniform(-4, 4), 0.0, rng.uniform(-6, 3)],
                             n=int(rng.integers(6, 26)), spacing=float(rng.uniform(0.4, 1.8)),
                             height=float(rng.uniform(0.8, 2.0)),
                             pole_r=float(rng.uniform(0.01, 0.05)),
                             wire_r=float(np.exp(rng.uniform(math.log(0.002), math.log(0.015)))),
                             wires=int(rng.integers(1, 5)),
                             color=_random_color(rng), wire_color=_random_color(rng, 0.3, 0.8)))
        return spec

    def to_json(self):
        return json.dumps(self.__dict__)


def _random_environment(rng, spec):
    """Ground texture colours, scale and path, and the sky's colours (its own random
    stream, so that the rest of a scene does not depend on it)."""
    dark = _random_color(rng, 0.02, 0.15)
    spec.ground = dict(albedo=np.array([dark, _random_color(rng, 0.1, 0.5),
                                        _random_color(rng, 0.3, 0.8), _random_color(rng),
                                        _random_color(rng, 0.05, 0.3)]).T.round(3).tolist(),
                       texels_per_metre=float(np.exp(rng.uniform(math.log(32), math.log(256)))),
                       path_x=float(rng.uniform(-3, 3)),
                       path_half=float(rng.uniform(0.3, 2.0) * (rng.random() < 0.6)))
    sky = rng.choice(["clear", "clear", "dusk", "overcast"])
    if sky == "clear":
        hor, zen = [0.8, 0.86, 0.95], [0.22, 0.42, 0.85]
    elif sky == "dusk":
        hor, zen = [1.2, 0.7, 0.4], [0.15, 0.2, 0.45]
    else:
        hor, zen = [0.7, 0.72, 0.75], [0.5, 0.52, 0.56]
    gain = rng.uniform(0.6, 1.6)
    spec.light["horizon"] = (np.array(hor) * gain).round(3).tolist()
    spec.light["zenith"] = (np.array(zen) * gain).round(3).tolist()


def ground_of(spec):
    g = spec.ground
    if not g:
        return None
    return Ground(np.asarray(g["albedo"], _F), g["texels_per_metre"], g["path_x"],
                  g["path_half"])


def _build_texture(t):
    return SolidTexture(t["kind"], t["freq"], t["basis"], t["c0"], t["c1"], t["duty"])


def _emission(obj, t):
    e = obj.get("emission")
    if e is None:
        return None
    e = np.asarray(e)
    if obj["blink"] == "blink":
        e = e * (1.0 if (int(math.floor(t)) // obj["period"]) % 2 == 0 else 0.08)
    elif obj["blink"] == "pulse":
        e = e * (0.55 + 0.45 * math.sin(2 * math.pi * t / (2 * obj["period"])))
    return e


def build_primitives(spec, t):
    """The primitives at frame time t with their transforms at t and t - 1; the list
    order (hence the primitive ids) is the same at every t."""
    prims = []
    for obj in spec.objects:
        kind = obj["type"]
        if kind == "fence":
            _fence(prims, obj)
            continue
        (c, yaw), (cp, yawp) = _pose(obj, t), _pose(obj, t - 1)
        rigid = _Rigid(c, yaw, cp, yawp)
        if kind == "sphere":
            prims.append(TexturedSphere(rigid, obj["radius"], _build_texture(obj["tex"]),
                                        tuple(obj["spec"]), _emission(obj, t)))
        elif kind == "box":
            prims.append(TexturedBox(rigid, obj["half"], _build_texture(obj["tex"]),
                                     tuple(obj["spec"]), _emission(obj, t)))
        else:
            prims.append(Cutout(rigid, obj["half"], obj["pattern"], obj["period"],
                                obj["width"], obj["angle"], obj["color"], obj["salt"]))
    return prims


def _fence(prims, f):
    """Poles every `spacing` and `wires` horizontal wires, in chunks of 4 spans so each
    chunk's screen rectangle stays small (as clss.scene's fence)."""
    axis = np.array([0.0, 0.0, -1.0]) if f["along_z"] else np.array([1.0, 0.0, 0.0])
    a = np.asarray(f["start"])
    for k in range(f["n"]):
        prims.append(Wire(a + axis * (f["spacing"] * k), (0, 1, 0), f["height"],
                          f["pole_r"], f["color"]))
    chunk = 4
    for m in range(f["wires"]):
        y = f["height"] * (m + 1) / (f["wires"] + 0.5)
        for k in range(0, f["n"] - 1, chunk):
            length = f["spacing"] * min(chunk, f["n"] - 1 - k)
            start = a + axis * (f["spacing"] * k) + [0.0, y, 0.0]
            prims.append(Wire(start, axis, length, f["wire_r"], f["wire_color"]))


def light_at(spec, t):
    L = spec.light
    elev, azim, gain = L["elev"], L["azim"], 1.0
    if L["anim"] == "moving":
        azim += L["rate"] * t
        elev = min(max(elev + 0.3 * L["rate"] * t, 0.15), 1.4)
    elif L["anim"] == "flicker":          # a cloud: the sun dims from change_at on
        gain = L["dim"] if t >= L["change_at"] else 1.0
    elif L["anim"] == "pulse":
        gain = 0.6 + 0.4 * math.cos(L["pulse"] * t)
    d = np.array([math.cos(elev) * math.sin(azim), math.sin(elev),
                  math.cos(elev) * math.cos(azim)])
    sky = {k: np.asarray(L[k], _F) for k in ("horizon", "zenith") if k in L}
    return Light(d / np.linalg.norm(d), (np.asarray(L["sun"]) * gain).astype(_F),
                 np.asarray(L["ambient"], _F), **sky)


def camera_at(spec, t, aspect):
    """Camera at frame time t; frames from spec.cut on follow the second path."""
    seg = 1 if spec.cut and t >= spec.cut else 0
    return _camera(spec.cameras[seg], t, aspect)


# ---------------------------------------------------------------- rendering and labels

def _ghost_labels(spec, i, view, prims_prev, light_prev, prev_cam):
    """label_ghost (H, W) by the module docstring's rules."""
    H, W = view.h, view.w
    if i == 0 or i == spec.cut:
        return np.full((H, W), GHOST_VISIBILITY, np.uint8)
    out = {}
    cols, rows = np.arange(W, dtype=_F) + _F(0.5), np.arange(H, dtype=_F) + _F(0.5)
    color, _, motion = _trace(view, cols, rows, prev_cam, out)
    u = cols[None, :] + motion[..., 0]
    v = rows[:, None] + motion[..., 1]
    on = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    prev_view = _View(prims_prev, prev_cam, W, H, light_prev, ground_of(spec))
    pc, pt, pid = trace_points(prev_view, u[on], v[on])
    cid, z = out["ids"][on], out["prev_z"][on]
    with np.errstate(invalid="ignore"):
        same = (pid == cid) & ((cid == scene.SKY_ID) | (np.abs(pt - z) <= DEPTH_TOL * z))
    cur = color.transpose(1, 2, 0)[on]
    changed = np.abs(tonemap(cur) - tonemap(pc)).max(-1) > SHADING_TOL
    lab = np.full((H, W), GHOST_VISIBILITY, np.uint8)
    lab[on] = np.where(same, np.where(changed, GHOST_SHADING, GHOST_NONE), GHOST_VISIBILITY)
    return lab


class _AliasStats:
    """Accumulates, over the reference's sample passes, whether a pixel's samples hit
    more than one primitive and the moments of their tone-mapped luminance."""

    def __init__(self):
        self.first = self.mixed = self.s1 = self.s2 = None
        self.n = 0

    def __call__(self, color, out):
        y = tonemap(np.tensordot(_LUMA, color, 1))
        ids = out["ids"]
        if self.first is None:
            self.first, self.mixed = ids, np.zeros(ids.shape, bool)
            self.s1, self.s2 = y, y * y
        else:
            self.mixed |= ids != self.first
            self.s1 = self.s1 + y
            self.s2 = self.s2 + y * y
        self.n += 1

    def labels(self):
        mean = self.s1 / self.n
        std = np.sqrt(np.maximum(self.s2 / self.n - mean * mean, 0))
        return np.where(self.mixed, ALIAS_GEOMETRY,
                        np.where(std > TEXTURE_TOL, ALIAS_TEXTURE, ALIAS_NONE)).astype(np.uint8)


def frame_jitter(spec, i, scale):
    """(jx, jy) of frame i: the spec's drawn pattern, or (a spec from before issue 53)
    Halton(2,3) if `jittered`, else zero."""
    if spec.jitter:
        return tuple(float(v) for v in jitter_mix.sequence_jitter(
            dict(spec.jitter, phase=spec.jitter["phase"] + i), 1, scale)[0])
    return halton_jitter(i, scale) if spec.jittered else (0.0, 0.0)


def render_frame(spec, i, render_size, scale, spp, gbuffers=True):
    """Frame i of the sequence `spec`: a dict of the DATA.md per-frame arrays; with
    `gbuffers` also the G-buffers (albedo, normal at the colour's jittered samples, from
    the same ray cast; albedo_hr, depth_hr, normal_hr at the output pixel centres).
    The other arrays do not depend on `gbuffers`."""
    h, w = render_size
    H, W = output_size(h, w, scale)
    aspect = w / h
    prims, prims_prev = build_primitives(spec, float(i)), build_primitives(spec, i - 1.0)
    light, light_prev = light_at(spec, float(i)), light_at(spec, i - 1.0)
    cam = camera_at(spec, float(i), aspect)
    # The previous camera of the current path: motion stays meaningful across a cut
    # (the frame is a reset anyway).
    seg = spec.cameras[1 if spec.cut and i >= spec.cut else 0]
    prev_cam = _camera(seg, i - 1.0, aspect)
    jx, jy = frame_jitter(spec, i, scale)
    us = np.arange(w, dtype=_F) + _F(0.5 + jx)
    vs = np.arange(h, dtype=_F) + _F(0.5 + jy)
    ground = ground_of(spec)
    gb = {} if gbuffers else None
    color, z, motion = _trace(_View(prims, cam, w, h, light, ground), us, vs, prev_cam,
                              gbuffers=gb)
    with np.errstate(divide="ignore"):
        depth = np.where(np.isfinite(z), _F(NEAR) / z, _F(0)).astype(_F)
    out_view = _View(prims, cam, W, H, light, ground)
    stats = _AliasStats()
    ref = render_reference(out_view, spp, np.random.default_rng([spec.seed, spec.index, i, 1]),
                           on_sample=stats)
    data = dict(color=np.ascontiguousarray(color.transpose(1, 2, 0)), depth=depth,
                motion=motion, jitter=np.array([jx, jy], _F), reset=i == 0 or i == spec.cut,
                reference=ref, label_ghost=_ghost_labels(spec, i, out_view, prims_prev,
                                                         light_prev, prev_cam),
                label_alias=stats.labels())
    if gb is not None:
        data.update(frame_gbuffers(gb, out_view))
    return data


def render_sequence(spec, render_size, scale, spp, gbuffers=True):
    """The DATA.md arrays (dict) of one sequence; gbuffers=False leaves out the
    G-buffer keys (albedo, normal, albedo_hr, depth_hr, normal_hr) and changes nothing
    else."""
    frames = [render_frame(spec, i, render_size, scale, spp, gbuffers)
              for i in range(spec.frames)]
    data = {k: np.stack([f[k] for f in frames]) for k in frames[0]}
    data["reset"] = data["reset"].astype(bool)
    data["scale"] = np.array(scale, _F)
    data["meta"] = np.array(json.dumps(dict(
        generator="weights_tools.scenegen", renderer="clss.scene numpy ray caster",
        seed=spec.seed, index=spec.index, render_size=list(render_size), spp=spp,
        label_rules_version=LABEL_RULES_VERSION,
        thresholds=dict(depth=DEPTH_TOL, shading=SHADING_TOL, texture=TEXTURE_TOL),
        content=spec.__dict__)))
    return data


def class_counts(data):
    """Pixel counts per class: {"ghost": [vis, shading, none], "alias": [geo, tex, none],
    "ghost_no_reset": ghost counts over the frames that are not resets (where every
    pixel is visibility ghosting by definition)}."""
    keep = ~data["reset"]
    return {"ghost": np.bincount(data["label_ghost"].ravel(), minlength=3).tolist(),
            "alias": np.bincount(data["label_alias"].ravel(), minlength=3).tolist(),
            "ghost_no_reset": np.bincount(data["label_ghost"][keep].ravel(),
                                          minlength=3).tolist()}


def write_sequence(path, data):
    tmp = path + ".tmp.npz"
    np.savez(tmp, **data)
    os.replace(tmp, path)


def _job(args):
    seed, index, frames, render_size, scale, spp, out_dir, mix = args
    t0 = time.perf_counter()
    spec = SceneSpec.random(seed, index, frames, mix)
    data = render_sequence(spec, render_size, scale, spp)
    write_sequence(os.path.join(out_dir, f"seq_{index:04d}.npz"), data)
    return index, class_counts(data), time.perf_counter() - t0


def generate(out_dir, sequences, frames, seed, render_size, scale=2.0, spp=16, workers=2,
             log=print, mix=jitter_mix.DEFAULT_MIX):
    """Write `sequences` .npz files into out_dir (which must exist) and stats.json
    (class frequencies, time, the jitter mix); returns the stats dict."""
    jobs = [(seed, k, frames, tuple(render_size), float(scale), spp, out_dir, mix)
            for k in range(sequences)]
    t0 = time.perf_counter()
    totals = {"ghost": [0, 0, 0], "alias": [0, 0, 0], "ghost_no_reset": [0, 0, 0]}

    def done(res):
        index, counts, dt = res
        for key in totals:
            totals[key] = [a + b for a, b in zip(totals[key], counts[key])]
        log(f"sequence {index:4d}: {dt:5.1f} s")
    if workers <= 1:
        for j in jobs:
            done(_job(j))
    else:
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(workers) as pool:
            for res in pool.map(_job, jobs):
                done(res)
    elapsed = time.perf_counter() - t0
    freq = {key: [c / max(sum(v), 1) for c in v] for key, v in totals.items()}
    stats = dict(sequences=sequences, frames=frames, seed=seed, render_size=list(render_size),
                 scale=scale, spp=spp, seconds=round(elapsed, 1), workers=workers,
                 jitter_mix=mix,
                 counts=totals, frequencies=freq,
                 class_names={"ghost": GHOST_NAMES, "alias": ALIAS_NAMES,
                              "ghost_no_reset": GHOST_NAMES})
    with open(os.path.join(out_dir, "stats.json"), "w") as fh:
        json.dump(stats, fh, indent=1)
    return stats
