"""A built-in procedural animated scene, ray cast in numpy, with a supersampled reference.

Made to exercise temporal supersampling: a tiled ground with thin grout lines and a
finely striped path (texture aliasing), a fence of thin poles and sub-pixel wires
receding into the distance (geometry aliasing), a bouncing striped ball that rotates, a
sphere crossing the view and a rotating box (disocclusions, shading change from their
shadows), an orbiting emissive lamp and specular highlights (HDR values well above 1),
and a camera that moves sideways and forward.

Conventions (clss-frame.md section 1):
  * colour: linear HDR, one point sample per render pixel at the jittered position;
  * depth: reversed-Z with an infinite far plane, ``depth = NEAR / z_view`` (near = 1,
    sky = 0);
  * motion: render pixels, ``prev = p + motion``, +y down, computed by reprojecting the
    hit point with the previous frame's object transform and (unjittered) camera; the
    jitter is not part of the motion (FSR2/DLSS convention);
  * jitter: Halton(2,3) of length ceil(8 * scale^2), the sample of render pixel (i,j)
    taken at (j + 0.5 + jx, i + 0.5 + jy);
  * reference: output resolution, box filter over the pixel, stratified samples (spp
    rounded up to a full gx x gy grid), each jittered inside its stratum.
  * G-buffers (Frame.gbuffers; clss.pipeline.contract.GBUFFERS): albedo (diffuse texture
    colour + the scalar specular factor, not hazed, sky 0) and normal (unit, camera space:
    +x right, +y up, +z toward the camera; sky 0) at the colour's jittered samples, from
    the same ray cast; albedo_hr, depth_hr, normal_hr at the output pixel centres
    (unjittered, one unshaded ray per output pixel).
The camera frustum is fixed by the render size, so output pixel (u, v) and render pixel
(u * w / W, v * h / H) look at the same point.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..io.frame import Frame  # noqa: F401  (what the scene renders; scene.Frame as before)
# The jitter sequence and the output size are the frame contract's: the scene renders
# exactly the samples and the size clss.Upscaler expects. (halton_jitter and
# jitter_sequence_length are the names scene users have always called them by.)
from ..pipeline.contract import jitter_at as halton_jitter
from ..pipeline.contract import jitter_phase_count as jitter_sequence_length  # noqa: F401
from ..pipeline.contract import output_size as contract_output_size

NEAR = 0.1                      # reversed-Z near plane (scene units, metres)
TAN_HALF_FOV = math.tan(math.radians(30.0))  # vertical field of view 60 degrees
SUN_DIR = np.array([-0.45, 0.75, 0.48]) / np.linalg.norm([-0.45, 0.75, 0.48])
SUN = np.array([1.7, 1.6, 1.45], np.float32)
AMBIENT = np.array([0.16, 0.19, 0.26], np.float32)
HORIZON = np.array([0.80, 0.86, 0.95], np.float32)
ZENITH = np.array([0.22, 0.42, 0.85], np.float32)
HAZE = 0.008                    # per metre: distant detail fades but still aliases

_F = np.float32


@dataclass
class Light:
    """The sun (a directional light casting shadows on the ground), the ambient term and
    the sky (horizon colour, also the haze colour; zenith colour). The built-in scene
    uses DEFAULT_LIGHT; generated scenes move and dim it per frame."""
    sun_dir: np.ndarray          # unit vector toward the sun (float64)
    sun: np.ndarray              # float32 RGB radiance
    ambient: np.ndarray          # float32 RGB
    horizon: np.ndarray = field(default_factory=lambda: HORIZON)
    zenith: np.ndarray = field(default_factory=lambda: ZENITH)


DEFAULT_LIGHT = Light(SUN_DIR, SUN, AMBIENT)
SKY_ID, GROUND_ID = -2, -1       # primitive ids of the sky and the ground plane


# ---------------------------------------------------------------- camera

@dataclass
class Camera:
    pos: np.ndarray
    right: np.ndarray
    up: np.ndarray
    fwd: np.ndarray
    aspect: float                # width / height of the render frame

    @staticmethod
    def look_at(pos, target, aspect):
        pos = np.asarray(pos, np.float64)
        fwd = np.asarray(target, np.float64) - pos
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        return Camera(pos, right, np.cross(right, fwd), fwd, aspect)

    def rays(self, u, v, width, height):
        """Directions (unnormalised, unit component along fwd, so the ray parameter is
        the view depth) through continuous pixel positions u (right), v (down)."""
        sx = ((2.0 / width) * u - 1.0) * _F(TAN_HALF_FOV * self.aspect)
        sy = (1.0 - (2.0 / height) * v) * _F(TAN_HALF_FOV)
        r, up, f = self.right.astype(_F), self.up.astype(_F), self.fwd.astype(_F)
        return tuple(f[k] + sx * r[k] + sy * up[k] for k in range(3))

    def project(self, px, py, pz, width, height):
        """World points -> continuous pixel positions (u, v) and view depth z."""
        rx, ry, rz = px - self.pos[0], py - self.pos[1], pz - self.pos[2]
        z = rx * self.fwd[0] + ry * self.fwd[1] + rz * self.fwd[2]
        x = (rx * self.right[0] + ry * self.right[1] + rz * self.right[2]) / z
        y = (rx * self.up[0] + ry * self.up[1] + rz * self.up[2]) / z
        u = (x / (TAN_HALF_FOV * self.aspect) + 1.0) * (0.5 * width)
        v = (1.0 - y / TAN_HALF_FOV) * (0.5 * height)
        return u, v, z


def camera_at(t, aspect):
    pos = (-1.3 + 0.075 * t, 1.35 + 0.12 * math.sin(0.21 * t), 6.2 - 0.06 * t)
    target = (0.5 + 0.05 * t, -1.0 + 0.1 * math.sin(0.13 * t), -4.0)
    return Camera.look_at(pos, target, aspect)


# ---------------------------------------------------------------- primitives
# Every primitive has: hit(o, d) -> ray parameter t (inf on miss) for arrays of ray
# directions; corners() -> world points bounding it (screen-space culling);
# surface(P, d) -> (normal, albedo) at gathered hit points; to_prev(P) -> where that
# surface point was one frame earlier. The ground plane is not a primitive: it covers
# most pixels, so it is shaded as whole image rows (see _ground).

def _yaw(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


class _Rigid:
    """Transform (translation, yaw) of a primitive at the current and previous frame."""

    def __init__(self, center, yaw=0.0, center_prev=None, yaw_prev=None):
        self.c = np.asarray(center, np.float64)
        self.R = _yaw(yaw)
        self.cp = self.c if center_prev is None else np.asarray(center_prev, np.float64)
        self.Rp = self.R if yaw_prev is None else _yaw(yaw_prev)

    # Python floats keep float32 arrays float32 (numpy scalars would promote them).
    def to_local(self, P):
        c, R = self.c.tolist(), self.R.tolist()
        q = [P[k] - c[k] for k in range(3)]
        return tuple(R[0][k] * q[0] + R[1][k] * q[1] + R[2][k] * q[2] for k in range(3))

    def dir_to_local(self, d):
        R = self.R.tolist()
        return tuple(R[0][k] * d[0] + R[1][k] * d[1] + R[2][k] * d[2] for k in range(3))

    def to_world_prev(self, L):
        c, R = self.cp.tolist(), self.Rp.tolist()
        return tuple(R[k][0] * L[0] + R[k][1] * L[1] + R[k][2] * L[2] + c[k] for k in range(3))

    def to_prev(self, P):
        return self.to_world_prev(self.to_local(P))


def _box_corners(c, h, R=np.eye(3)):
    return np.array([c + R @ (np.asarray(h) * [sx, sy, sz])
                     for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])


class Sphere:
    def __init__(self, rigid, radius, color, stripes=0, spec=(0.0, 1.0), emission=None):
        self.rigid, self.r = rigid, radius
        self.color = np.asarray(color, _F)
        self.stripes, self.spec = stripes, spec
        self.emission = None if emission is None else np.asarray(emission, _F)

    def corners(self):
        return _box_corners(self.rigid.c, (self.r,) * 3)

    def shadow_corners(self, L):
        """Ground points bounding this sphere's shadow along direction L."""
        g = self.rigid.c - (self.rigid.c[1] / L[1]) * L
        R = self.r / L[1]
        return _box_corners(g * [1, 0, 1], (R, 0, R))

    def hit(self, o, d):
        oc = [float(o[k] - self.rigid.c[k]) for k in range(3)]
        a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        b = d[0] * oc[0] + d[1] * oc[1] + d[2] * oc[2]
        c = oc[0] ** 2 + oc[1] ** 2 + oc[2] ** 2 - self.r ** 2
        disc = b * b - a * c
        with np.errstate(invalid="ignore"):
            t = (-b - np.sqrt(disc)) / a
        return np.where((disc > 0) & (t > NEAR), t, _F(np.inf))

    def surface(self, P, d):
        c = self.rigid.c.tolist()
        n = np.stack([(P[k] - c[k]) * (1 / self.r) for k in range(3)], -1)
        albedo = np.broadcast_to(self.color, n.shape)
        if self.stripes:
            L = self.rigid.to_local(P)
            ang = np.arctan2(L[2], L[0]) * (self.stripes / (2 * math.pi))
            white = (ang - np.floor(ang)) < 0.5
            albedo = np.where(white[:, None], np.array([0.85, 0.85, 0.8], _F), albedo)
        return n, albedo

    def occludes(self, P, L):
        """Whether the ray from points P toward unit direction L hits the sphere."""
        c = self.rigid.c.tolist()
        oc = [P[k] - c[k] for k in range(3)]
        b = oc[0] * L[0] + oc[1] * L[1] + oc[2] * L[2]
        cc = oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2] - self.r ** 2
        return (b < 0) & (b * b > cc)

    def to_prev(self, P):
        return self.rigid.to_prev(P)


