"""Render validation sequences with Blender (Cycles, CPU), unlike the training generator.

Run inside Blender (its Python has bpy, not numpy or clss):

    blender -b -P weights_tools/blender/render_validation.py -- --out DIR \\
        [--scenes interior,foliage] [--frames 16] [--size 90x160] [--scale 2] \\
        [--spp 64] [--ref-spp 96] [--hr-spp 4]

then convert the EXRs to the DATA.md .npz with `python -m weights_tools.blender.convert`
(`make validation-data` does both).

Per scene, DIR/<scene>/ receives for every frame f (Blender frame f + 1):
  * lr_FFFF.exr: multilayer EXR at render size with the Combined, Depth and Vector
    passes, and the G-buffer passes DiffCol, GlossCol (their sum is the albedo) and
    Normal (world space; convert.py rotates it into the camera's frame with the
    camera_rotation recorded below). Point sampling: Cycles' box pixel filter of width 0.01 px puts every sample
    within +-0.005 px of the (jittered) pixel centre; `--spp` such samples average away
    the path-tracing noise, so the colour is the converged radiance at one point per
    pixel, as a rasteriser's would be (one path-traced sample would be noise, not
    aliasing). Jitter: Halton(2,3) (as clss.scene, length ceil(8 scale^2)) applied as
    camera shift: shift_x = jx / max(w, h), shift_y = -jy / max(w, h) (Blender's shift
    is in units of the larger image side, +y up), so render pixel (i, j) samples
    (j + 0.5 + jx, i + 0.5 + jy) of the unshifted image.
  * ref_FFFF.exr: the reference at scale x the render size, unshifted, `--ref-spp`
    samples per pixel with a box filter 1 output pixel wide.
  * hr_FFFF.exr: the output-resolution G-buffers (albedo_hr, depth_hr, normal_hr): a
    render at scale x the render size, unshifted, point-sampled like lr (0.01 px box
    filter) with `--hr-spp` samples, so each output pixel holds its centre's Depth,
    Normal, DiffCol and GlossCol, as a renderer's full-resolution feature pass would
    (the reference's passes would be averages over the pixel, and its normals not of
    unit length). Its Combined pass is not used.
  * frames.json: jitter, reset, size, scale, the camera's clip start (NEAR), timings,
    and per frame `camera_rotation`: the camera's world rotation (3 x 3 rows; its
    columns are the camera's x right, y up, z backward axes in Blender's world).
Motion blur is off (Cycles fills the Vector pass only then) and all animation is
keyframed on every frame, so Cycles' motion pass (scene at frame - 1 and + 1) is exact.

Scenes:
  * interior: a room with brick and plank textures, a window with thin mullions onto a
    bright outside, a turning ceiling fan with thin blades, a table and a slatted chair,
    a walking figure swinging its arms, a desk lamp that switches on; the camera pans
    and dollies.
  * foliage: a tree with thin branches and hundreds of leaves, a field of grass blades,
    a cloth banner waving (mesh deformation), a string of thin wires, an orbiting light
    (moving shadows) and a sun; the camera trucks sideways.
  * pan_test: a textured plane 5 m in front of a camera moving +0.10 m in x and
    +0.05 m in y per frame (tests check the Vector pass's convention against it).
"""
import json
import math
import os
import sys
import time

# Inside Blender (-P) bpy is already imported; elsewhere (weights_tools, tests reading the
# constants and halton) it is imported by new_scene, the first bpy call of a render, so
# that importing this module costs nothing where bpy is installed as a module (pip bpy).
bpy = sys.modules.get("bpy")

NEAR = 0.1   # camera clip start = the reversed-Z near plane of DATA.md


# ---------------------------------------------------------------- setup

# clss.scene's Halton jitter, repeated here because Blender's Python has no numpy (which
# clss.scene imports); tests/test_blender_validation.py checks that the two agree.
def halton(index, base):
    f, r = 1.0, 0.0
    while index > 0:
        f /= base
        r += f * (index % base)
        index //= base
    return r


def halton_jitter(index, scale):
    n = int(math.ceil(8.0 * scale * scale - 1e-9))
    k = index % n + 1
    return halton(k, 2) - 0.5, halton(k, 3) - 0.5


