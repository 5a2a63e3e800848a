"""Blender EXRs (render_validation.py) -> DATA.md sequences (.npz, no labels).

    python -m weights_tools.blender.convert SRC OUT [--check] [--fp16]

SRC holds one directory per scene (with frames.json); OUT/<scene>.npz is written for
each (np.savez_compressed, float32 as DATA.md; with --fp16 colour and the
reference are stored as float16, which keeps the copies committed to the repository
small: readers cast with .astype(np.float32); depth and motion stay float32). Conversions:
  * colour: the Combined pass (RGB, linear scene-referred radiance);
  * depth: Cycles' Depth pass is the planar view depth z (checked on the pan test:
    a plane 5 m away reads 5.0 in every pixel); depth = NEAR / z (reversed-Z), 0 where
    nothing was hit (Cycles writes 1e10 there);
  * motion: Cycles' Vector pass holds (X, Y) = previous raster position - current one,
    in pixels, with raster +y *up*, and (Z, W) = current - next position. DATA.md wants
    prev = p + motion with +y down, so motion = (X, -Y). Checked on the pan test (the
    camera moves +x and +y: content moved left and down, so the previous position lies
    right, +x, and above, -y in DATA.md's convention). The pass excludes the camera
    shift (jitter), as DATA.md requires: Cycles projects the previous position with
    the current projection, shift included, and the shift cancels in the difference;
  * reference: the Combined pass of the unshifted scale x render.
G-buffers (docs/input-contract.md section 5), when the EXRs carry the passes (renders
made before render_validation.py enabled them do not: their .npz have no G-buffer keys):
  * albedo: DiffCol + GlossCol (Cycles' diffuse and glossy colour passes: the BSDF's
    diffuse and specular albedo), 0 where nothing was hit;
  * normal: Cycles' Normal pass is the world-space shading normal (Blender's world, +z
    up); the contract wants camera space (+x right, +y up, +z toward the camera), which
    is the Blender camera's own frame (it looks along its local -z): normal = R^T n
    with R the camera's world rotation (frames.json `camera_rotation`); 0 on background;
  * albedo_hr, depth_hr, normal_hr: the same from hr_FFFF.exr (output resolution,
    point-sampled at the unshifted pixel centres); depth_hr as depth.
`--check` also prints, per scene, how well the low-resolution colour matches the
reference sampled at the jittered sample positions, with the jitter's sign as recorded
and flipped (the recorded sign must win clearly).
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

NO_HIT_DEPTH = 1e9      # Cycles writes 1e10 for rays that leave the scene
# Blender 5 spells some passes out; read_exr gives them the short names of Blender <= 4.
PASS_NAMES = {"Diffuse Color": "DiffCol", "Glossy Color": "GlossCol"}


def read_exr(path):
    """Channels of a (multilayer) EXR: {name: float32 (H, W)}, names without the view
    layer prefix ("Combined.R", "Depth.Z", "Vector.X", ...). Blender up to 4.x writes one
    part with every pass; Blender 5 writes a multi-part EXR, one part (OIIO subimage) per
    pass: every part is read."""
    import OpenImageIO as oiio
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise OSError(f"{path}: cannot read ({oiio.geterror()})")
    out = {}
    try:
        part = 0
        while inp.seek_subimage(part, 0):
            names = list(inp.spec().channelnames)
            pixels = inp.read_image(part, 0, 0, len(names), oiio.FLOAT)
            if pixels is None:
                raise OSError(f"{path}: cannot read the pixels of part {part}")
            pixels = pixels.reshape(pixels.shape[0], pixels.shape[1], len(names))
            for k, n in enumerate(names):
                n = n.split(".", 1)[1] if n.count(".") >= 2 else n
                layer, _, c = n.rpartition(".")
                out[f"{PASS_NAMES.get(layer, layer)}.{c}" if layer else n] = \
                    np.ascontiguousarray(pixels[..., k])
            part += 1
    finally:
        inp.close()
    if not out:
        raise OSError(f"{path}: no image in the file")
    return out


def _rgb(ch, path):
    try:
        return np.stack([ch["Combined." + c] for c in "RGB"], -1)
    except KeyError:
        raise OSError(f"{path}: no Combined pass (channels: {', '.join(ch)})") from None


def depth_from_pass(z, near):
    """Cycles' Depth pass (planar view depth, 1e10 where nothing was hit) -> reversed-Z
    NEAR / z in [0, 1], 0 where nothing was hit."""
    with np.errstate(divide="ignore"):
        return np.where(z < NO_HIT_DEPTH, np.minimum(near / z, 1.0), 0.0)


def motion_from_pass(ch):
    """Cycles' Vector pass -> DATA.md motion: (X, Y) is previous - current raster
    position in pixels with raster +y up (Cycles' primitive_motion_vector returns
    (pre - center, center - post); Z, W point to the next frame), so (X, -Y)."""
    return np.stack([ch["Vector.X"], -ch["Vector.Y"]], -1)


GBUFFER_PASSES = ("DiffCol.R", "DiffCol.G", "DiffCol.B", "GlossCol.R", "GlossCol.G",
                  "GlossCol.B", "Normal.X", "Normal.Y", "Normal.Z")


def has_gbuffer_passes(ch):
    return all(c in ch for c in GBUFFER_PASSES)


def gbuffers_from_passes(ch, camera_rotation, near):
    """{"albedo", "normal", "depth"} in the contract's conventions from one EXR's
    passes (`read_exr`'s dict): albedo = DiffCol + GlossCol (>= 0), normal = the
    world-space Normal pass in the camera's frame (camera_rotation: 3 x 3, columns the
    camera's x, y, z axes in the world), renormalised, 0 where the pass is 0
    (background), depth as `depth_from_pass`."""
    albedo = np.stack([ch["DiffCol." + c] + ch["GlossCol." + c] for c in "RGB"], -1)
    n = np.stack([ch["Normal." + c] for c in "XYZ"], -1).astype(np.float64)
    R = np.asarray(camera_rotation, np.float64).reshape(3, 3)
    n = n @ R                       # row vectors: (R^T n)^T = n^T R
    length = np.sqrt(np.sum(n * n, -1, keepdims=True))
    hit = length > 1e-6
    n = np.where(hit, n / np.where(hit, length, 1.0), 0.0)
    return {"albedo": np.maximum(albedo, 0).astype(np.float32),
            "normal": n.astype(np.float32),
            "depth": depth_from_pass(ch["Depth.Z"], near).astype(np.float32)}


def convert_scene(src, twin=None):
    """The DATA.md arrays (dict) of one rendered scene directory; with the G-buffer keys
    when every frame's EXRs carry the passes (and frames.json the camera rotation).
    `twin`: the sequence of one of render_scene's twins instead (its low-resolution
    render, jitter, size and scale; the reference and output-resolution G-buffers are
    the scene's own)."""
    with open(os.path.join(src, "frames.json")) as fh:
        rec = json.load(fh)
    if twin is not None:
        if twin not in rec.get("twins", {}):
            raise KeyError(f"{src}: no twin {twin!r} (have {', '.join(rec.get('twins', {}))})")
        rec = dict(rec, **rec["twins"][twin], twin=twin,
                   frames=[dict(fr, **fr["twins"][twin]) for fr in rec["frames"]])
    near = rec["near"]
    color, depth, motion, ref = [], [], [], []
    gbs = {k: [] for k in ("albedo", "normal", "albedo_hr", "depth_hr", "normal_hr")}
    for fr in rec["frames"]:
        lr_path = os.path.join(src, fr["lr"])
        ch = read_exr(lr_path)
        color.append(_rgb(ch, lr_path))
        depth.append(depth_from_pass(ch["Depth.Z"], near))
        motion.append(motion_from_pass(ch))
        ref_path = os.path.join(src, fr["ref"])
        ref.append(_rgb(read_exr(ref_path), ref_path))
        rot = fr.get("camera_rotation")
        if rot is not None and has_gbuffer_passes(ch):
            g = gbuffers_from_passes(ch, rot, near)
            gbs["albedo"].append(g["albedo"])
            gbs["normal"].append(g["normal"])
        hr = fr.get("hr")
        if rot is not None and hr is not None:
            hr_path = os.path.join(src, hr)
            hch = read_exr(hr_path)
            if not has_gbuffer_passes(hch):
                raise OSError(f"{hr_path}: no G-buffer passes (need {', '.join(GBUFFER_PASSES)}"
                              f"; channels: {', '.join(hch)})")
            g = gbuffers_from_passes(hch, rot, near)
            gbs["albedo_hr"].append(g["albedo"])
            gbs["depth_hr"].append(g["depth"])
            gbs["normal_hr"].append(g["normal"])
    meta = dict(generator="weights_tools/blender/render_validation.py",
                renderer=f"Blender {rec['blender']} Cycles (CPU)", scene=rec["scene"],
                content=rec["description"], render_size=rec["render_size"],
                spp=rec["spp"], ref_spp=rec["ref_spp"], render_seconds=rec["seconds"],
                label_rules_version=None,
                **({"twin": rec["twin"]} if "twin" in rec else {}),
                sampling="colour: spp samples of a 0.01 px box filter at the jittered "
                         "pixel centre (converged point sample); reference: ref_spp "
                         "samples, 1-pixel box filter")
    if any(v and len(v) == len(rec["frames"]) for v in gbs.values()):
        meta["gbuffers"] = ("albedo = DiffCol + GlossCol; normal = Normal pass rotated into "
                            "camera space; *_hr from hr_FFFF.exr, point samples at the "
                            "output pixel centres")
    data = dict(color=np.stack(color).astype(np.float32),
                depth=np.stack(depth).astype(np.float32),
                motion=np.stack(motion).astype(np.float32),
                jitter=np.array([f["jitter"] for f in rec["frames"]], np.float32),
                reset=np.array([f["reset"] for f in rec["frames"]], bool),
                reference=np.stack(ref).astype(np.float32),
                scale=np.array(rec["scale"], np.float32),
                meta=np.array(json.dumps(meta)))
    # A G-buffer goes in only when every frame has it (a key is the whole sequence's).
    for k, frames in gbs.items():
        if frames and len(frames) == len(rec["frames"]):
            data[k] = np.stack(frames)
    return data


def _bilinear(img, x, y):
    h, w = img.shape[:2]
    x0 = np.clip(np.floor(x).astype(int), 0, w - 2)
    y0 = np.clip(np.floor(y).astype(int), 0, h - 2)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    return ((img[y0, x0] * (1 - fx) + img[y0, x0 + 1] * fx) * (1 - fy)
            + (img[y0 + 1, x0] * (1 - fx) + img[y0 + 1, x0 + 1] * fx) * fy)


def jitter_check(data):
    """Mean |colour - reference at the sample position| (tone-mapped), with the jitter
    as recorded and with its sign flipped, over the frames with non-zero jitter."""
    s = float(data["scale"])
    errs = {"recorded": [], "flipped": []}
    for t in range(len(data["color"])):
        jx, jy = data["jitter"][t]
        if jx == 0 and jy == 0:
            continue
        h, w = data["color"].shape[1:3]
        ii, jj = np.mgrid[0:h, 0:w].astype(np.float64)
        c = data["color"][t]
        for key, sgn in (("recorded", 1), ("flipped", -1)):
            # output pixel (u, v) has its centre at u + 0.5: position X maps to X*s - 0.5
            x = (jj + 0.5 + sgn * jx) * s - 0.5
            y = (ii + 0.5 + sgn * jy) * s - 0.5
            r = _bilinear(data["reference"][t], x, y)
            errs[key].append(float(np.abs(c / (1 + c) - r / (1 + r)).mean()))
    return {k: float(np.mean(v)) if v else float("nan") for k, v in errs.items()}


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m weights_tools.blender.convert",
                                description=__doc__.split("\n")[0])
    p.add_argument("src", help="directory of rendered scenes (render_validation.py --out)")
    p.add_argument("out", help="directory for <scene>.npz")
    p.add_argument("--check", action="store_true", help="print the jitter sign check")
    p.add_argument("--fp16", action="store_true",
                   help="store colour and reference as float16")
    a = p.parse_args(argv)
    if not os.path.isdir(a.src):
        print(f"error: {a.src} is not a directory", file=sys.stderr)
        return 2
    scenes = sorted(d for d in os.listdir(a.src)
                    if os.path.isfile(os.path.join(a.src, d, "frames.json")))
    if not scenes:
        print(f"error: no rendered scene (a directory with frames.json) in {a.src}",
              file=sys.stderr)
        return 2
    os.makedirs(a.out, exist_ok=True)
    for name in scenes:
        try:
            data = convert_scene(os.path.join(a.src, name))
        except (OSError, KeyError, ValueError) as e:
            print(f"error: {name}: {e}", file=sys.stderr)
            return 1
        if a.fp16:
            for k in ("color", "reference"):
                data[k] = data[k].astype(np.float16)
        path = os.path.join(a.out, name + ".npz")
        np.savez_compressed(path + ".tmp.npz", **data)
        os.replace(path + ".tmp.npz", path)
        line = (f"{path}: {data['color'].shape[0]} frames, render "
                f"{data['color'].shape[2]}x{data['color'].shape[1]}, "
                f"{os.path.getsize(path) / 1e6:.1f} MB")
        if a.check:
            e = jitter_check({k: v.astype(np.float32) if v.dtype == np.float16 else v
                              for k, v in data.items()})
            line += f"; colour vs reference at samples: {e['recorded']:.4f} " \
                    f"(jitter flipped: {e['flipped']:.4f})"
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