class Box:
    """Box turning about y, with fine horizontal stripes on its sides."""
    spec = (0.15, 40.0)
    emission = None

    def __init__(self, rigid, half):
        self.rigid, self.h = rigid, np.asarray(half, np.float64)

    def corners(self):
        return _box_corners(self.rigid.c, self.h, self.rigid.R)

    def shadow_corners(self, L):
        c = self.corners()
        return c - (c[:, 1:2] / L[1]) * L

    def _slabs(self, lo, ld):
        tn = tf = None
        with np.errstate(divide="ignore", invalid="ignore"):
            for k in range(3):
                inv = 1.0 / ld[k]
                t1 = (-self.h[k] - lo[k]) * inv
                t2 = (self.h[k] - lo[k]) * inv
                a, b = np.minimum(t1, t2), np.maximum(t1, t2)
                tn = a if tn is None else np.maximum(tn, a)
                tf = b if tf is None else np.minimum(tf, b)
        return tn, tf

    def hit(self, o, d):
        lo = [_F(v) for v in self.rigid.to_local(o)]
        tn, tf = self._slabs(lo, self.rigid.dir_to_local(d))
        return np.where((tn <= tf) & (tn > NEAR), tn, _F(np.inf))

    def surface(self, P, d):
        loc = self.rigid.to_local(P)
        L = np.stack(loc, -1) / self.h.astype(_F)
        axis = np.argmax(np.abs(L), -1)
        rows = np.arange(len(L))
        nl = np.zeros_like(L)
        nl[rows, axis] = np.sign(L[rows, axis])
        n = nl @ self.rigid.R.T.astype(_F)
        stripe = ((loc[1] * (1 / 0.08)) % 1.0 < 0.5) & (axis != 1)
        albedo = np.where(stripe[:, None], np.array([0.9, 0.9, 0.9], _F),
                          np.array([0.15, 0.35, 0.2], _F))
        return n, albedo

    def occludes(self, P, L):
        lo = self.rigid.to_local(P)
        ld = [_F(v) for v in self.rigid.dir_to_local(L)]
        tn, tf = self._slabs(lo, ld)
        return (tn <= tf) & (tf > 0)

    def to_prev(self, P):
        return self.rigid.to_prev(P)


