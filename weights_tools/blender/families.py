"""Seeded, randomised Blender scene families: the training, validation and test data of
issue 31, rendered by weights_tools.blender.shards (bpy, the [data] extra).

A family is a function `build(scene, frames, rnd)` that fills an empty Cycles scene
(render_validation.new_scene) with procedural assets only (primitives, generated meshes,
Blender's built-in font and procedural textures: nothing is downloaded), keyframes every
frame (Cycles' Vector pass is then exact) and returns (description, cuts): cuts are the
0-based frames that start a new camera shot (recorded as resets). `rnd` is a
random.Random seeded by the shard's seed, the only source of randomness, so a (family,
seed) pair gives the same scene on every machine.

Families (FAMILIES) and where they go (SPLITS): whole families are held out for the test
split, so no test family's assets (its meshes, materials, layouts) appear in training or
validation; validation uses the training families with seeds from its own range.
  * foliage: bushes of alpha-cut leaves (UV leaf masks) swaying, grass blades;
  * wires: sub-pixel wires, poles, alpha-cut chain-link fences (brick-mortar masks);
  * text: fine text (Blender's built-in font) and fine procedural textures on walls;
  * materials: glossy, metallic and emissive (HDR) objects turning on a checker floor;
  * cuts: fast camera pans and hard cuts between shots of a cluttered field;
  * movers: objects crossing fast against a camera moving the other way;
  * interior (test): rooms with pillars, shelves and a doorway occluding as the camera
    walks past;
  * particles (test): hundreds of small falling/swirling particles, some emissive.
"""
from __future__ import annotations

import math

from . import render_validation as rv

TEST_FAMILIES = ("interior", "particles")
# First seed of each split; a split's sequence k of a family has seed SEED_BASE[split] + k.
SEED_BASE = {"train": 0, "validation": 100_000, "test": 200_000}


# ---------------------------------------------------------------- shared pieces

def _rcolor(rnd, lo=0.05, hi=0.9):
    return tuple(rnd.uniform(lo, hi) for _ in range(3))


def _textured(rnd, name, fine=False):
    """A Principled material with a random procedural texture (fine: high frequency)."""
    tex = rnd.choice(("brick", "checker", "wave", "noise", "planks"))
    scale = rnd.uniform(20, 60) if fine else rnd.uniform(2, 12)
    return rv.material(name, _rcolor(rnd), rnd.uniform(0.2, 0.9), tex, scale, _rcolor(rnd))


def _keys(frames):
    return range(0, frames + 2)


def _sun(scene, rnd, energy=(2.0, 4.0)):
    sun = rv.bpy.data.lights.new("sun", "SUN")
    sun.energy, sun.angle = rnd.uniform(*energy), math.radians(1.0)
    so = rv.bpy.data.objects.new("sun", sun)
    scene.collection.objects.link(so)
    so.rotation_euler = (math.radians(rnd.uniform(25, 60)), 0, rnd.uniform(0, 2 * math.pi))
    return so


def _ground(rnd, size=80):
    return rv.add("primitive_plane_add", _textured(rnd, "ground"), "ground", size=size)


def _moving_camera(scene, keys, rnd, start, target, speed=0.1, lens=(55, 80)):
    """Camera at `start` looking at `target`, both drifting with random velocities."""
    cam, tgt = rv.camera(scene, rnd.uniform(*lens))
    v = [rnd.uniform(-1, 1) * speed for _ in range(3)]
    vt = [rnd.uniform(-1, 1) * speed * 0.6 for _ in range(3)]
    v[2] *= 0.2
    rv.key(cam, keys, location=lambda f: tuple(s + d * f for s, d in zip(start, v)))
    rv.key(tgt, keys, location=lambda f: tuple(s + d * f for s, d in zip(target, vt)))
    return cam, tgt


