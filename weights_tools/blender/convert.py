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


def read_exr(path):
    """Channels of a (multilayer) EXR: {name: float32 (H, W)}, names without the view
    layer prefix ("Combined.R", "Depth.Z", "Vector.X", ...)."""
    import OpenImageIO as oiio
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise OSError(f"{path}: cannot read ({oiio.geterror()})")
    try:
        names = list(inp.spec().channelnames)
        pixels = inp.read_image(oiio.FLOAT)
    finally:
        inp.close()
    if pixels is None:
        raise OSError(f"{path}: cannot read its pixels")
    return {n.split(".", 1)[1] if n.count(".") >= 2 else n: np.ascontiguousarray(pixels[..., k])
            for k, n in enumerate(names)}


def _rgb(ch, path):
    try:
        return np.stack([ch["Combined." + c] for c in "RGB"], -1)
    except KeyError:
        raise OSError(f"{path}: no Combined pass (channels: {', '.join(ch)})") from None


def convert_scene(src):
    """The DATA.md arrays (dict) of one rendered scene directory."""
    with open(os.path.join(src, "frames.json")) as fh:
        rec = json.load(fh)
    near = rec["near"]
    color, depth, motion, ref = [], [], [], []
    for fr in rec["frames"]:
        lr_path = os.path.join(src, fr["lr"])
        ch = read_exr(lr_path)
        color.append(_rgb(ch, lr_path))
        z = ch["Depth.Z"]
        with np.errstate(divide="ignore"):
            depth.append(np.where(z < NO_HIT_DEPTH, np.minimum(near / z, 1.0), 0.0))
        motion.append(np.stack([ch["Vector.X"], -ch["Vector.Y"]], -1))
        ref_path = os.path.join(src, fr["ref"])
        ref.append(_rgb(read_exr(ref_path), ref_path))
    meta = dict(generator="weights_tools/blender/render_validation.py",
                renderer=f"Blender {rec['blender']} Cycles (CPU)", scene=rec["scene"],
                content=rec["description"], render_size=rec["render_size"],
                spp=rec["spp"], ref_spp=rec["ref_spp"], render_seconds=rec["seconds"],
                label_rules_version=None,
                sampling="colour: spp samples of a 0.01 px box filter at the jittered "
                         "pixel centre (converged point sample); reference: ref_spp "
                         "samples, 1-pixel box filter")
    return dict(color=np.stack(color).astype(np.float32),
                depth=np.stack(depth).astype(np.float32),
                motion=np.stack(motion).astype(np.float32),
                jitter=np.array([f["jitter"] for f in rec["frames"]], np.float32),
                reset=np.array([f["reset"] for f in rec["frames"]], bool),
                reference=np.stack(ref).astype(np.float32),
                scale=np.array(rec["scale"], np.float32),
                meta=np.array(json.dumps(meta)))


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