class Cylinder:
    """Static open cylinder from `a` along an axis-aligned unit `axis` for `length`
    (poles, wires).

    `thin_safe` (a class attribute, off here so that the built-in scene's output stays
    as it was) computes the hit with the cancellation-free discriminant
    A r^2 - (o x d)^2 and renormalises the normal: for radii of millimetres metres away,
    float32's B^2 - A C loses r^2 entirely (the wire is missed) and the hit point is
    too coarse for (P - axis) / r to stay of unit length (highlights of thousands)."""
    spec = (0.3, 60.0)
    emission = None
    thin_safe = False

    def __init__(self, a, axis, length, radius, color):
        self.a = np.asarray(a, np.float64)
        axis = np.asarray(axis, np.float64)
        self.k = int(np.argmax(np.abs(axis)))
        if np.count_nonzero(axis) != 1:
            raise ValueError("Cylinder axis must be along x, y or z")
        self.sign = float(np.sign(axis[self.k]))
        self.ax = np.eye(3)[self.k] * self.sign
        self.len, self.r = length, radius
        self.color = np.asarray(color, _F)

    def corners(self):
        b = self.a + self.ax * self.len
        return _box_corners((self.a + b) / 2, np.abs(b - self.a) / 2 + self.r)

    def hit(self, o, d):
        i, j = [m for m in range(3) if m != self.k]
        oi, oj = float(o[i] - self.a[i]), float(o[j] - self.a[j])
        di, dj = d[i], d[j]
        A = di * di + dj * dj
        B = di * oi + dj * oj
        if self.thin_safe:
            cross = oi * dj - oj * di
            disc = A * self.r ** 2 - cross * cross
        else:
            disc = B * B - A * (oi * oi + oj * oj - self.r ** 2)
        with np.errstate(invalid="ignore", divide="ignore"):
            t = (-B - np.sqrt(disc)) / A
        s = (float(o[self.k] - self.a[self.k]) + t * d[self.k]) * self.sign
        ok = (t > NEAR) & (s >= 0) & (s <= self.len)   # NaN t (disc < 0) fails t > NEAR
        return np.where(ok, t, _F(np.inf))

    def surface(self, P, d):
        n = np.stack([P[m] - float(self.a[m]) for m in range(3)], -1)
        n[:, self.k] = 0
        if self.thin_safe:
            n /= np.maximum(np.sqrt(np.sum(n * n, -1, keepdims=True)), _F(1e-12))
        else:
            n *= 1 / self.r
        return n, np.broadcast_to(self.color, n.shape)

    def to_prev(self, P):
        return P


class Grille:
    """Static slatted panel in the plane z = z0 (alpha-tested): x in [x0, x1], y in
    [0, height]; vertical slats `slat` wide every `period`, two horizontal rails."""
    spec = (0.0, 1.0)
    emission = None

    def __init__(self, z0, x0, x1, height, period, slat, color):
        self.z0, self.x0, self.x1, self.hgt = z0, x0, x1, height
        self.period, self.slat = period, slat
        self.color = np.asarray(color, _F)

    def corners(self):
        return _box_corners(((self.x0 + self.x1) / 2, self.hgt / 2, self.z0),
                            ((self.x1 - self.x0) / 2, self.hgt / 2, 0.0))

    def hit(self, o, d):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.z0 - float(o[2])) / d[2]
        x = float(o[0]) + t * d[0]
        y = float(o[1]) + t * d[1]
        f = (x - self.x0) * (1 / self.period)
        slat = (f - np.floor(f)) < self.slat / self.period
        rail = (np.abs(y - 0.35) < 0.03) | (y > self.hgt - 0.06)
        ok = (slat | rail) & (x >= self.x0) & (x <= self.x1) & (y >= 0) & (y <= self.hgt)
        return np.where(ok & (t > NEAR), t, _F(np.inf))

    def surface(self, P, d):
        n = np.zeros((len(P[0]), 3), _F)
        n[:, 2] = np.where(d[2] < 0, _F(1), _F(-1))
        return n, np.broadcast_to(self.color, n.shape)

    def to_prev(self, P):
        return P