def _cutout_material(name, color, mask, scale=1.0, rough=0.6):
    """Alpha-tested material: opaque where the mask is 1, fully transparent elsewhere (a
    hard threshold, as a game's alpha test). mask: "leaf" (an ellipse in the face's UV
    square) or "grid" (a square wire grid: the mortar of a brick texture, object space)."""
    m = rv.material(name, color, rough)
    nt = m.node_tree
    bsdf = nt.nodes["Principled BSDF"]
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.interpolation = "CONSTANT"
    if mask == "leaf":
        coord = nt.nodes.new("ShaderNodeTexCoord")
        mapping = nt.nodes.new("ShaderNodeMapping")
        mapping.inputs["Location"].default_value = (-1.0, -2.0, 0.0)
        mapping.inputs["Scale"].default_value = (2.0, 4.0, 1.0)
        grad = nt.nodes.new("ShaderNodeTexGradient")
        grad.gradient_type = "SPHERICAL"
        nt.links.new(coord.outputs["UV"], mapping.inputs["Vector"])
        nt.links.new(mapping.outputs["Vector"], grad.inputs["Vector"])
        nt.links.new(grad.outputs["Fac"], ramp.inputs["Fac"])
        ramp.color_ramp.elements[1].position = 0.02
    else:
        coord = nt.nodes.new("ShaderNodeTexCoord")
        brick = nt.nodes.new("ShaderNodeTexBrick")
        brick.offset = 0.0
        brick.inputs["Scale"].default_value = scale
        brick.inputs["Mortar Size"].default_value = 0.04
        brick.inputs["Brick Width"].default_value = 0.5
        brick.inputs["Row Height"].default_value = 0.5
        nt.links.new(coord.outputs["Object"], brick.inputs["Vector"])
        nt.links.new(brick.outputs["Fac"], ramp.inputs["Fac"])
        ramp.color_ramp.elements[1].position = 0.5
    nt.links.new(ramp.outputs["Color"], bsdf.inputs["Alpha"])
    return m


def _uv_quads(name, verts, faces, mat):
    """A mesh of quads, each with the full UV square (leaf masks are drawn in it)."""
    obj = rv.mesh_object(name, verts, faces, mat)
    uv = obj.data.uv_layers.new(name="UVMap")
    corners = ((0, 0), (1, 0), (1, 1), (0, 1))
    for poly in obj.data.polygons:
        for k, li in enumerate(poly.loop_indices):
            uv.data[li].uv = corners[k % 4]
    return obj


# ---------------------------------------------------------------- families

def foliage(scene, frames, rnd):
    rv.set_world(scene, (0.5, 0.65, 0.95), rnd.uniform(0.5, 1.2))
    keys = _keys(frames)
    _ground(rnd)
    _sun(scene, rnd)
    for b in range(rnd.randint(2, 4)):
        cx, cy = rnd.uniform(-2.5, 2.5), rnd.uniform(-1.5, 2.5)
        leaf = _cutout_material(f"leaf{b}", (rnd.uniform(0.05, 0.3), rnd.uniform(0.3, 0.6),
                                            rnd.uniform(0.02, 0.15)), "leaf")
        verts, faces = [], []
        for _ in range(rnd.randint(150, 300)):
            x = cx + rnd.gauss(0, 0.5)
            y = cy + rnd.gauss(0, 0.5)
            z = abs(rnd.gauss(1.0, 0.5)) + 0.1
            r, t = rnd.uniform(0.05, 0.12), rnd.uniform(0, 2 * math.pi)
            tilt = rnd.uniform(-0.8, 0.8)
            ux, uy = math.cos(t) * r, math.sin(t) * r
            n = len(verts)
            verts += [(x - ux, y - uy, z - tilt * r), (x + ux, y + uy, z - tilt * r),
                      (x + ux, y + uy, z + 2 * r), (x - ux, y - uy, z + 2 * r)]
            faces.append((n, n + 1, n + 2, n + 3))
        bush = _uv_quads(f"bush{b}", verts, faces, leaf)
        amp, ph = rnd.uniform(0.01, 0.05), rnd.uniform(0, 6.28)
        rv.key(bush, keys, rotation=lambda f, a=amp, p=ph: (a * math.sin(0.5 * f + p),
                                                             a * math.cos(0.4 * f + p), 0))
    grass = rv.material("grass", (0.25, 0.55, 0.12), 0.6)
    verts, faces = [], []
    for _ in range(rnd.randint(300, 800)):
        x, y = rnd.uniform(-5, 5), rnd.uniform(-1.5, 4)
        hgt, wid = rnd.uniform(0.15, 0.5), rnd.uniform(0.004, 0.012)
        a = rnd.uniform(0, 6.28)
        n = len(verts)
        verts += [(x - math.cos(a) * wid, y - math.sin(a) * wid, 0),
                  (x + math.cos(a) * wid, y + math.sin(a) * wid, 0),
                  (x + rnd.uniform(-0.1, 0.1), y + rnd.uniform(-0.1, 0.1), hgt)]
        faces.append((n, n + 1, n + 2))
    rv.mesh_object("grass", verts, faces, grass)
    _moving_camera(scene, keys, rnd, (rnd.uniform(-1, 1), 6.0, rnd.uniform(0.6, 1.6)),
                   (0, 0.5, 0.9), speed=0.08)
    return "bushes of alpha-cut leaves swaying, grass blades; drifting camera", ()