def new_scene(threads=None):
    """An empty Cycles scene with the passes of the contract; `threads`: Cycles' CPU
    threads (default: up to 2; 1 when several renders share the machine)."""
    global bpy
    if bpy is None:
        import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    cy = scene.cycles
    cy.device = "CPU"
    cy.use_denoising = False
    cy.use_adaptive_sampling = False
    cy.seed = 0
    # One bounce, small lights and a firm indirect clamp: the path tracing noise that
    # remains stays well below the aliasing the sequences are about.
    cy.max_bounces, cy.diffuse_bounces, cy.glossy_bounces = 2, 1, 1
    cy.transmission_bounces, cy.transparent_max_bounces = 1, 4
    cy.sample_clamp_indirect = 1.0
    scene.render.use_motion_blur = False
    scene.render.film_transparent = False
    scene.render.resolution_percentage = 100
    scene.render.threads_mode = "FIXED"
    scene.render.threads = threads or max(1, min(2, os.cpu_count() or 1))
    vl = scene.view_layers[0]
    vl.use_pass_z = True
    vl.use_pass_vector = True
    # G-buffers (docs/input-contract.md section 5): the albedo is DiffCol + GlossCol, the
    # normal Cycles' world-space Normal pass (convert.py puts both in the contract's form).
    vl.use_pass_diffuse_color = True
    vl.use_pass_glossy_color = True
    vl.use_pass_normal = True
    s = scene.render.image_settings
    if hasattr(s, "media_type"):        # Blender >= 5.0: multilayer is a media type
        s.media_type = "MULTI_LAYER_IMAGE"
    s.file_format = "OPEN_EXR_MULTILAYER"
    s.color_depth = "32"
    s.exr_codec = "ZIP"
    world = bpy.data.worlds.new("world")
    scene.world = world
    world.use_nodes = True
    return scene


def set_world(scene, color, strength):
    bg = scene.world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*color, 1.0)
    bg.inputs["Strength"].default_value = strength


def material(name, color=(0.8, 0.8, 0.8), rough=0.5, tex=None, scale=10.0, color2=None,
             emission=None, strength=0.0, metallic=0.0):
    """Principled BSDF, optionally textured (object coordinates): brick, checker, wave
    (stripes), noise or planks."""
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    nt = m.node_tree
    bsdf = nt.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = rough
    bsdf.inputs["Metallic"].default_value = metallic
    if tex:
        coord = nt.nodes.new("ShaderNodeTexCoord")
        c2 = (*(color2 or tuple(0.3 * c for c in color)), 1.0)
        if tex == "brick":
            t = nt.nodes.new("ShaderNodeTexBrick")
            t.inputs["Color1"].default_value = (*color, 1.0)
            t.inputs["Color2"].default_value = c2
            t.inputs["Mortar"].default_value = (0.85, 0.85, 0.8, 1.0)
            t.inputs["Mortar Size"].default_value = 0.015
        elif tex == "checker":
            t = nt.nodes.new("ShaderNodeTexChecker")
            t.inputs["Color1"].default_value = (*color, 1.0)
            t.inputs["Color2"].default_value = c2
        elif tex in ("wave", "planks"):
            t = nt.nodes.new("ShaderNodeTexWave")
            t.wave_profile = "SAW" if tex == "planks" else "SIN"
            t.inputs["Distortion"].default_value = 2.0 if tex == "planks" else 0.0
            ramp = nt.nodes.new("ShaderNodeValToRGB")
            ramp.color_ramp.elements[0].color = c2
            ramp.color_ramp.elements[1].color = (*color, 1.0)
            nt.links.new(t.outputs["Fac"], ramp.inputs["Fac"])
        else:   # noise
            t = nt.nodes.new("ShaderNodeTexNoise")
            t.inputs["Detail"].default_value = 8.0
            ramp = nt.nodes.new("ShaderNodeValToRGB")
            ramp.color_ramp.elements[0].position = 0.35
            ramp.color_ramp.elements[0].color = c2
            ramp.color_ramp.elements[1].position = 0.65
            ramp.color_ramp.elements[1].color = (*color, 1.0)
            nt.links.new(t.outputs["Fac"], ramp.inputs["Fac"])
        t.inputs["Scale"].default_value = scale
        nt.links.new(coord.outputs["Object"], t.inputs["Vector"])
        out = ramp.outputs["Color"] if tex in ("wave", "planks", "noise") else t.outputs["Color"]
        nt.links.new(out, bsdf.inputs["Base Color"])
    if emission:
        emit = bsdf.inputs.get("Emission Color") or bsdf.inputs["Emission"]   # 4.0 renamed it
        emit.default_value = (*emission, 1.0)
        bsdf.inputs["Emission Strength"].default_value = strength
    return m


