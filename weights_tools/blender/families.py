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
  * particles (test): hundreds of small falling/swirling particles, some emissive;
  * game (held out, rendered on request: `--split test --families game`): an engine's
    pre-upscale frame (issue 53 part 4): a rolling terrain and props (crates, barrels,
    rocks, ruined walls) in procedural PBR materials (noise, voronoi and multifractal
    noise driving albedo, roughness, metallic and bump), instanced trees of alpha-cut
    leaves and grass tufts out to 40 m, lamp posts with HDR emissive bulbs, blinking
    beacons, rising emissive sparks over fire pits; the camera runs and pans fast and cuts
    hard between shots (resets). No post effects: no motion blur, no depth of field, no
    bloom (Cycles has none), linear output.
"""
from __future__ import annotations

import math

from . import render_validation as rv

TEST_FAMILIES = ("interior", "particles")
# Held out as well, but not in the test split's default families (make train-data-blender's
# test split and its scores stay as they were): rendered with --families game
# (make validation-data-game).
GAME_FAMILIES = ("game",)
HELD_OUT = TEST_FAMILIES + GAME_FAMILIES
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


# ---------------------------------------------------------------- game (issue 53 part 4)

def _pbr(rnd, name, base, kind="painted", scale=None, bump=None):
    """A procedural PBR material, textured in object coordinates (so it moves with its
    object): albedo from noise and voronoi through a colour ramp, roughness from another
    noise mapped into a range, metallic from a voronoi scratch mask ("metal", "painted":
    metal showing through worn paint), and a bump from multifractal noise or voronoi cells.
    kind: "terrain", "stone", "wood", "metal", "painted", "rock"."""
    m = rv.material(name, base, 0.5)
    nt = m.node_tree
    N = nt.nodes.new
    bsdf = nt.nodes["Principled BSDF"]
    coord = N("ShaderNodeTexCoord")
    vec = coord.outputs["Object"]
    scale = scale or {"terrain": 0.35, "stone": 3.0, "wood": 4.0, "metal": 6.0,
                      "painted": 5.0, "rock": 2.5}[kind]
    # albedo: two colours of a ramp over fBm noise, darkened in voronoi cracks
    noise = N("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = scale * rnd.uniform(0.8, 1.25)
    noise.inputs["Detail"].default_value = 8.0
    noise.inputs["Roughness"].default_value = rnd.uniform(0.5, 0.7)
    nt.links.new(vec, noise.inputs["Vector"])
    ramp = N("ShaderNodeValToRGB")
    dark = tuple(c * rnd.uniform(0.25, 0.55) for c in base)
    ramp.color_ramp.elements[0].position = rnd.uniform(0.3, 0.45)
    ramp.color_ramp.elements[0].color = (*dark, 1.0)
    ramp.color_ramp.elements[1].position = rnd.uniform(0.55, 0.7)
    ramp.color_ramp.elements[1].color = (*base, 1.0)
    nt.links.new(noise.outputs["Fac"], ramp.inputs["Fac"])
    vor = N("ShaderNodeTexVoronoi")
    vor.feature = "DISTANCE_TO_EDGE"
    vor.inputs["Scale"].default_value = scale * rnd.uniform(1.5, 3.0)
    nt.links.new(vec, vor.inputs["Vector"])
    crack = N("ShaderNodeMapRange")          # 0 in a crack, 1 elsewhere
    crack.inputs["From Min"].default_value = 0.0
    crack.inputs["From Max"].default_value = rnd.uniform(0.03, 0.08)
    nt.links.new(vor.outputs["Distance"], crack.inputs["Value"])
    mul = N("ShaderNodeMix")
    mul.data_type = "RGBA"
    mul.blend_type = "MULTIPLY"
    mul.inputs["Factor"].default_value = {"stone": 0.6, "rock": 0.6, "terrain": 0.3}.get(kind, 0.25)
    nt.links.new(ramp.outputs["Color"], mul.inputs["A"])
    nt.links.new(crack.outputs["Result"], mul.inputs["B"])
    nt.links.new(mul.outputs["Result"], bsdf.inputs["Base Color"])
    # roughness: a second noise mapped into the material's range
    rough = N("ShaderNodeTexNoise")
    rough.inputs["Scale"].default_value = scale * rnd.uniform(2.0, 4.0)
    nt.links.new(vec, rough.inputs["Vector"])
    rmap = N("ShaderNodeMapRange")
    lo, hi = {"terrain": (0.7, 0.95), "stone": (0.5, 0.9), "wood": (0.4, 0.8),
              "metal": (0.12, 0.4), "painted": (0.25, 0.6), "rock": (0.55, 0.9)}[kind]
    rmap.inputs["To Min"].default_value, rmap.inputs["To Max"].default_value = lo, hi
    nt.links.new(rough.outputs["Fac"], rmap.inputs["Value"])
    nt.links.new(rmap.outputs["Result"], bsdf.inputs["Roughness"])
    # metallic: all metal, or bare metal in voronoi scratches through worn paint
    if kind == "metal":
        bsdf.inputs["Metallic"].default_value = 1.0
    elif kind == "painted":
        wear = N("ShaderNodeTexVoronoi")
        wear.feature = "F1"
        wear.inputs["Scale"].default_value = scale * rnd.uniform(3, 6)
        nt.links.new(vec, wear.inputs["Vector"])
        mask = N("ShaderNodeMath")
        mask.operation = "LESS_THAN"
        mask.inputs[1].default_value = rnd.uniform(0.08, 0.18)
        nt.links.new(wear.outputs["Distance"], mask.inputs[0])
        nt.links.new(mask.outputs["Value"], bsdf.inputs["Metallic"])
    # bump: multifractal noise (the former Musgrave), or the voronoi cracks
    if kind in ("stone", "rock", "wood") or (kind == "terrain" and rnd.random() < 0.5):
        height = vor.outputs["Distance"] if kind == "stone" else None
    else:
        height = None
    if height is None:
        mf = N("ShaderNodeTexNoise")
        if hasattr(mf, "noise_type"):
            mf.noise_type = rnd.choice(("RIDGED_MULTIFRACTAL", "HETERO_TERRAIN", "FBM"))
        mf.inputs["Scale"].default_value = scale * rnd.uniform(1.5, 3.0)
        mf.inputs["Detail"].default_value = 6.0
        nt.links.new(vec, mf.inputs["Vector"])
        height = mf.outputs["Fac"]
    b = N("ShaderNodeBump")
    b.inputs["Strength"].default_value = bump if bump is not None else rnd.uniform(0.2, 0.6)
    b.inputs["Distance"].default_value = 0.05
    nt.links.new(height, b.inputs["Height"])
    nt.links.new(b.outputs["Normal"], bsdf.inputs["Normal"])
    return m


def _terrain(rnd, size=90.0, n=72):
    """A rolling terrain: a grid mesh displaced by a few seeded sine waves; returns
    (object, height(x, y))."""
    waves = [(rnd.uniform(0.4, 0.9) * a, rnd.uniform(0, 6.28), rnd.uniform(0, 6.28), 6.28 / wl)
             for a, wl in ((1.2, 31.0), (0.5, 13.0), (0.2, 6.0))]

    def height(x, y):
        h = sum(a * math.sin(k * (x * math.cos(d) + y * math.sin(d)) + p)
                for a, d, p, k in waves)
        # a gentle bowl round the play area, rising towards the horizon
        return h * min(1.0, 0.3 + math.hypot(x, y) / 12.0) + 0.004 * (x * x + y * y) ** 0.75
    verts = [(-size / 2 + size * i / n, -size / 2 + size * j / n, 0.0)
             for j in range(n + 1) for i in range(n + 1)]
    verts = [(x, y, height(x, y)) for x, y, _ in verts]
    faces = [(j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1,
              (j + 1) * (n + 1) + i) for j in range(n) for i in range(n)]
    mat = _pbr(rnd, "terrain", (rnd.uniform(0.18, 0.35), rnd.uniform(0.25, 0.4),
                                rnd.uniform(0.08, 0.18)), "terrain")
    ob = rv.mesh_object("terrain", verts, faces, mat)
    for poly in ob.data.polygons:
        poly.use_smooth = True
    return ob, height


def _instances(scene, name, mesh, placements):
    """Linked duplicates of one mesh (Cycles instances the shared geometry)."""
    for k, (loc, rot, s) in enumerate(placements):
        ob = rv.bpy.data.objects.new(f"{name}{k}", mesh)
        scene.collection.objects.link(ob)
        ob.location, ob.rotation_euler, ob.scale = loc, rot, (s, s, s)


def _tree_mesh(rnd, k):
    """A tree: a trunk (its own object's material slot 0) and a crown of alpha-cut leaf
    quads (slot 1), as one mesh to instance."""
    verts, faces, mat_idx = [], [], []
    hgt, r0 = rnd.uniform(3.0, 5.0), rnd.uniform(0.1, 0.18)
    for i in range(6):                                   # trunk: a 6-sided prism
        a = i * math.pi / 3
        verts += [(r0 * math.cos(a), r0 * math.sin(a), 0.0),
                  (0.6 * r0 * math.cos(a), 0.6 * r0 * math.sin(a), hgt)]
    for i in range(6):
        j = (i + 1) % 6
        faces.append((2 * i, 2 * j, 2 * j + 1, 2 * i + 1))
        mat_idx.append(0)
    crown_r, crown_z = rnd.uniform(1.0, 1.8), hgt * rnd.uniform(0.65, 0.8)
    for _ in range(rnd.randint(350, 600)):
        u, v = rnd.uniform(-1, 1), rnd.uniform(-1, 1)
        w = rnd.uniform(-1, 1)
        if u * u + v * v + w * w > 1:
            continue
        cx, cy, cz = crown_r * u, crown_r * v, crown_z + 1.2 * crown_r * w
        r, t, tilt = rnd.uniform(0.08, 0.16), rnd.uniform(0, 6.28), rnd.uniform(-0.8, 0.8)
        ux, uy = math.cos(t) * r, math.sin(t) * r
        n = len(verts)
        verts += [(cx - ux, cy - uy, cz - tilt * r), (cx + ux, cy + uy, cz - tilt * r),
                  (cx + ux, cy + uy, cz + 2 * r), (cx - ux, cy - uy, cz + 2 * r)]
        faces.append((n, n + 1, n + 2, n + 3))
        mat_idx.append(1)
    me = rv.bpy.data.meshes.new(f"tree{k}")
    me.from_pydata(verts, [], faces)
    me.update()
    uv = me.uv_layers.new(name="UVMap")
    corners = ((0, 0), (1, 0), (1, 1), (0, 1))
    for poly, mi in zip(me.polygons, mat_idx):
        poly.material_index = mi
        for c, li in enumerate(poly.loop_indices):
            uv.data[li].uv = corners[c % 4]
    return me


def _grass_mesh(rnd, k, mat):
    """A tuft patch: a few hundred thin blades (1 cm wide) over a 2 m disc."""
    verts, faces = [], []
    for _ in range(rnd.randint(200, 350)):
        r, a = 1.0 * math.sqrt(rnd.random()), rnd.uniform(0, 6.28)
        x, y = r * math.cos(a), r * math.sin(a)
        hgt, wid, b = rnd.uniform(0.2, 0.6), rnd.uniform(0.004, 0.012), rnd.uniform(0, 6.28)
        n = len(verts)
        verts += [(x - math.cos(b) * wid, y - math.sin(b) * wid, -0.05),
                  (x + math.cos(b) * wid, y + math.sin(b) * wid, -0.05),
                  (x + rnd.uniform(-0.12, 0.12), y + rnd.uniform(-0.12, 0.12), hgt)]
        faces.append((n, n + 1, n + 2))
    me = rv.bpy.data.meshes.new(f"grass{k}")
    me.from_pydata(verts, [], faces)
    me.update()
    me.materials.append(mat)
    return me


def _rock_mesh(rnd, k, mat):
    """An ico sphere with its vertices pushed in and out (a rock)."""
    ob = rv.add("primitive_ico_sphere_add", mat, f"rock{k}", subdivisions=2, radius=1.0,
                location=(0, 0, -100))
    for v in ob.data.vertices:
        f = rnd.uniform(0.75, 1.15)
        v.co = (v.co[0] * f, v.co[1] * f, v.co[2] * f * 0.7)
    return ob


def _game_shots(frames, rnd, sights):
    """Cut frames (0-based) and per shot (kind, start, heading, speed, yaw rate): at least
    one fast pan and, from 2 frames on, at least one hard cut; shots of 8 or more frames
    where the sequence is long enough. Each shot starts facing one of `sights` ((x, y):
    lamps, fire pits, beacons), give or take 0.4 rad, so the effects come into view."""
    n_cuts = 0 if frames < 2 else max(1, min(3, frames // 12))
    if frames < 16:
        cuts = sorted(rnd.sample(range(1, frames), min(n_cuts, frames - 1)))
    else:
        step = frames / (n_cuts + 1)
        cuts = [int(round(step * (i + 1) + rnd.uniform(-1.5, 1.5))) for i in range(n_cuts)]
    kinds = ["pan", "run"] + [rnd.choice(("pan", "run", "strafe")) for _ in range(n_cuts)]
    kinds = kinds[:n_cuts + 1]
    rnd.shuffle(kinds)
    shots = []
    for kind in kinds:
        a, r = rnd.uniform(0, 6.28), rnd.uniform(0, 5)
        start = (r * math.cos(a), r * math.sin(a))
        sx, sy = rnd.choice(sights)
        heading = math.atan2(sy - start[1], sx - start[0]) + rnd.uniform(-0.4, 0.4)
        if kind == "pan":           # standing, turning fast (0.07-0.14 rad a frame)
            speed, yaw = rnd.uniform(0.0, 0.05), rnd.uniform(0.07, 0.14) * rnd.choice((-1, 1))
        elif kind == "run":         # running forward (4-7 m/s at 20 fps), drifting
            speed, yaw = rnd.uniform(0.2, 0.35), rnd.uniform(-0.03, 0.03)
        else:                       # strafing sideways while turning a little
            speed, yaw = -rnd.uniform(0.1, 0.2), rnd.uniform(-0.04, 0.04)
        shots.append((kind, start, heading, speed, yaw))
    return cuts, shots


def game(scene, frames, rnd):
    rv.set_world(scene, (rnd.uniform(0.45, 0.6), rnd.uniform(0.6, 0.75), rnd.uniform(0.85, 1.0)),
                 rnd.uniform(0.6, 1.1))
    keys = _keys(frames)
    _sun(scene, rnd, (2.5, 4.5))
    _, height = _terrain(rnd)
    # props near the play area: crates, barrels, rocks, ruined walls and pillars
    crate = _pbr(rnd, "crate", _rcolor(rnd, 0.3, 0.6), "wood")
    barrel = _pbr(rnd, "barrel", _rcolor(rnd, 0.2, 0.7), "painted")
    steel = _pbr(rnd, "steel", (0.6, 0.6, 0.62), "metal")
    stone = _pbr(rnd, "stone", _rcolor(rnd, 0.35, 0.6), "stone", bump=0.5)
    rock = _pbr(rnd, "rock", _rcolor(rnd, 0.25, 0.45), "rock")
    rocks = [_rock_mesh(rnd, k, rock).data for k in range(3)]

    def ground(r0, r1):
        a, r = rnd.uniform(0, 6.28), rnd.uniform(r0, r1)
        x, y = r * math.cos(a), r * math.sin(a)
        return x, y, height(x, y)
    for k in range(rnd.randint(10, 18)):
        x, y, z = ground(3, 16)
        s = rnd.uniform(0.5, 1.1)
        rv.add("primitive_cube_add", crate, f"crate{k}", size=s, location=(x, y, z + s / 2 - 0.05),
               rotation=(0, 0, rnd.uniform(0, 6.28)))
    for k in range(rnd.randint(6, 12)):
        x, y, z = ground(3, 16)
        rv.add("primitive_cylinder_add", barrel, f"barrel{k}", radius=0.3, depth=0.9,
               location=(x, y, z + 0.4))
    _instances(scene, "rock", rocks[0], [
        ((x, y, z), (0, 0, rnd.uniform(0, 6.28)), rnd.uniform(0.3, 1.4))
        for x, y, z in (ground(4, 30) for _ in range(rnd.randint(12, 24)))])
    for k in range(rnd.randint(2, 4)):                 # ruined walls with pillars
        x, y, z = ground(7, 18)
        a = rnd.uniform(0, 6.28)
        length = rnd.uniform(3, 7)
        for s in range(rnd.randint(2, 4)):
            d = (s - 1) * length / 3
            px, py = x + d * math.cos(a), y + d * math.sin(a)
            hz = rnd.uniform(1.0, 3.0)
            rv.add("primitive_cube_add", stone, f"wall{k}_{s}", size=1,
                   location=(px, py, height(px, py) + hz / 2 - 0.1),
                   scale=(length / 3 * 0.9, 0.4, hz), rotation=(0, 0, a))
        rv.add("primitive_cylinder_add", stone, f"pillar{k}", radius=0.25, depth=4.0,
               location=(x + 0.6, y + 0.6, z + 1.9))
    # foliage at distance: instanced trees of alpha-cut leaves, instanced grass tufts
    bark = _pbr(rnd, "bark", (0.3, 0.2, 0.12), "wood", scale=8.0)
    for t in range(2):
        leaf = _cutout_material(f"gleaf{t}", (rnd.uniform(0.05, 0.25), rnd.uniform(0.3, 0.55),
                                              rnd.uniform(0.02, 0.12)), "leaf", rough=0.55)
        me = _tree_mesh(rnd, t)
        me.materials.append(bark)
        me.materials.append(leaf)
        _instances(scene, f"tree{t}_", me, [
            ((x, y, z - 0.1), (0, 0, rnd.uniform(0, 6.28)), rnd.uniform(0.8, 1.4))
            for x, y, z in (ground(14, 42) for _ in range(rnd.randint(20, 35)))])
    grass_mat = _pbr(rnd, "grassblade", (0.25, 0.5, 0.1), "painted", scale=20.0, bump=0.0)
    tufts = [_grass_mesh(rnd, k, grass_mat) for k in range(3)]
    for k, me in enumerate(tufts):
        _instances(scene, f"tuft{k}_", me, [
            ((x, y, z), (0, 0, rnd.uniform(0, 6.28)), rnd.uniform(0.8, 1.5))
            for x, y, z in (ground(2, 36) for _ in range(rnd.randint(25, 45)))])
    # emissive effects: lamp posts with HDR bulbs, blinking beacons, sparks over fire pits
    sights = []
    for k in range(rnd.randint(3, 6)):
        x, y, z = ground(4, 20)
        sights.append((x, y))
        rv.add("primitive_cylinder_add", steel, f"post{k}", radius=0.05, depth=3.0,
               location=(x, y, z + 1.5))
        bulb = rv.material(f"bulb{k}", (1, 1, 1), 0.5, emission=(1.0, rnd.uniform(0.7, 0.9),
                           rnd.uniform(0.4, 0.7)), strength=rnd.uniform(20, 60))
        rv.add("primitive_uv_sphere_add", bulb, f"bulb{k}", radius=0.12,
               location=(x, y, z + 3.05))
    for k in range(rnd.randint(2, 4)):
        x, y, z = ground(3, 14)
        sights.append((x, y))
        beacon = rv.material(f"beacon{k}", (0.2, 0.05, 0.05), 0.4,
                             emission=_rcolor(rnd, 0.3, 1.0), strength=0.0)
        rv.add("primitive_cube_add", beacon, f"beacon{k}", size=0.25, location=(x, y, z + 0.6))
        period, on = rnd.randint(4, 8), rnd.uniform(15, 40)
        ph = rnd.randint(0, 7)
        rv.key_value(beacon.node_tree.nodes["Principled BSDF"].inputs["Emission Strength"],
                     keys, lambda f, p=period, o=on, q=ph: o if (f + q) % p < p // 2 else 0.0)
    spark = rv.material("gspark", (1, 0.6, 0.2), 0.5, emission=(1.0, 0.5, 0.12),
                        strength=rnd.uniform(20, 60))
    ember = rv.material("ember", (0.1, 0.05, 0.02), 0.9, emission=(1.0, 0.3, 0.05),
                        strength=rnd.uniform(3, 8))
    sm = rv.add("primitive_ico_sphere_add", spark, "sparkproto", subdivisions=1, radius=1.0,
                location=(0, 0, -100)).data
    for k in range(rnd.randint(1, 3)):
        fx, fy, fz = ground(3, 10)
        sights += [(fx, fy)] * 2
        rv.add("primitive_cylinder_add", ember, f"firepit{k}", radius=0.5, depth=0.2,
               location=(fx, fy, fz + 0.05))
        for i in range(rnd.randint(50, 90)):
            ob = rv.bpy.data.objects.new(f"spark{k}_{i}", sm)
            scene.collection.objects.link(ob)
            s = rnd.uniform(0.01, 0.03)
            ob.scale = (s, s, s)
            z0, vz = rnd.uniform(0.1, 3.0), rnd.uniform(0.04, 0.15)
            r, w, ph = rnd.uniform(0.05, 0.5), rnd.uniform(0.2, 0.6), rnd.uniform(0, 6.28)
            rv.key(ob, keys, location=lambda f, z0=z0, vz=vz, r=r, w=w, ph=ph, fx=fx, fy=fy,
                   fz=fz: (fx + r * math.cos(w * f + ph), fy + r * math.sin(w * f + ph),
                           fz + z0 + vz * f))
    # the camera: shots of a player's view (eye height 1.6 m over the terrain) cut hard
    cuts, shots = _game_shots(frames, rnd, sights)
    bounds = [0] + cuts

    def at(f):
        """(camera, target) at Blender frame f (rendered frame index f - 1)."""
        i = f - 1
        k = max(j for j in range(len(bounds)) if bounds[j] <= max(i, 0))
        kind, (x0, y0), h0, speed, yaw = shots[k]
        g = i - bounds[k]
        a = h0 + yaw * g
        if kind == "strafe":
            x = x0 + speed * g * math.cos(h0 + math.pi / 2)
            y = y0 + speed * g * math.sin(h0 + math.pi / 2)
        else:
            dx = sum(speed * math.cos(h0 + yaw * j) for j in range(max(g, 0)))
            dy = sum(speed * math.sin(h0 + yaw * j) for j in range(max(g, 0)))
            x, y = x0 + dx, y0 + dy
        bob = 0.03 * math.sin(1.7 * g) if kind == "run" else 0.0
        tx, ty = x + 6 * math.cos(a), y + 6 * math.sin(a)
        return ((x, y, height(x, y) + 1.6 + bob), (tx, ty, height(tx, ty) + 1.3))
    cam, tgt = rv.camera(scene, rnd.uniform(65, 80))
    cam.data.dof.use_dof = False
    rv.key(cam, keys, location=lambda f: at(f)[0])
    rv.key(tgt, keys, location=lambda f: at(f)[1])
    for ob in (cam, tgt):
        for fc in _fcurves(ob):
            for kp in fc.keyframe_points:
                kp.interpolation = "CONSTANT"
    desc = (f"game-like: PBR terrain and props, instanced trees and grass to 40 m, lamps, "
            f"blinking beacons and sparks; shots {', '.join(s[0] for s in shots)} with "
            f"{len(cuts)} hard cut(s)")
    return desc, tuple(cuts)


FAMILIES = {"foliage": foliage, "wires": wires, "text": text, "materials": materials,
            "cuts": cuts, "movers": movers, "interior": interior, "particles": particles,
            "game": game}
# The families a split may render (held-out ones only in test) ...
SPLITS = {"train": tuple(f for f in FAMILIES if f not in HELD_OUT),
          "validation": tuple(f for f in FAMILIES if f not in HELD_OUT),
          "test": HELD_OUT}
# ... and those it renders when --families is not given.
DEFAULT_FAMILIES = dict(SPLITS, test=TEST_FAMILIES)


def builder(family, seed):
    """build(scene, frames) for render_validation.render_scene: family `family` drawn with
    random.Random(seed)."""
    import random
    fn = FAMILIES[family]
    return lambda scene, frames: fn(scene, frames, random.Random(f"{family}:{seed}"))