def wires(scene, frames, rnd):
    rv.set_world(scene, _rcolor(rnd, 0.4, 1.0), rnd.uniform(0.6, 1.2))
    keys = _keys(frames)
    _ground(rnd)
    _sun(scene, rnd)
    steel = rv.material("steel", (0.6, 0.6, 0.62), rnd.uniform(0.2, 0.5), metallic=1.0)
    dark = rv.material("wire", _rcolor(rnd, 0.02, 0.2), 0.5)
    yaw = rnd.uniform(-0.4, 0.4)
    for m in range(rnd.randint(3, 8)):              # cables (radius 2-8 mm: sub-pixel)
        rv.add("primitive_cylinder_add", dark, "cable", radius=rnd.uniform(0.002, 0.008),
               depth=40.0, location=(0, rnd.uniform(-6, 2), rnd.uniform(1.5, 4.0)),
               rotation=(0, math.pi / 2, yaw + rnd.uniform(-0.1, 0.1)))
    for k in range(rnd.randint(4, 10)):              # poles
        rv.add("primitive_cylinder_add", steel, "pole", radius=rnd.uniform(0.01, 0.04),
               depth=3.0, location=(rnd.uniform(-6, 6), rnd.uniform(-4, 1), 1.5))
    for k in range(rnd.randint(1, 3)):              # chain-link fences
        fence = _cutout_material(f"fence{k}", _rcolor(rnd, 0.3, 0.8), "grid",
                                 scale=rnd.uniform(4, 12), rough=0.4)
        rv.add("primitive_plane_add", fence, "fence", size=1,
               location=(rnd.uniform(-2, 2), rnd.uniform(-1, 2), 1.0),
               scale=(rnd.uniform(4, 8), 2.0, 1), rotation=(math.pi / 2, 0, rnd.uniform(-0.5, 0.5)))
    for k in range(rnd.randint(2, 5)):              # something behind
        rv.add("primitive_cube_add", _textured(rnd, f"block{k}"), "block", size=1,
               location=(rnd.uniform(-6, 6), rnd.uniform(-8, -3), 1.0),
               scale=(rnd.uniform(1, 3), rnd.uniform(1, 3), rnd.uniform(1, 4)))
    _moving_camera(scene, keys, rnd, (rnd.uniform(-2, 2), 6.0, rnd.uniform(1.0, 2.2)),
                   (0, -1, 1.5), speed=0.12)
    return "sub-pixel cables, thin poles, alpha-cut chain-link fences; moving camera", ()