def add(op, mat=None, name=None, scale=None, **kw):
    """A mesh primitive; `scale` is applied to the mesh (the operators' own scale
    argument is ignored by some, e.g. planes), so textures in object coordinates keep
    their size in metres."""
    getattr(bpy.ops.mesh, op)(**kw)
    obj = bpy.context.active_object
    if scale is not None:
        from mathutils import Matrix
        obj.data.transform(Matrix.Diagonal((*scale, 1.0)))
    if name:
        obj.name = name
    if mat is not None:
        obj.data.materials.append(mat)
    return obj


def mesh_object(name, verts, faces, mat):
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    me.update()
    obj = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(obj)
    obj.data.materials.append(mat)
    return obj


def camera(scene, lens_angle_deg=70.0):
    cam_data = bpy.data.cameras.new("cam")
    cam_data.angle = math.radians(lens_angle_deg)      # along the larger image side
    cam_data.clip_start = NEAR
    cam_data.clip_end = 1000.0
    cam = bpy.data.objects.new("cam", cam_data)
    scene.collection.objects.link(cam)
    scene.camera = cam
    target = bpy.data.objects.new("cam_target", None)
    scene.collection.objects.link(target)
    c = cam.constraints.new("TRACK_TO")
    c.target = target
    c.track_axis = "TRACK_NEGATIVE_Z"
    c.up_axis = "UP_Y"
    return cam, target


def key(obj, frames, location=None, rotation=None):
    """Keyframe obj at every frame in `frames` from functions of the frame."""
    for f in frames:
        if location:
            obj.location = location(f)
            obj.keyframe_insert("location", frame=f)
        if rotation:
            obj.rotation_euler = rotation(f)
            obj.keyframe_insert("rotation_euler", frame=f)


def key_value(socket, frames, value):
    for f in frames:
        socket.default_value = value(f)
        socket.keyframe_insert("default_value", frame=f)


# ---------------------------------------------------------------- scenes

