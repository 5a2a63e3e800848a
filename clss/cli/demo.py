"""`clss demo`: the built-in sample scene through bicubic, CLSS rules and CLSS net.

Renders clss.scene (jittered render-resolution frames and a 16-spp output-resolution
reference), upscales every frame four ways and writes to OUT (default out/demo):

    input/                 the rendered sequence as EXR + jitter.json (`clss upscale` reads it)
    bicubic/ rules/ net/   output frames, EXR (half) and PNG
    side_by_side.png       last frame: input (nearest), bicubic, rules, net, reference
    side_by_side_crop.png  a 3x enlarged crop of the same
    temporal_profile.png   one scanline over time for each method (flicker shows as noise)
    debug/                 rules_* and net_* debug views of the last frame
    metrics.json           PSNR / SSIM per frame and their means, per-stage milliseconds

"bicubic" is a plain (not jitter-aware) Keys bicubic of each render frame in the PQ
domain (clss.pipeline.baselines), i.e. what a spatial upscaler without history gives.
Metrics compare tone-mapped display values (clss.metrics) from frame SKIP on, once the
history has warmed up. The net mode runs the trained weights shipped in the package
(clss/weights/clss_trained.safetensors, from `make train`) unless --weights is given
(`--weights untrained`: the seeded init, which shows the machinery, not the method).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass, field

import numpy as np

SKIP = 4


def _size(text):
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH (e.g. 480x270), got {text!r}")
    if w < 4 or h < 4:
        raise argparse.ArgumentTypeError(f"expected at least 4x4, got {text!r}")
    return h, w


def _crop_box(H, W):
    """A region with the fence and wires (upper middle of the frame), 1/4 of each side."""
    ch, cw = max(H // 4, 8), max(W // 4, 8)
    y0, x0 = int(H * 0.30), int(W * 0.45)
    return (min(y0, H - ch), min(y0, H - ch) + ch, min(x0, W - cw), min(x0, W - cw) + cw)


# What a demo run writes into OUT: replaced as a whole by --overwrite.
OUTPUT_SET = ("input/*", "bicubic/*", "rules/*", "net/*", "debug/*", "side_by_side.png",
              "side_by_side_crop.png", "temporal_profile.png", "metrics.json")


def _parser():
    from .args import ArgParser, positive_int
    from .upscaler_common import add_upscaler_args
    p = ArgParser(
        prog="clss demo",
        description="Render the built-in sample scene, upscale it with bicubic, CLSS rules and "
                    "CLSS net, and write frames, a side-by-side, a temporal profile, debug views "
                    "and PSNR/SSIM against the scene's 16-spp reference.")
    p.add_argument("-o", "--out", default=os.path.join("out", "demo"),
                   help="output directory (default out/demo): created if missing, refused if "
                        "not empty unless --overwrite")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a previous demo's output in OUT")
    p.add_argument("--frames", "-n", type=positive_int, default=30, help="frames (default 30)")
    p.add_argument("--size", type=_size, default=(270, 480), metavar="WxH",
                   help="render size (default 480x270; output = size x scale)")
    add_upscaler_args(p)
    p.add_argument("--weights", "-w", default=None,
                   help="network weights: a .safetensors file or a directory (default: the "
                        "trained weights shipped in the package; 'untrained': the seeded init)")
    p.add_argument("--spp", type=positive_int, default=16, help="reference samples per output pixel")
    p.add_argument("--modes", default="rules,net", help="comma-separated subset of rules,net")
    p.add_argument("--workers", type=positive_int, default=2, help="processes rendering the scene")
    return p


def main(argv=None) -> int:
    from .args import prepare_output_dir, start_output
    from .upscaler_common import FrameFiles, check_weights_mode
    p = _parser()
    a = p.parse_args(argv)
    modes = [m.strip() for m in a.modes.split(",") if m.strip()]
    if not modes or any(m not in ("rules", "net") for m in modes):
        p.error(f"--modes: expected a subset of rules,net, got {a.modes!r}")
    check_weights_mode(a.weights, "net" in modes)

    from .. import io as cio
    from ..device import get_device
    from ..pipeline import Upscaler
    from ..pipeline.contract import output_size

    h, w = a.size
    H, W = output_size(h, w, a.scale)
    stale = prepare_output_dir(a.out, "-o", overwrite=a.overwrite, outputs=OUTPUT_SET)
    dev = get_device(a.device)
    ups = {m: Upscaler(a.scale, mode=m, weights=a.weights if m == "net" else None, device=dev,
                       precision=a.precision, profile=True, debug=True) for m in modes}
    start_output(a.out, stale)
    trained = ups["net"].trained if "net" in ups else None
    out = a.out
    print(f"clss demo: {a.frames} frames {w}x{h} -> {W}x{H} (x{a.scale:g}), {a.precision}, "
          f"device {dev.info.name}; writing to {out}", file=sys.stderr)

    methods = ["bicubic"] + modes
    # What the frames leave for the pictures and the summary.
    run = _Run(scores={m: {"psnr": [], "ssim": []} for m in methods},
               lines={m: [] for m in methods + ["reference"]}, wall={m: 0.0 for m in methods})
    t_all = time.perf_counter()
    in_dir = os.path.join(out, "input")
    files = FrameFiles()
    try:
        _upscale_frames(a, dev, ups, modes, (H, W), in_dir, files, run)
    except KeyboardInterrupt:
        files.discard()
        sidecar = run.sidecar
        if sidecar is not None:     # the sidecar of the whole frames only
            k = files.done_frames
            cio.write_json(os.path.join(in_dir, "jitter.json"),
                        dict(sidecar, frames=sidecar["frames"][:k], jitter=sidecar["jitter"][:k],
                             resets=[r for r in sidecar["resets"] if r in sidecar["frames"][:k]]))
        print(f"\nclss demo: interrupted; {files.done_frames} frames written to {out} "
              "(no pictures or metrics)", file=sys.stderr)
        return 130
    total_s = time.perf_counter() - t_all
    side = _write_pictures(a, ups, modes, trained, (H, W), run)
    _write_summary(a, dev, ups, modes, trained, (h, w), (H, W), run, total_s, side)
    return 0


@dataclass
class _Run:
    """The per-method state a demo run gathers frame by frame."""
    scores: dict            # method: {"psnr": [...], "ssim": [...]} from frame SKIP on
    lines: dict             # method (and "reference"): the profile scanline of each frame
    wall: dict              # method: seconds upscaling
    render_s: float = 0.0   # seconds rendering the scene
    last: dict = field(default_factory=dict)    # the last frame's pictures, by name
    sidecar: dict | None = None                 # input/jitter.json so far


def _upscale_frames(a, dev, ups, modes, out_hw, in_dir, files, run):
    """Render, write the input, upscale with every method and score each frame."""
    from .. import io as cio
    from .. import metrics
    from ..pipeline.baselines import Bicubic, nearest
    from ..progress import progress
    from ..scene import iter_sequence
    H, W = out_hw
    out = a.out
    bicubic = Bicubic(dev, (H, W))
    scores, lines, wall = run.scores, run.lines, run.wall
    row = int(H * 0.55)                          # the profile's scanline: ground and fence
    frames = iter_sequence(a.frames, a.size, a.scale, spp_ref=a.spp, workers=a.workers)
    t = time.perf_counter()
    for f in progress(frames, desc="demo", unit="frame", total=a.frames):
        run.render_s += time.perf_counter() - t
        # One frame at a time (the references are large); write_sample_sequence writes a
        # one-frame jitter.json each time, gathered into the sequence's sidecar, which is
        # rewritten after every frame so that input/ is always a readable sequence.
        files.add(*[q for q in cio.write_sample_sequence([f], in_dir)
                    if not q.endswith("jitter.json")])
        with open(os.path.join(in_dir, "jitter.json")) as fh:
            one = json.load(fh)
        if run.sidecar is None:
            run.sidecar = dict(one, frames=[], jitter=[], resets=[])
        sidecar = run.sidecar
        sidecar["frames"] += one["frames"]
        sidecar["jitter"] += one["jitter"]
        sidecar["resets"] += one["resets"]
        cio.write_json(os.path.join(in_dir, "jitter.json"), sidecar)
        results = {}
        t = time.perf_counter()
        results["bicubic"] = bicubic(f.color)
        wall["bicubic"] += time.perf_counter() - t
        for m in modes:
            t = time.perf_counter()
            results[m] = ups[m].step(f.color, f.depth, f.motion, f.jitter, reset=f.reset)
            wall[m] += time.perf_counter() - t
        for m, img in results.items():
            stem = os.path.join(out, m, f"frame.{f.index:04d}")
            files.add(stem + ".exr", stem + ".png")
            cio.write_exr(stem + ".exr", img)
            cio.write_png(stem + ".png", img)
            if f.index >= min(SKIP, a.frames - 1):
                scores[m]["psnr"].append(metrics.psnr(img, f.reference))
                scores[m]["ssim"].append(metrics.ssim(img, f.reference))
            lines[m].append(img[row:row + 1])
        files.done()
        lines["reference"].append(f.reference[row:row + 1])
        run.last = dict(results, reference=f.reference, input=nearest(f.color, H, W))
        t = time.perf_counter()


def _write_pictures(a, ups, modes, trained, out_hw, run) -> str:
    """The side-by-side (whole and a crop), the temporal profile and the debug views;
    returns the side-by-side's path."""
    from .. import metrics
    from .upscaler_common import write_debug_views
    H, W = out_hw
    out = a.out
    methods = ["bicubic"] + modes
    order = ["input"] + methods + ["reference"]
    labels = ["input (nearest)", "bicubic"] + [f"CLSS {m}" for m in modes] + [f"reference {a.spp} spp"]
    if "net" in modes and not trained:
        labels[order.index("net")] = "CLSS net (untrained)"
    pics = [run.last[k] for k in order]
    side = os.path.join(out, "side_by_side.png")
    metrics.save_side_by_side(side, pics, labels)
    metrics.save_side_by_side(os.path.join(out, "side_by_side_crop.png"), pics, labels,
                              crop=_crop_box(H, W), zoom=3)
    span = (W // 4, W // 4 + min(W // 2, 240))
    metrics.save_temporal_profiles(os.path.join(out, "temporal_profile.png"),
                                   [run.lines[m] for m in methods + ["reference"]], labels[1:],
                                   row=0, span=span, repeat=max(1, 240 // a.frames))
    for m in modes:
        write_debug_views(os.path.join(out, "debug"), ups[m], a.frames - 1, prefix=f"{m}_")
    return side


def _write_summary(a, dev, ups, modes, trained, render_hw, out_hw, run, total_s, side):
    """The metrics table and per-stage times on stdout, and metrics.json."""
    from .. import io as cio
    from .upscaler_common import format_stage_table
    (h, w), (H, W) = render_hw, out_hw
    methods = ["bicubic"] + modes
    scores, wall, render_s = run.scores, run.wall, run.render_s
    stage = {m: ups[m].stage_ms() for m in modes}
    summary = {"frames": a.frames, "render_size": [h, w], "output_size": [H, W], "scale": a.scale,
               "precision": a.precision, "device": dev.info.name, "metrics_from_frame":
               min(SKIP, a.frames - 1), "net_weights": "trained" if trained else "untrained (seeded)",
               "methods": {}, "stage_ms": stage, "render_s": render_s, "total_s": total_s}
    if "net" in ups:
        summary["classifier_backend"] = ups["net"].classifier_backend_name
    print(f"\nsample scene, {a.frames} frames {w}x{h} -> {W}x{H}; metrics on tone-mapped frames "
          f"{summary['metrics_from_frame']}..{a.frames - 1} against the {a.spp}-spp reference")
    print(f"{'method':22s} {'PSNR dB':>8s} {'SSIM':>7s} {'ms/frame':>9s}")
    for m in methods:
        ps, ss = np.mean(scores[m]["psnr"]), np.mean(scores[m]["ssim"])
        ms = wall[m] / a.frames * 1e3
        name = "bicubic" if m == "bicubic" else f"CLSS {m}"
        if m == "net" and not trained:
            name += " (untrained)"
        print(f"{name:22s} {ps:8.2f} {ss:7.4f} {ms:9.1f}")
        summary["methods"][m] = {"psnr": scores[m]["psnr"], "ssim": scores[m]["ssim"],
                                 "psnr_mean": float(ps), "ssim_mean": float(ss),
                                 "ms_per_frame": ms}
    if "net" in modes and not trained:
        print("note: the net weights are untrained (seeded He init); its numbers show the "
              "pipeline runs, not the quality of a trained CLSS")
    for m in modes:
        print(f"\nCLSS {m}, per-stage time per frame ({dev.info.name}; OpenCL events, "
              f"classifier wall time):")
        print(format_stage_table(stage[m]))
    if "net" in ups:
        print(f"classifier backend: {summary['classifier_backend']}")
    print(f"\nscene rendering {render_s:.1f} s, total {total_s:.1f} s; pictures: {side}")
    cio.write_json(os.path.join(a.out, "metrics.json"), summary)


if __name__ == "__main__":
    sys.exit(main())