def scene_at(t):
    """Primitives at frame time t, with their transforms at t and t - 1."""
    def ball(s):
        return (0.3 + 1.3 * math.sin(0.12 * s), 0.5 + 1.1 * abs(math.sin(0.23 * s)), -1.4)

    def mover(s):
        return (-3.2 + 0.24 * s, 0.7, 0.6)

    def lamp(s):
        b = ball(s)
        return (b[0] + 1.0 * math.cos(0.3 * s), b[1] + 0.35, b[2] + 1.0 * math.sin(0.3 * s))

    prims = [Sphere(_Rigid(ball(t), 0.17 * t, ball(t - 1), 0.17 * (t - 1)), 0.5,
                    (0.8, 0.12, 0.1), stripes=10, spec=(1.0, 250.0)),
             Sphere(_Rigid(mover(t), 0, mover(t - 1), 0), 0.7, (0.12, 0.2, 0.7),
                    spec=(0.8, 120.0)),
             Sphere(_Rigid(lamp(t), 0, lamp(t - 1), 0), 0.12, (1, 1, 1),
                    emission=(14.0, 11.0, 6.0)),
             Box(_Rigid((-2.4, 0.6, -3.6), 0.08 * t, (-2.4, 0.6, -3.6), 0.08 * (t - 1)),
                 (0.6, 0.6, 0.6)),
             Grille(-6.0, -8.0, -0.7, 1.3, 0.2, 0.035, (0.16, 0.13, 0.11))]
    wood, steel = (0.45, 0.33, 0.22), (0.5, 0.5, 0.55)
    fx, z0, dz, n = 2.3, 4.5, 1.5, 26
    for k in range(n):
        prims.append(Cylinder((fx, 0.0, z0 - dz * k), (0, 1, 0), 1.45, 0.03, wood))
    # Wires in chunks so that each chunk's screen rectangle stays small.
    chunk = 5
    for y in (0.55, 1.0, 1.4):
        for k in range(0, n - 1, chunk):
            L = dz * min(chunk, n - 1 - k)
            prims.append(Cylinder((fx, y, z0 - dz * k), (0, 0, -1), L, 0.007, steel))
    return prims


# ---------------------------------------------------------------- tracing

def _screen_rect(corners, cam, width, height, margin=2):
    """Pixel rectangle (r0, r1, c0, c1) covering world points `corners`, or None when
    off-screen. `margin` covers sample offsets up to +-1 pixel from the centre."""
    u, v, z = cam.project(corners[:, 0], corners[:, 1], corners[:, 2], width, height)
    if (z <= NEAR).all():
        return None
    if (z <= NEAR).any():
        return 0, height, 0, width
    c0 = max(int(math.floor(u.min())) - margin, 0)
    c1 = min(int(math.ceil(u.max())) + margin, width)
    r0 = max(int(math.floor(v.min())) - margin, 0)
    r1 = min(int(math.ceil(v.max())) + margin, height)
    if c0 >= c1 or r0 >= r1:
        return None
    return r0, r1, c0, c1


class _View:
    """One frame's primitives seen by one camera at one image size; screen rectangles
    are computed once and shared by all sample passes."""

    def __init__(self, prims, cam, width, height, light=None, ground=None):
        self.prims, self.cam, self.w, self.h = prims, cam, width, height
        self.light = DEFAULT_LIGHT if light is None else light
        self.ground = DEFAULT_GROUND if ground is None else ground
        self.rects = [_screen_rect(p.corners(), cam, width, height) for p in prims]
        L = self.light.sun_dir
        self.casters = [(p, _screen_rect(p.shadow_corners(L), cam, width, height))
                        for p in prims if hasattr(p, "shadow_corners") and p.emission is None]


def _sky(d, light=DEFAULT_LIGHT):
    n2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    a = np.sqrt(np.sqrt(np.maximum(d[1], 0) ** 2 / n2))
    hor, zen = light.horizon, light.zenith
    return [hor[k] + (zen[k] - hor[k]) * a for k in range(3)]


# Ground texture: a 2 m x 2 m tile of 256 x 256 texels (0.78 cm), point sampled:
# 1 m checker tiles with grout lines every 0.5 m. Class -> albedo in _GROUND_ALBEDO:
# grout, dark tile, light tile, path stripe, path gap. The path (|x - 0.4| < 0.9) has
# stripes of period 0.125 m along z.
_TEX = 256
_GROUND_ALBEDO = np.array([[0.08, 0.08, 0.08], [0.30, 0.29, 0.28], [0.52, 0.50, 0.48],
                           [0.75, 0.55, 0.25], [0.12, 0.10, 0.09]], _F).T.copy()