def scene_interior(scene, frames):
    set_world(scene, (0.6, 0.75, 1.0), 1.0)
    keys = range(0, frames + 2)
    W, D, H = 8.0, 7.0, 3.2
    floor = material("planks", (0.55, 0.36, 0.2), 0.35, "planks", 6.0, (0.3, 0.18, 0.09))
    brick = material("brick", (0.55, 0.25, 0.18), 0.8, "brick", 6.0, (0.4, 0.2, 0.15))
    plaster = material("plaster", (0.85, 0.83, 0.78), 0.9, "noise", 40.0, (0.75, 0.73, 0.68))
    wood = material("wood", (0.35, 0.2, 0.1), 0.4)
    metal = material("metal", (0.8, 0.8, 0.82), 0.25, metallic=1.0)
    cloth = material("shirt", (0.15, 0.3, 0.7), 0.7, "checker", 18.0, (0.9, 0.85, 0.7))
    skin = material("skin", (0.8, 0.6, 0.5), 0.5)
    outside = material("outside", (1, 1, 1), emission=(1.0, 0.95, 0.85), strength=4.0)
    add("primitive_plane_add", floor, "floor", size=1, location=(0, 0, 0), scale=(W, D, 1))
    add("primitive_plane_add", plaster, "ceiling", size=1, location=(0, 0, H),
        scale=(W, D, 1), rotation=(math.pi, 0, 0))
    add("primitive_cube_add", brick, "back", size=1, location=(0, -D / 2, H / 2),
        scale=(W, 0.1, H))
    add("primitive_cube_add", brick, "left", size=1, location=(-W / 2, 0, H / 2),
        scale=(0.1, D, H))
    # Right wall with a window: four wall pieces around a hole, mullions, bright outside.
    wx0, wx1, wz0, wz1 = -1.5, 1.0, 0.9, 2.4
    for (y0, y1, z0, z1) in ((-D / 2, wx0, 0, H), (wx1, D / 2, 0, H), (wx0, wx1, 0, wz0),
                             (wx0, wx1, wz1, H)):
        add("primitive_cube_add", plaster, "right", size=1,
            location=(W / 2, (y0 + y1) / 2, (z0 + z1) / 2), scale=(0.1, y1 - y0, z1 - z0))
    for k in range(1, 8):
        y = wx0 + (wx1 - wx0) * k / 8
        add("primitive_cube_add", wood, "mullion", size=1,
            location=(W / 2, y, (wz0 + wz1) / 2), scale=(0.12, 0.015, wz1 - wz0))
    for k in range(1, 4):
        z = wz0 + (wz1 - wz0) * k / 4
        add("primitive_cube_add", wood, "transom", size=1,
            location=(W / 2, (wx0 + wx1) / 2, z), scale=(0.12, wx1 - wx0, 0.015))
    sky = add("primitive_plane_add", outside, "outside", size=1,
              location=(W / 2 + 1.0, -0.25, 1.6), scale=(3, 4, 1), rotation=(0, math.pi / 2, 0))
    # Seen through the window but lighting nothing (a large emitter is a noisy light):
    # a sun shines through the window instead.
    sky.visible_diffuse = sky.visible_glossy = sky.visible_shadow = False
    sun = bpy.data.lights.new("sun", "SUN")
    sun.energy, sun.angle = 4.0, math.radians(1.0)
    so = bpy.data.objects.new("sun", sun)
    scene.collection.objects.link(so)
    so.rotation_euler = (math.radians(50), math.radians(25), math.radians(80))
    # Table with thin legs, a slatted chair.
    add("primitive_cube_add", wood, "table", size=1, location=(0.5, -1.0, 0.75),
        scale=(1.6, 0.9, 0.05))
    for sx in (-0.75, 0.75):
        for sy in (-0.4, 0.4):
            add("primitive_cylinder_add", metal, "leg", radius=0.02, depth=0.72,
                location=(0.5 + sx, -1.0 + sy, 0.36))
    for k in range(9):
        add("primitive_cube_add", wood, "slat", size=1,
            location=(-1.0, -0.3 + 0.07 * k - 0.28, 0.95), scale=(0.03, 0.02, 0.9))
    add("primitive_cube_add", wood, "seat", size=1, location=(-0.75, -0.3, 0.48),
        scale=(0.5, 0.6, 0.04))
    # Ceiling fan: hub and four thin blades turning 25 degrees per frame.
    fan = bpy.data.objects.new("fan", None)
    scene.collection.objects.link(fan)
    fan.location = (0.3, -0.8, H - 0.35)
    add("primitive_cylinder_add", metal, "rod", radius=0.015, depth=0.35,
        location=(0.3, -0.8, H - 0.17))
    for k in range(4):
        b = add("primitive_cube_add", wood, "blade", size=1, location=(0.45, 0, 0),
                scale=(0.8, 0.12, 0.01), rotation=(0.15, 0, 0))
        b.parent = fan
        b.location = (0.45 * math.cos(k * math.pi / 2), 0.45 * math.sin(k * math.pi / 2), 0)
        b.rotation_euler = (0.15, 0, k * math.pi / 2)
    key(fan, keys, rotation=lambda f: (0, 0, math.radians(25.0) * f))
    # A walking figure: body, head, swinging arms, crossing the room.
    fig = bpy.data.objects.new("figure", None)
    scene.collection.objects.link(fig)
    body = add("primitive_cylinder_add", cloth, "body", radius=0.2, depth=0.8,
               location=(0, 0, 1.1))
    head = add("primitive_uv_sphere_add", skin, "head", radius=0.13, location=(0, 0, 1.68))
    legs = [add("primitive_cylinder_add", cloth, "leg", radius=0.07, depth=0.75,
                location=(0, s * 0.1, 0.37)) for s in (-1, 1)]
    for o in [body, head] + legs:
        o.parent = fig
    arms = []
    for s in (-1, 1):
        pivot = bpy.data.objects.new("shoulder", None)
        scene.collection.objects.link(pivot)
        pivot.parent = fig
        pivot.location = (0, s * 0.26, 1.45)
        arm = add("primitive_cylinder_add", skin, "arm", radius=0.035, depth=0.65,
                  location=(0, 0, -0.32))
        arm.parent = pivot
        arms.append((pivot, s))
    key(fig, keys, location=lambda f: (-1.8 + 0.17 * f, -0.1 - 0.03 * f, 0.02 * abs(
        math.sin(0.8 * f))), rotation=lambda f: (0, 0, -0.3))
    for pivot, s in arms:
        key(pivot, keys, rotation=lambda f, s=s: (0, 0.6 * math.sin(0.8 * f) * s, 0))
    # Lights: a ceiling area light, a desk lamp switching on at frame 8.
    for k, (x, y) in enumerate(((-1.5, 1.0), (1.5, -1.5))):
        area = bpy.data.lights.new(f"area{k}", "AREA")
        area.energy, area.size = 300.0, 0.5
        ao = bpy.data.objects.new(f"area{k}", area)
        scene.collection.objects.link(ao)
        ao.location = (x, y, H - 0.02)
    lampm = material("lampshade", (1, 1, 1), emission=(1.0, 0.8, 0.5), strength=0.0)
    add("primitive_uv_sphere_add", lampm, "bulb", radius=0.08, location=(1.0, -1.2, 1.0))
    bulb = bpy.data.lights.new("bulb", "POINT")
    bulb.shadow_soft_size = 0.05
    bo = bpy.data.objects.new("bulb", bulb)
    scene.collection.objects.link(bo)
    bo.location = (1.0, -1.2, 1.12)
    on = frames // 2 + 1
    for f in keys:
        bulb.energy = 60.0 if f >= on else 0.0
        bulb.keyframe_insert("energy", frame=f)
    key_value(lampm.node_tree.nodes["Principled BSDF"].inputs["Emission Strength"], keys,
              lambda f: 25.0 if f >= on else 0.0)
    cam, target = camera(scene, 75.0)
    key(cam, keys, location=lambda f: (-2.6 + 0.05 * f, 3.0 - 0.08 * f, 1.6))
    key(target, keys, location=lambda f: (1.2 - 0.12 * f, -2.5, 1.1 + 0.02 * f))
    return "room: brick/plank/plaster textures, window mullions, turning fan, walking " \
           "figure, lamp switching on; camera pan + dolly"