WORDS = ("CLSS", "Cycles", "temporal", "supersampling", "jitter", "motion", "depth",
         "albedo", "0123456789", "Blender", "fence", "glyph", "raster", "OpenCL")


def text(scene, frames, rnd):
    rv.set_world(scene, _rcolor(rnd, 0.3, 0.9), rnd.uniform(0.5, 1.0))
    keys = _keys(frames)
    _ground(rnd)
    _sun(scene, rnd)
    for k in range(3):
        rv.add("primitive_cube_add", _textured(rnd, f"wall{k}", fine=True), "wall", size=1,
               location=(-4 + 4 * k, -2.0 - rnd.uniform(0, 1.5), 1.5),
               scale=(4.0, 0.1, 3.0), rotation=(0, 0, rnd.uniform(-0.3, 0.3)))
    ink = [rv.material(f"ink{k}", _rcolor(rnd, 0.0, 0.9), 0.5) for k in range(3)]
    for k in range(rnd.randint(6, 14)):
        cu = rv.bpy.data.curves.new(f"text{k}", type="FONT")
        cu.body = " ".join(rnd.choice(WORDS) for _ in range(rnd.randint(1, 3)))
        cu.size = rnd.uniform(0.06, 0.35)
        cu.extrude = 0.005
        ob = rv.bpy.data.objects.new(f"text{k}", cu)
        scene.collection.objects.link(ob)
        ob.data.materials.append(rnd.choice(ink))
        ob.location = (rnd.uniform(-5, 4), rnd.uniform(-1.8, 0.5), rnd.uniform(0.2, 2.6))
        ob.rotation_euler = (math.pi / 2, 0, math.pi + rnd.uniform(-0.3, 0.3))   # faces +y
    _moving_camera(scene, keys, rnd, (rnd.uniform(-1, 1), 4.0, 1.4), (0, -2, 1.3),
                   speed=0.06)
    return "fine text (built-in font) and fine procedural textures on walls; dolly/pan", ()


def materials(scene, frames, rnd):
    rv.set_world(scene, _rcolor(rnd, 0.2, 1.0), rnd.uniform(0.3, 1.5))
    keys = _keys(frames)
    rv.add("primitive_plane_add", rv.material("floor", (0.8, 0.8, 0.8), 0.3, "checker",
                                              rnd.uniform(1, 4), (0.1, 0.1, 0.1)), size=40)
    _sun(scene, rnd)
    ops = ("primitive_uv_sphere_add", "primitive_cube_add", "primitive_torus_add",
           "primitive_ico_sphere_add", "primitive_cylinder_add")
    for k in range(rnd.randint(5, 10)):
        kind = rnd.random()
        if kind < 0.35:
            m = rv.material(f"gloss{k}", _rcolor(rnd), rnd.uniform(0.02, 0.15))
        elif kind < 0.7:
            m = rv.material(f"metal{k}", _rcolor(rnd, 0.5, 1.0), rnd.uniform(0.05, 0.4),
                            metallic=1.0)
        else:
            m = rv.material(f"emit{k}", _rcolor(rnd, 0.1, 0.5), 0.5,
                            emission=_rcolor(rnd, 0.3, 1.0), strength=rnd.uniform(5, 40))
        ob = rv.add(rnd.choice(ops), m, f"obj{k}",
                    location=(rnd.uniform(-3, 3), rnd.uniform(-3, 1), rnd.uniform(0.4, 1.2)))
        ob.scale = (rnd.uniform(0.3, 0.7),) * 3
        w = [rnd.uniform(-0.15, 0.15) for _ in range(3)]
        rv.key(ob, keys, rotation=lambda f, w=w: tuple(a * f for a in w))
    r, h = rnd.uniform(6, 8), rnd.uniform(1.0, 2.5)
    a0, da = rnd.uniform(0, 6.28), rnd.uniform(-0.06, 0.06)
    cam, tgt = rv.camera(scene, rnd.uniform(50, 70))
    rv.key(cam, keys, location=lambda f: (r * math.cos(a0 + da * f), r * math.sin(a0 + da * f), h))
    rv.key(tgt, keys, location=lambda f: (0, -1, 0.6))
    return "glossy, metallic and emissive (HDR) objects turning; orbiting camera", ()