def _ground_texture():
    i = np.arange(_TEX)
    g = (i % (_TEX // 4) < 2) | (i % (_TEX // 4) >= _TEX // 4 - 2)   # grout, both edges
    tile = 1 + ((i[:, None] // (_TEX // 2) + i[None, :] // (_TEX // 2)) % 2)
    tile = np.where(g[:, None] | g[None, :], 0, tile).astype(np.uint8).ravel()
    stripe = np.where(i % (_TEX // 16) < _TEX // 32, 3, 4).astype(np.uint8)
    return tile, stripe


_TILE_CLASS, _STRIPE_CLASS = _ground_texture()


@dataclass
class Ground:
    """The ground texture's colours (3 x 5 float32: grout, dark tile, light tile, path
    stripe, path gap), texels per metre (the 256-texel tile repeats every 256 / that
    metres; at most 256 so float32 still floors to whole texels) and the striped path
    (|x - path_x| < path_half; path_half 0 for none)."""
    albedo: np.ndarray = field(default_factory=lambda: _GROUND_ALBEDO)
    texels_per_metre: float = _TEX / 2.0
    path_x: float = 0.4
    path_half: float = 0.9


DEFAULT_GROUND = Ground()
_BAND = 64   # rows per band: keeps the band's temporaries in cache


def _ground(view, A, B, rows):
    """Ground colour (3 planes) for image rows `rows` (a slice; all of them look below
    the horizon), shadows included. A (3, w), B (3, h) are the separable ray terms."""
    out = [np.empty((rows.stop - rows.start, len(A[0])), _F) for _ in range(3)]
    for r in range(rows.start, rows.stop, _BAND):
        band = slice(r, min(r + _BAND, rows.stop))
        col = _ground_band(view, A, B, band)
        for k in range(3):
            out[k][r - rows.start:band.stop - rows.start] = col[k]
    return out


def _ground_band(view, A, B, rows):
    o = view.cam.pos.tolist()
    b = [B[k][rows, None] for k in range(3)]
    t = -o[1] / b[1]                                     # per row
    x = (o[0] + t * b[0]) + t * A[0]
    z = (o[2] + t * b[2]) + t * A[2]
    return _ground_color(view, x, z, t, rows)


def _ground_class(g, x, z):
    """Texture class (index into g.albedo's columns) of ground points (x, 0, z)."""
    # float32 keeps 4 fractional bits at 2^20, enough to floor to whole texels.
    scale, off = _F(g.texels_per_metre), _F(2 ** 20)
    ix = (x * scale + off).astype(np.int32) & (_TEX - 1)
    iz = (z * scale + off).astype(np.int32) & (_TEX - 1)
    return np.where(np.abs(x - _F(g.path_x)) < g.path_half, np.take(_STRIPE_CLASS, iz),
                    np.take(_TILE_CLASS, (iz << 8) | ix))


def _ground_color(view, x, z, t, rows=None):
    """Ground colour (3 arrays shaped like x) at ground points (x, 0, z) seen at ray
    parameter t. `rows`: the image rows of a band (x, z are (rows, w) and the casters'
    screen rectangles crop the shadow tests), or None for arbitrary points."""
    g = view.ground
    cls = _ground_class(g, x, z)
    fog = np.exp(t * -HAZE)
    L = view.light.sun_dir.tolist()
    sun, ambient, hor = view.light.sun, view.light.ambient, view.light.horizon
    out = [hor[k] * (1 - fog) + np.take(g.albedo[k], cls) * (
        (sun[k] * L[1] + ambient[k]) * fog) for k in range(3)]
    for p, rect in view.casters:
        if rect is None:
            continue
        if rows is None:
            idx, f = (Ellipsis,), fog
        else:
            r0 = rows.start
            if rect[1] <= r0 or rect[0] >= rows.stop:
                continue
            a0, a1, c0, c1 = max(rect[0] - r0, 0), rect[1] - r0, rect[2], rect[3]
            idx, f = (slice(a0, a1), slice(c0, c1)), fog[a0:a1]
        shadow = p.occludes((x[idx], 0.0, z[idx]), L)
        if not shadow.any():
            continue
        for k in range(3):
            dark = hor[k] * (1 - f) + np.take(g.albedo[k], cls[idx]) * (
                ambient[k] * f)
            sub = out[k][idx]
            sub[shadow] = dark[shadow]
    return out


def _shade(o, hits, d, t, light=DEFAULT_LIGHT):
    """Colour (N, 3) of the gathered hit points of several primitives at once, for
    rays from o along d (3 arrays) at parameter t; `hits` lists (primitive, slice)."""
    SUN, AMBIENT = light.sun, light.ambient
    P = [o[j] + t * d[j] for j in range(3)]
    parts = [p.surface([q[s] for q in P], [q[s] for q in d]) for p, s in hits]
    n = np.concatenate([a for a, _ in parts])
    albedo = np.concatenate([b for _, b in parts])
    ks = np.concatenate([np.full(s.stop - s.start, p.spec[0], _F) for p, s in hits])
    shin = np.concatenate([np.full(s.stop - s.start, p.spec[1], _F) for p, s in hits])
    L = light.sun_dir.astype(_F)
    ndl = np.maximum(n @ L, 0)
    col = albedo * (ndl[:, None] * SUN + AMBIENT)
    dn = np.stack(d, -1)
    dn /= np.linalg.norm(dn, axis=-1, keepdims=True)
    h = L - dn
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    col += (ks * np.maximum(np.sum(n * h, -1), 0) ** shin * (ndl > 0))[:, None] * SUN
    for p, s in hits:
        if p.emission is not None:
            col[s] = p.emission
    fog = np.exp(t * -HAZE)[:, None]
    return light.horizon + (col - light.horizon) * fog


def _cast(view, us, vs):
    """The separable rays of _trace and their closest hits: (o, A, B, rg, tbest, ids)
    with o the camera position, A (3, w) and B (3, h) the ray terms (d = A[:, col] +
    B[:, row]), rg the first ground row, tbest (h, w) the ray parameter of the closest
    hit (inf for sky) and ids (h, w) its primitive (-1: ground or sky)."""
    cam, W, H = view.cam, view.w, view.h
    o = cam.pos.tolist()
    sx = ((2.0 / W) * us - 1.0) * _F(TAN_HALF_FOV * cam.aspect)
    sy = (1.0 - (2.0 / H) * vs) * _F(TAN_HALF_FOV)
    A = [(sx * _F(cam.right[k])).astype(_F) for k in range(3)]
    B = [(_F(cam.fwd[k]) + sy * _F(cam.up[k])).astype(_F) for k in range(3)]
    rg = int(np.argmax(B[1] < 0)) if (B[1] < 0).any() else H   # first ground row
    with np.errstate(divide="ignore"):
        trow = np.where(B[1] < 0, -o[1] / B[1], _F(np.inf)).astype(_F)
    tbest = np.repeat(trow[:, None], W, 1)
    ids = np.full((H, W), -1, np.int16)
    for k, p in enumerate(view.prims):
        rect = view.rects[k]
        if rect is None:
            continue
        r0, r1, c0, c1 = rect
        d = tuple(A[j][c0:c1] + B[j][r0:r1, None] for j in range(3))
        t = p.hit(o, d)
        tb, ib = tbest[r0:r1, c0:c1], ids[r0:r1, c0:c1]
        closer = t < tb
        tb[closer] = t[closer]
        ib[closer] = k
    return o, A, B, rg, tbest, ids


def _gather(view, ids):
    """The pixels each primitive won: (rr, cc, hits), rows and columns concatenated over
    the primitives and hits = [(primitive, slice of rr/cc)]; (None, None, []) if none."""
    sel, hits, n = [], [], 0
    for k, p in enumerate(view.prims):
        rect = view.rects[k]
        if rect is None:
            continue
        r0, r1, c0, c1 = rect
        rr, cc = np.nonzero(ids[r0:r1, c0:c1] == k)
        if rr.size:
            sel.append((rr + r0, cc + c0))
            hits.append((p, slice(n, n + rr.size)))
            n += rr.size
    if not hits:
        return None, None, hits
    return (np.concatenate([a for a, _ in sel]), np.concatenate([b for _, b in sel]), hits)


def _trace(view, us, vs, prev_cam=None, out=None, gbuffers=None):
    """Planar colour (3, h, w) for one sample per pixel taken at column positions
    us (w,) and row positions vs (h,) (each within +-1 pixel of the pixel centre);
    with prev_cam also view depth (h, w) and motion (h, w, 2). A dict `out` receives
    what labelling needs: "t" (view depth, inf for sky), "ids" (int16 index into
    view.prims, GROUND_ID or SKY_ID) and, with prev_cam, "prev_z" (the hit point's view
    depth in the previous frame). A dict `gbuffers` receives the G-buffers of the same
    samples (see _gbuffers; the colour, depth and motion do not change).

    Sample positions that vary per column and per row, not per pixel, make the ray
    directions separable, d = A[:, col] + B[:, row], and the ground depth a function
    of the row alone (the camera never rolls), which is what makes numpy fast here."""
    W, H = view.w, view.h
    o, A, B, rg, tbest, ids = _cast(view, us, vs)
    color = np.empty((3, H, W), _F)
    if rg > 0:
        color[:, :rg] = _sky([A[j] + B[j][:rg, None] for j in range(3)], view.light)
    if rg < H:
        color[:, rg:] = _ground(view, A, B, slice(rg, H))
    want_motion = prev_cam is not None
    if want_motion:
        far = np.where(np.isfinite(tbest), tbest, 1e7)
        prev = [o[j] + far * (A[j] + B[j][:, None]).astype(np.float64) for j in range(3)]
    rr, cc, hits = _gather(view, ids)
    if hits:
        t = tbest[rr, cc]
        dk = [A[j][cc] + B[j][rr] for j in range(3)]
        color[:, rr, cc] = _shade(o, hits, dk, t, view.light).T
        if want_motion:
            for p, s in hits:
                P = [o[j] + t[s].astype(np.float64) * dk[j][s] for j in range(3)]
                Pp = p.to_prev(P)
                for j in range(3):
                    prev[j][rr[s], cc[s]] = Pp[j]
    if gbuffers is not None:
        gbuffers.update(_gbuffers(view, o, A, B, rg, tbest, rr, cc, hits))
    if out is not None:
        out["t"] = tbest
        out["ids"] = np.where(np.isfinite(tbest), ids, np.int16(SKY_ID)).astype(np.int16)
    if not want_motion:
        return color, None, None
    up, vp, zp = prev_cam.project(prev[0], prev[1], prev[2], W, H)
    motion = np.stack([up - us[None, :], vp - vs[:, None]], -1).astype(_F)
    if out is not None:
        out["prev_z"] = zp
    return color, tbest, motion


def reversed_z(t):
    """View depth (inf where nothing was hit) -> the contract's reversed-Z depth,
    NEAR / z (near plane = 1, sky = 0), float32."""
    with np.errstate(divide="ignore"):
        return np.where(np.isfinite(t), _F(NEAR) / t, _F(0)).astype(_F)


def _gbuffers(view, o, A, B, rg, tbest, rr, cc, hits):
    """The G-buffers (clss.pipeline.contract.GBUFFERS) of the samples _cast traced:
    {"albedo": (h, w, 3) diffuse texture colour plus the scalar specular factor ks
    (the surface's, before haze; emitters keep theirs; 0 for sky), "normal": (h, w, 3)
    unit normal in camera space (+x right, +y up, +z toward the camera; 0 for sky),
    "depth": (h, w) reversed-Z as render_frame's}. The surfaces are evaluated again
    (not taken from _shade), so the colour path stays exactly as it was."""
    H, W = tbest.shape
    cam = view.cam
    to_cam = np.stack([cam.right, cam.up, -cam.fwd]).T.astype(_F)   # world row @ -> camera
    alb = np.zeros((H, W, 3), _F)
    nrm = np.zeros((H, W, 3), _F)
    if rg < H:
        table = np.ascontiguousarray(view.ground.albedo.T, _F)      # class -> RGB
        for r in range(rg, H, _BAND):
            band = slice(r, min(r + _BAND, H))
            b = [B[k][band, None] for k in range(3)]
            t = -o[1] / b[1]                   # as _ground_band: the same texels
            x = (o[0] + t * b[0]) + t * A[0]
            z = (o[2] + t * b[2]) + t * A[2]
            alb[band] = table[_ground_class(view.ground, x, z)]
        nrm[rg:] = np.array([0.0, 1.0, 0.0], _F) @ to_cam         # the ground faces up
    if hits:
        t = tbest[rr, cc]
        dk = [A[j][cc] + B[j][rr] for j in range(3)]
        P = [o[j] + t * dk[j] for j in range(3)]
        for p, s in hits:
            n, a = p.surface([q[s] for q in P], [q[s] for q in dk])
            n = np.asarray(n, _F)
            # Some surfaces' normals are only nearly unit (Cylinder without thin_safe).
            n = n / np.maximum(np.sqrt(np.sum(n * n, -1, keepdims=True)), _F(1e-12))
            alb[rr[s], cc[s]] = np.asarray(a, _F) + _F(p.spec[0])
            nrm[rr[s], cc[s]] = n @ to_cam
    return {"albedo": alb, "normal": nrm, "depth": reversed_z(tbest)}


def trace_gbuffers(view, us, vs):
    """The G-buffers (see _gbuffers) of one sample per pixel at column positions us and
    row positions vs, without shading: what a renderer's cheap full-resolution feature
    pass gives (the output-resolution G-buffers, at the output pixel centres)."""
    o, A, B, rg, tbest, ids = _cast(view, us, vs)
    rr, cc, hits = _gather(view, ids)
    return _gbuffers(view, o, A, B, rg, tbest, rr, cc, hits)


def trace_points(view, u, v):
    """Colour (N, 3), view depth t (N,) (inf for sky) and primitive ids (N,) (as
    _trace's) of one ray through each of the arbitrary continuous pixel positions u, v
    (N,) of `view`. Slower per ray than _trace (no separable rays, no screen
    rectangles); made for a few scattered positions, such as where the labeller asks
    what the previous frame saw at a point's reprojected position."""
    o = view.cam.pos.tolist()
    d = view.cam.rays(np.asarray(u, _F), np.asarray(v, _F), view.w, view.h)
    d = tuple(np.asarray(c, _F) for c in d)
    with np.errstate(divide="ignore"):
        tbest = np.where(d[1] < 0, -o[1] / d[1], np.inf).astype(_F)
    ids = np.full(tbest.shape, GROUND_ID, np.int16)
    for k, p in enumerate(view.prims):
        if view.rects[k] is None:     # nowhere on screen (positions are on screen)
            continue
        t = p.hit(o, d)
        closer = t < tbest
        tbest[closer] = t[closer]
        ids[closer] = k
    sky = ~np.isfinite(tbest)
    ids[sky] = SKY_ID
    color = np.empty(tbest.shape + (3,), _F)
    if sky.any():
        color[sky] = np.stack(_sky([c[sky] for c in d], view.light), -1)
    g = ids == GROUND_ID
    if g.any():
        tg = tbest[g]
        x = o[0] + tg * d[0][g]
        z = o[2] + tg * d[2][g]
        color[g] = np.stack(_ground_color(view, x, z, tg), -1)
    sel = [(p, np.nonzero(ids == k)[0]) for k, p in enumerate(view.prims)]
    sel = [(p, i) for p, i in sel if i.size]
    if sel:
        idx = np.concatenate([i for _, i in sel])
        bounds = np.cumsum([0] + [i.size for _, i in sel])
        hits = [(p, slice(bounds[m], bounds[m + 1])) for m, (p, _) in enumerate(sel)]
        color[idx] = _shade(o, hits, [c[idx] for c in d], tbest[idx], view.light)
    return color, tbest, ids


# ---------------------------------------------------------------- frames

def output_size(render_size, scale):
    """(H, W) of the reference frames: the contract's, the size clss.Upscaler outputs."""
    return contract_output_size(render_size[0], render_size[1], scale)


def render_frame(index, render_size=(270, 480), scale=2.0, spp_ref=16, seed=0,
                 gbuffers=True):
    """Frame `index` of the sequence (each frame is independent of the others).
    gbuffers=True fills Frame.gbuffers with every G-buffer of the contract (see
    `frame_gbuffers`); colour, depth, motion and the reference do not depend on it."""
    h, w = render_size
    H, W = output_size(render_size, scale)
    aspect = w / h
    prims = scene_at(float(index))
    cam, prev_cam = camera_at(float(index), aspect), camera_at(index - 1.0, aspect)
    jx, jy = halton_jitter(index, scale)
    us = np.arange(w, dtype=_F) + _F(0.5 + jx)
    vs = np.arange(h, dtype=_F) + _F(0.5 + jy)
    gb = {} if gbuffers else None
    color, z, motion = _trace(_View(prims, cam, w, h), us, vs, prev_cam, gbuffers=gb)
    with np.errstate(divide="ignore"):
        depth = np.where(np.isfinite(z), _F(NEAR) / z, _F(0)).astype(_F)
    out_view = _View(prims, cam, W, H)
    ref = None
    if spp_ref > 0:
        ref = render_reference(out_view, spp_ref, np.random.default_rng([seed, index]))
    return Frame(index=index, color=np.ascontiguousarray(color.transpose(1, 2, 0)),
                 depth=depth, motion=motion, jitter=(float(jx), float(jy)),
                 reset=index == 0, reference=ref,
                 meta={"scale": scale, "spp_ref": spp_ref, "near": NEAR},
                 gbuffers={} if gb is None else frame_gbuffers(gb, out_view))


def frame_gbuffers(render_gb, out_view):
    """Every G-buffer of the contract for one frame: albedo and normal from `render_gb`
    (what _trace(..., gbuffers=) gave for the render-resolution samples, at the jittered
    positions, like the colour), albedo_hr, depth_hr and normal_hr traced at the output
    pixel centres of `out_view` (unjittered, one sample per output pixel, no shading:
    the cheap full-resolution feature pass a renderer would add). Conventions in
    _gbuffers and docs/input-contract.md section 5."""
    hr = trace_gbuffers(out_view, np.arange(out_view.w, dtype=_F) + _F(0.5),
                        np.arange(out_view.h, dtype=_F) + _F(0.5))
    return {"albedo": render_gb["albedo"], "normal": render_gb["normal"],
            "albedo_hr": hr["albedo"], "depth_hr": hr["depth"], "normal_hr": hr["normal"]}


def render_reference(view, spp, rng, on_sample=None):
    """Box-filtered reference: gx x gy strata per pixel (gx * gy >= spp), one sample
    in each at a random position inside the stratum. The random offset is drawn per
    column (x) and per row (y) for each stratum (see _trace), which keeps the samples
    stratified and breaks up the regular-grid moire. `on_sample(color, out)`, if given,
    sees each sample pass: planar colour (3, H, W) and _trace's `out` dict."""
    gx = int(math.ceil(math.sqrt(spp)))
    gy = int(math.ceil(spp / gx))
    H, W = view.h, view.w
    cols, rows = np.arange(W, dtype=_F), np.arange(H, dtype=_F)
    acc = np.zeros((3, H, W), _F)
    for sy in range(gy):
        for sx in range(gx):
            us = cols + (sx + rng.random(W, _F)) * _F(1 / gx)
            vs = rows + (sy + rng.random(H, _F)) * _F(1 / gy)
            out = None if on_sample is None else {}
            c = _trace(view, us, vs, out=out)[0]
            acc += c
            if on_sample is not None:
                on_sample(c, out)
    acc *= _F(1.0 / (gx * gy))
    return np.ascontiguousarray(acc.transpose(1, 2, 0))


def iter_sequence(n_frames=30, render_size=(270, 480), scale=2.0, spp_ref=16, seed=0,
                  workers=1, gbuffers=True):
    """Frames one at a time, in order. `workers` > 1 renders that many frames ahead in
    worker processes (frames are independent). gbuffers=False leaves Frame.gbuffers
    empty (a little faster; nothing else changes)."""
    args = (render_size, scale, spp_ref, seed, gbuffers)
    if workers <= 1 or n_frames <= 1:
        for i in range(n_frames):
            yield render_frame(i, *args)
        return
    from concurrent.futures import ProcessPoolExecutor
    with ProcessPoolExecutor(min(workers, n_frames)) as pool:
        pending = [pool.submit(render_frame, i, *args) for i in range(n_frames)]
        for fut in pending:
            yield fut.result()


def render_sequence(n_frames=30, render_size=(270, 480), scale=2.0, spp_ref=16, seed=0,
                    workers=1, gbuffers=True):
    """List of `n_frames` Frames (`iter_sequence` holds one at a time). Frame 0 has
    reset=True. Deterministic; the seed only moves the reference's sample positions.
    The default (480x270 -> 960x540, 16 spp, 30 frames) takes about 20 s of one core;
    `workers=2` splits it over two processes. Frame.gbuffers holds every G-buffer
    unless gbuffers=False."""
    return list(iter_sequence(n_frames, render_size, scale, spp_ref, seed, workers,
                              gbuffers))