def scene_foliage(scene, frames):
    set_world(scene, (0.5, 0.65, 0.95), 0.8)
    keys = range(0, frames + 2)
    import random
    rnd = random.Random(7)
    ground = material("ground", (0.35, 0.28, 0.15), 0.9, "noise", 3.0, (0.12, 0.1, 0.05))
    bark = material("bark", (0.3, 0.2, 0.12), 0.8, "wave", 30.0, (0.15, 0.1, 0.05))
    leaf = material("leaf", (0.2, 0.5, 0.1), 0.5, "noise", 25.0, (0.08, 0.25, 0.04))
    grass = material("grass", (0.3, 0.6, 0.15), 0.6)
    banner = material("banner", (0.8, 0.15, 0.1), 0.6, "wave", 12.0, (0.95, 0.9, 0.7))
    steel = material("steel", (0.6, 0.6, 0.62), 0.3, metallic=1.0)
    add("primitive_plane_add", ground, "ground", size=60)
    # Tree: a trunk, branches in rings, leaves as small quads at the branch ends.
    add("primitive_cylinder_add", bark, "trunk", radius=0.12, depth=3.0, location=(0, 0, 1.5))
    verts, faces = [], []
    for k in range(14):
        a, z = rnd.uniform(0, 6.28), rnd.uniform(1.4, 2.9)
        length = rnd.uniform(0.8, 1.6)
        tilt = rnd.uniform(0.3, 1.0)
        br = add("primitive_cylinder_add", bark, "branch", radius=0.02, depth=length,
                 location=(0, 0, 0))
        dx, dy, dz = math.cos(a) * math.sin(tilt), math.sin(a) * math.sin(tilt), math.cos(tilt)
        br.location = (dx * length / 2, dy * length / 2, z + dz * length / 2)
        br.rotation_euler = (0, tilt, a)
        for m in range(30):
            s = rnd.uniform(0.3, 1.0) * length
            cx, cy = dx * s + rnd.gauss(0, 0.15), dy * s + rnd.gauss(0, 0.15)
            cz = z + dz * s + rnd.gauss(0, 0.15)
            r, t = rnd.uniform(0.04, 0.09), rnd.uniform(0, 6.28)
            n = len(verts)
            for u, v in ((-1, 0), (0, -0.5), (1, 0), (0, 0.5)):
                verts.append((cx + r * (u * math.cos(t)), cy + r * (u * math.sin(t)),
                              cz + r * v + 0.3 * r * u * rnd.uniform(-1, 1)))
            faces.append((n, n + 1, n + 2, n + 3))
    mesh_object("leaves", verts, faces, leaf)
    # Grass: thin blades (two triangles each), in a band in front of the camera path.
    verts, faces = [], []
    for k in range(900):
        x, y = rnd.uniform(-5, 5), rnd.uniform(-1.5, 3.5)
        hgt, wid, lean = rnd.uniform(0.15, 0.45), rnd.uniform(0.006, 0.015), rnd.uniform(-0.1, 0.1)
        a = rnd.uniform(0, 6.28)
        ca, sa = math.cos(a) * wid, math.sin(a) * wid
        n = len(verts)
        verts += [(x - ca, y - sa, 0), (x + ca, y + sa, 0), (x + lean, y + lean * 0.5, hgt)]
        faces.append((n, n + 1, n + 2))
    mesh_object("grass", verts, faces, grass)
    # A banner waving (Wave modifier: mesh deformation).
    flag = add("primitive_grid_add", banner, "banner", x_subdivisions=40, y_subdivisions=20,
               size=1, location=(1.8, 1.0, 1.6), rotation=(math.pi / 2, 0, 0.4))
    flag.scale = (1.6, 0.9, 1)
    wave = flag.modifiers.new("wave", "WAVE")
    wave.use_normal = True
    wave.height, wave.width, wave.speed = 0.08, 0.5, 0.12
    for x in (1.0, 2.6):
        add("primitive_cylinder_add", steel, "pole", radius=0.02, depth=2.2,
            location=(x, 1.0 + 0.4 * (x - 1.8), 1.1))
    # Wires: a string of thin cables between two masts.
    for m in range(4):
        add("primitive_cylinder_add", steel, "wire", radius=0.004, depth=12.0,
            location=(-1.0, -2.0, 2.4 + 0.18 * m), rotation=(0, math.pi / 2, 0.1))
    # Lights: a sun and a warm point light orbiting the tree (moving shadows).
    sun = bpy.data.lights.new("sun", "SUN")
    sun.energy, sun.angle = 3.0, math.radians(1.0)
    so = bpy.data.objects.new("sun", sun)
    scene.collection.objects.link(so)
    so.rotation_euler = (math.radians(50), 0, math.radians(30))
    pl = bpy.data.lights.new("orbit", "POINT")
    pl.energy, pl.shadow_soft_size = 400.0, 0.05
    pl.color = (1.0, 0.75, 0.45)
    po = bpy.data.objects.new("orbit", pl)
    scene.collection.objects.link(po)
    key(po, keys, location=lambda f: (2.0 * math.cos(0.35 * f), 2.0 * math.sin(0.35 * f), 2.2))
    cam, target = camera(scene, 70.0)
    key(cam, keys, location=lambda f: (-2.2 + 0.1 * f, 3.4, 0.9 + 0.01 * f))
    key(target, keys, location=lambda f: (0.4 + 0.04 * f, 0.0, 1.5))
    return "tree with thin branches and leaves, grass blades, waving banner, thin wires, " \
           "orbiting point light and sun; camera trucks sideways"