def cuts(scene, frames, rnd):
    rv.set_world(scene, _rcolor(rnd, 0.3, 1.0), rnd.uniform(0.5, 1.2))
    keys = _keys(frames)
    _ground(rnd)
    _sun(scene, rnd)
    ops = ("primitive_cube_add", "primitive_uv_sphere_add", "primitive_cylinder_add")
    for k in range(rnd.randint(12, 24)):
        ob = rv.add(rnd.choice(ops), _textured(rnd, f"obj{k}"), f"obj{k}",
                    location=(rnd.uniform(-8, 8), rnd.uniform(-8, 8), rnd.uniform(0.3, 1.5)))
        ob.scale = (rnd.uniform(0.2, 1.0), rnd.uniform(0.2, 1.0), rnd.uniform(0.3, 1.5))
    n = rnd.randint(2, 3)
    starts = sorted(rnd.sample(range(3, max(frames - 2, 4)), min(n - 1, max(frames - 5, 0))))
    bounds = [0] + starts + [frames + 2]
    shots = []
    for _ in range(len(bounds) - 1):
        a, r = rnd.uniform(0, 6.28), rnd.uniform(5, 9)
        shots.append(((r * math.cos(a), r * math.sin(a), rnd.uniform(0.8, 2.5)),
                      rnd.uniform(0.04, 0.12) * rnd.choice((-1, 1))))    # fast pans

    def shot(f):
        k = max(i for i in range(len(bounds) - 1) if bounds[i] <= f)
        return k, f - bounds[k]
    cam, tgt = rv.camera(scene, rnd.uniform(55, 75))
    rv.key(cam, keys, location=lambda f: shots[shot(f)[0]][0])

    def look(f):
        k, g = shot(f)
        (x, y, z), w = shots[k]
        a = math.atan2(-y, -x) + w * g
        return (x + 5 * math.cos(a), y + 5 * math.sin(a), 0.8)
    rv.key(tgt, keys, location=look)
    # Constant interpolation: a cut is a jump, not a sweep through the frames between.
    for ob in (cam, tgt):
        for fc in _fcurves(ob):
            for kp in fc.keyframe_points:
                kp.interpolation = "CONSTANT"
    return f"fast camera pans and {len(starts)} hard cuts in a cluttered field", tuple(starts)


def _fcurves(ob):
    """An object's F-curves (Blender 5 keeps them in layered actions' channelbags)."""
    act = ob.animation_data.action
    if hasattr(act, "fcurves"):
        return list(act.fcurves)
    out = []
    for layer in act.layers:
        for strip in layer.strips:
            for bag in strip.channelbags:
                out += list(bag.fcurves)
    return out


def movers(scene, frames, rnd):
    rv.set_world(scene, _rcolor(rnd, 0.3, 1.0), rnd.uniform(0.5, 1.2))
    keys = _keys(frames)
    _ground(rnd)
    _sun(scene, rnd)
    for k in range(rnd.randint(3, 6)):               # textured backdrop
        rv.add("primitive_cube_add", _textured(rnd, f"back{k}", fine=rnd.random() < 0.5),
               "back", size=1, location=(-8 + 4 * k, -6, 1.5), scale=(4, 0.2, 3))
    direction = rnd.choice((-1, 1))
    ops = ("primitive_cube_add", "primitive_uv_sphere_add", "primitive_cylinder_add")
    for k in range(rnd.randint(3, 7)):
        ob = rv.add(rnd.choice(ops), _textured(rnd, f"mover{k}"), f"mover{k}")
        ob.scale = (rnd.uniform(0.3, 1.0),) * 3
        x0, y, z = rnd.uniform(-6, 6), rnd.uniform(-3, 1.5), rnd.uniform(0.4, 1.5)
        v = direction * rnd.uniform(0.15, 0.5)
        w = rnd.uniform(-0.3, 0.3)
        rv.key(ob, keys, location=lambda f, x0=x0, y=y, z=z, v=v: (x0 + v * f, y, z),
               rotation=lambda f, w=w: (0, 0, w * f))
    cam, tgt = rv.camera(scene, rnd.uniform(55, 75))
    vc = -direction * rnd.uniform(0.05, 0.15)
    z = rnd.uniform(0.8, 2.0)
    rv.key(cam, keys, location=lambda f: (vc * f, 6.0, z))
    rv.key(tgt, keys, location=lambda f: (vc * f * 0.5, -2.0, 0.9))
    return "objects crossing fast against a camera trucking the other way", ()