PAN_STEP = (0.10, 0.05)     # camera metres per frame in x (right) and y (up)
PAN_DISTANCE = 5.0


def scene_pan_test(scene, frames):
    set_world(scene, (0.5, 0.5, 0.5), 1.0)
    keys = range(0, frames + 2)
    m = material("checker", (0.9, 0.9, 0.9), 0.8, "checker", 4.0, (0.1, 0.1, 0.1),
                 emission=(1, 1, 1), strength=0.0)
    add("primitive_plane_add", m, "wall", size=40, location=(0, 0, -PAN_DISTANCE))
    cam_data = bpy.data.cameras.new("cam")
    cam_data.angle = math.radians(60.0)
    cam_data.clip_start = NEAR
    cam = bpy.data.objects.new("cam", cam_data)      # looks along -z, +y up
    scene.collection.objects.link(cam)
    scene.camera = cam
    key(cam, keys, location=lambda f: (PAN_STEP[0] * f, PAN_STEP[1] * f, 0.0),
        rotation=lambda f: (0, 0, 0))
    sun = bpy.data.lights.new("sun", "SUN")
    scene.collection.objects.link(bpy.data.objects.new("sun", sun))
    return "pan test: checker plane at 5 m, camera moving (+0.10, +0.05) m per frame"


SCENES = {"interior": scene_interior, "foliage": scene_foliage, "pan_test": scene_pan_test}


# ---------------------------------------------------------------- rendering

def camera_rotation(cam_obj):
    """The camera's world rotation as 3 lists (rows), scale removed: column k is the
    camera's local axis k (x right, y up, z backward: Blender cameras look along -z) in
    world coordinates, which is what turns world normals into the contract's camera
    space (normal_camera = R^T normal_world)."""
    m = cam_obj.matrix_world.to_3x3().normalized()
    return [[float(m[i][j]) for j in range(3)] for i in range(3)]


def render_scene(name, out_dir, frames, size, scale, spp, ref_spp, hr_spp=4, build=None,
                 threads=None, log=print, jitter=None, twins=()):
    """Render `frames` frames of scene `name` (SCENES) into out_dir (see the module's
    docstring). `build(scene, frames)` replaces SCENES[name] (weights_tools.blender.families
    passes its seeded families); it returns the description, or (description, cuts):
    cuts are the frames (0-based) that start a new shot, recorded as resets. `jitter`: one
    (jx, jy) per frame in render pixels (the shards' draw from a jitter mix); default
    Halton(2,3). `twins`: other low-resolution inputs of the same frames, each a dict
    {"name", "size": (w, h), "scale", "jitter": [(jx, jy)] per frame} whose output size
    (size x scale) is this render's: each frame renders them too, as <name>_FFFF.exr
    (point-sampled like lr, `spp` samples), recorded in frames.json under "twins"; they
    share the reference and the output-resolution G-buffers (convert_scene(src, twin=name)
    reads one: a jitter-free or a 4x twin costs its low-resolution render only)."""
    scene = new_scene(threads)
    built = (build or SCENES[name])(scene, frames)
    description, cuts = built if isinstance(built, tuple) else (built, ())
    w, h = size
    W, H = int(math.floor(w * scale + 0.5)), int(math.floor(h * scale + 0.5))
    cam = scene.camera.data
    os.makedirs(out_dir, exist_ok=True)
    record = dict(scene=name, description=description, render_size=[h, w],
                  output_size=[H, W], scale=scale, near=NEAR, spp=spp, ref_spp=ref_spp,
                  blender=bpy.app.version_string, frames=[])
    for tw in twins:
        tw_w, tw_h = tw["size"]
        if (int(math.floor(tw_h * tw["scale"] + 0.5)), int(math.floor(tw_w * tw["scale"] + 0.5))) \
                != (H, W) or len(tw["jitter"]) < frames:
            raise ValueError(f"twin {tw['name']}: {tw_h}x{tw_w} at {tw['scale']}x is not the "
                             f"output size {H}x{W}, or fewer than {frames} jitter values")
    if twins:
        record["twins"] = {tw["name"]: dict(render_size=[tw["size"][1], tw["size"][0]],
                                            scale=tw["scale"]) for tw in twins}
    t_lr = t_ref = t_hr = t_tw = 0.0
    for f in range(frames):
        scene.frame_set(f + 1)
        jx, jy = halton_jitter(f, scale) if jitter is None else (float(v) for v in jitter[f])
        # Low resolution: point samples at the jittered pixel centres.
        scene.render.resolution_x, scene.render.resolution_y = w, h
        scene.cycles.samples = spp
        scene.cycles.pixel_filter_type = "BOX"
        scene.cycles.filter_width = 0.01
        cam.shift_x, cam.shift_y = jx / max(w, h), -jy / max(w, h)
        scene.render.filepath = os.path.join(out_dir, f"lr_{f:04d}.exr")
        t0 = time.time()
        bpy.ops.render.render(write_still=True)
        t_lr += time.time() - t0
        # Twins: the same frame at another render size or jitter (a jitter-free input, 4x).
        done_twins = {}
        for tw in twins:
            tw_w, tw_h = tw["size"]
            tx, ty = (float(v) for v in tw["jitter"][f])
            scene.render.resolution_x, scene.render.resolution_y = tw_w, tw_h
            cam.shift_x, cam.shift_y = tx / max(tw_w, tw_h), -ty / max(tw_w, tw_h)
            scene.render.filepath = os.path.join(out_dir, f"{tw['name']}_{f:04d}.exr")
            t0 = time.time()
            bpy.ops.render.render(write_still=True)
            t_tw += time.time() - t0
            done_twins[tw["name"]] = dict(lr=f"{tw['name']}_{f:04d}.exr", jitter=[tx, ty])
        # Reference: unshifted, box filter over the output pixel.
        scene.render.resolution_x, scene.render.resolution_y = W, H
        scene.cycles.samples = ref_spp
        scene.cycles.filter_width = 1.0
        cam.shift_x = cam.shift_y = 0.0
        scene.render.filepath = os.path.join(out_dir, f"ref_{f:04d}.exr")
        t0 = time.time()
        bpy.ops.render.render(write_still=True)
        t_ref += time.time() - t0
        # Output-resolution G-buffers: point samples at the unshifted output pixel centres.
        scene.cycles.samples = hr_spp
        scene.cycles.filter_width = 0.01
        scene.render.filepath = os.path.join(out_dir, f"hr_{f:04d}.exr")
        t0 = time.time()
        bpy.ops.render.render(write_still=True)
        t_hr += time.time() - t0
        record["frames"].append(dict(lr=f"lr_{f:04d}.exr", ref=f"ref_{f:04d}.exr",
                                     hr=f"hr_{f:04d}.exr", jitter=[jx, jy],
                                     reset=f == 0 or f in cuts,
                                     camera_rotation=camera_rotation(scene.camera)))
        if twins:
            record["frames"][-1]["twins"] = done_twins
        if log:
            log(f"[render_validation] {name} frame {f + 1}/{frames}")
    record["seconds"] = dict(lr=round(t_lr, 1), ref=round(t_ref, 1), hr=round(t_hr, 1))
    if twins:
        record["seconds"]["twins"] = round(t_tw, 1)
    with open(os.path.join(out_dir, "frames.json"), "w") as fh:
        json.dump(record, fh, indent=1)
    if log:
        log(f"[render_validation] {name}: {frames} frames, low res {t_lr:.1f} s, "
            f"reference {t_ref:.1f} s, output-res G-buffers {t_hr:.1f} s")
    return record


def main(argv):
    import argparse
    p = argparse.ArgumentParser(prog="render_validation.py")
    p.add_argument("--out", required=True)
    p.add_argument("--scenes", default="interior,foliage")
    p.add_argument("--frames", type=int, default=16)
    p.add_argument("--size", default="90x160", help="render size HxW")
    p.add_argument("--scale", type=float, default=2.0)
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--ref-spp", type=int, default=96)
    p.add_argument("--hr-spp", type=int, default=4,
                   help="samples of the output-resolution G-buffer render")
    a = p.parse_args(argv)
    h, w = (int(v) for v in a.size.lower().split("x"))
    for name in a.scenes.split(","):
        if name not in SCENES:
            p.error(f"--scenes: unknown scene {name!r} (have {', '.join(SCENES)})")
        render_scene(name, os.path.join(a.out, name), a.frames, (w, h), a.scale, a.spp,
                     a.ref_spp, a.hr_spp)


if __name__ == "__main__":
    main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else [])