def interior(scene, frames, rnd):
    rv.set_world(scene, (0.6, 0.7, 0.9), 0.3)
    keys = _keys(frames)
    W, D, H = rnd.uniform(6, 10), rnd.uniform(6, 10), rnd.uniform(2.6, 3.6)
    rv.add("primitive_plane_add", _textured(rnd, "floor"), "floor", size=1, scale=(W, D, 1))
    rv.add("primitive_plane_add", _textured(rnd, "ceiling"), "ceiling", size=1,
           location=(0, 0, H), scale=(W, D, 1), rotation=(math.pi, 0, 0))
    wall = _textured(rnd, "wall")
    for (x, y, sx, sy) in ((0, -D / 2, W, 0.1), (0, D / 2, W, 0.1), (-W / 2, 0, 0.1, D),
                           (W / 2, 0, 0.1, D)):
        rv.add("primitive_cube_add", wall, "wall", size=1, location=(x, y, H / 2),
               scale=(sx, sy, H))
    # A partition with a doorway: the camera walks past it (disocclusions).
    door = rnd.uniform(-1, 1)
    for (y0, y1) in ((-D / 2, door - 0.5), (door + 0.5, D / 2)):
        rv.add("primitive_cube_add", wall, "partition", size=1,
               location=(rnd.uniform(-0.5, 0.5), (y0 + y1) / 2, H / 2), scale=(0.15, y1 - y0, H))
    pillar = _textured(rnd, "pillar")
    for k in range(rnd.randint(3, 6)):
        rv.add("primitive_cylinder_add", pillar, "pillar", radius=rnd.uniform(0.1, 0.25),
               depth=H, location=(rnd.uniform(-W / 2 + 0.5, W / 2 - 0.5),
                                  rnd.uniform(-D / 2 + 0.5, D / 2 - 0.5), H / 2))
    shelf = rv.material("shelf", _rcolor(rnd, 0.2, 0.6), 0.5)
    for k in range(rnd.randint(2, 4)):
        x, y = rnd.uniform(-W / 2 + 1, W / 2 - 1), rnd.uniform(-D / 2 + 0.3, -D / 2 + 1)
        for s in range(4):
            rv.add("primitive_cube_add", shelf, "board", size=1,
                   location=(x, y, 0.3 + 0.45 * s), scale=(1.2, 0.35, 0.03))
            for b in range(rnd.randint(2, 6)):
                rv.add("primitive_cube_add", _textured(rnd, f"book{k}{s}{b}", fine=True),
                       "book", size=1, location=(x - 0.5 + 0.14 * b, y, 0.43 + 0.45 * s),
                       scale=(0.05, 0.25, rnd.uniform(0.15, 0.25)))
    for k in range(2):
        area = rv.bpy.data.lights.new(f"area{k}", "AREA")
        area.energy, area.size = rnd.uniform(150, 400), 0.5
        ao = rv.bpy.data.objects.new(f"area{k}", area)
        scene.collection.objects.link(ao)
        ao.location = (rnd.uniform(-W / 3, W / 3), rnd.uniform(-D / 3, D / 3), H - 0.05)
    lamp = rv.material("lamp", (1, 1, 1), emission=(1.0, 0.85, 0.6), strength=rnd.uniform(5, 20))
    rv.add("primitive_uv_sphere_add", lamp, "lamp", radius=0.1,
           location=(rnd.uniform(-2, 2), rnd.uniform(-2, 2), 1.2))
    x0, x1 = -W / 2 + 0.8, W / 2 - 0.8
    y = rnd.uniform(D / 4, D / 2 - 0.6)
    step = rnd.uniform(0.03, 0.1) * rnd.choice((-1, 1))        # metres per frame
    xs = x0 if step > 0 else x1
    cam, tgt = rv.camera(scene, rnd.uniform(70, 85))
    z = rnd.uniform(1.4, 1.7)
    rv.key(cam, keys, location=lambda f: (xs + step * f, y, z))
    rv.key(tgt, keys, location=lambda f: (xs + step * f * 0.5, -D / 2, 1.2))
    return "room with a doorway partition, pillars, shelves of books; camera walks past", ()


def particles(scene, frames, rnd):
    rv.set_world(scene, _rcolor(rnd, 0.05, 0.5), rnd.uniform(0.3, 1.0))
    keys = _keys(frames)
    _ground(rnd)
    _sun(scene, rnd, (1.0, 3.0))
    for k in range(rnd.randint(2, 4)):
        rv.add("primitive_cube_add", _textured(rnd, f"back{k}"), "back", size=1,
               location=(-6 + 4 * k, -5, 1.5), scale=(3.5, 0.2, 3))
    mesh_op = rnd.choice(("primitive_ico_sphere_add", "primitive_cube_add"))
    proto = rv.add(mesh_op, rv.material("snow", (0.9, 0.9, 0.95), 0.4), "proto",
                   location=(0, 0, -50))
    proto.scale = (0.03, 0.03, 0.03)
    spark = rv.material("spark", (1, 0.6, 0.2), 0.5, emission=(1.0, 0.55, 0.15),
                        strength=rnd.uniform(10, 40))
    sparks = proto.data.copy()
    sparks.materials.clear()
    sparks.materials.append(spark)
    swirl = rnd.uniform(0.0, 0.3)
    for k in range(rnd.randint(150, 300)):
        ob = rv.bpy.data.objects.new(f"p{k}", sparks if k % 5 == 0 else proto.data)
        scene.collection.objects.link(ob)
        s = rnd.uniform(0.01, 0.04)
        ob.scale = (s, s, s)
        x0, y0, z0 = rnd.uniform(-4, 4), rnd.uniform(-3, 2), rnd.uniform(0.8, 4.5)
        vz, ph = -rnd.uniform(0.02, 0.12), rnd.uniform(0, 6.28)
        rv.key(ob, keys, location=lambda f, x0=x0, y0=y0, z0=z0, vz=vz, ph=ph: (
            x0 + swirl * math.sin(0.3 * f + ph), y0 + swirl * math.cos(0.3 * f + ph),
            z0 + vz * f))
    _moving_camera(scene, keys, rnd, (rnd.uniform(-1, 1), 5.0, 1.5), (0, -1, 1.5), speed=0.06)
    return "hundreds of small falling/swirling particles, some emissive; drifting camera", ()


FAMILIES = {"foliage": foliage, "wires": wires, "text": text, "materials": materials,
            "cuts": cuts, "movers": movers, "interior": interior, "particles": particles}
SPLITS = {"train": tuple(f for f in FAMILIES if f not in TEST_FAMILIES),
          "validation": tuple(f for f in FAMILIES if f not in TEST_FAMILIES),
          "test": TEST_FAMILIES}


def builder(family, seed):
    """build(scene, frames) for render_validation.render_scene: family `family` drawn with
    random.Random(seed)."""
    import random
    fn = FAMILIES[family]
    return lambda scene, frames: fn(scene, frames, random.Random(f"{family}:{seed}"))
