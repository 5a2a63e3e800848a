"""`clss demo`: the built-in sample scene through every method it can feed.

Renders clss.demo.scene (jittered render-resolution frames, its G-buffers and a 16-spp
output-resolution reference), upscales every frame with each method (`clss methods`; by
default every method whose inputs the scene provides) and writes to OUT (default out/demo)
what a visitor looks at, a few MB:

    demo.png               the last frame as a labelled grid, 1200 px wide: the whole
                           reference with the hardest window marked (the one the scene's
                           sub-pixel wires cross most over the frames), then that window
                           zoomed in the input and each method, named with its PSNR
    temporal_profile.png   the window's middle column over time, one tile per method
                           (flicker shows as broken, noisy streaks)
    demo.gif               the window over the frames: input, a baseline, CLSS, reference
    metrics.json, .md      PSNR / SSIM per frame and their means, times, per-stage ms

and, with --exr, the full sequences (418 MB at the defaults before they became optional):

    input/                 the rendered sequence as EXR (with its G-buffers) + jitter.json
                           (`clss upscale` reads it)
    METHOD/                output frames of each method, EXR (half) and PNG
    debug/                 METHOD_* debug views of the last frame (the methods that have them)

Metrics compare tone-mapped display values (clss.metrics) from frame SKIP on, once the
history has warmed up. The ms/frame column is the warm time of one `step` (frames after
the first two: the first builds the kernels); the build and the file I/O are printed apart.
CLSS net runs the trained weights shipped in the package
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


COLS = 4            # grid columns: more methods add rows, the picture stays 1200 px wide
GIF_FPS = 8


def _wire_window(frames, out_hw, size):
    """The window (y0, y1, x0, x1) of `size` = (h, w) output pixels that the scene's thin
    wires (its sub-pixel cylinders) cross most over the frames, or None when none is in
    view: the hardest region, known from the scene itself rather than found in the error
    of a method, so the pictures and the GIF show the same wires however they moved."""
    from ..demo.scene import NEAR, Cylinder, camera_at, scene_at
    from ..pictures import hardest_box
    H, W = out_hw
    hits = np.zeros((H, W))
    s = np.linspace(0.0, 1.0, 400)
    for t in range(frames):
        cam = camera_at(float(t), W / H)
        for c in scene_at(float(t)):
            if not isinstance(c, Cylinder) or c.r > 0.01:
                continue
            p = c.a[:, None] + c.ax[:, None] * (c.len * s)
            u, v, z = cam.project(p[0], p[1], p[2], W, H)
            ok = (z > NEAR) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
            np.add.at(hits, (v[ok].astype(int), u[ok].astype(int)), 1.0)
    return None if not hits.any() else hardest_box(hits, *size)


def _window(H, W):
    """The inset window's size (h, w) and its zoom: a grid tile of COLS holds the window
    at least 2x enlarged (pixel repetition)."""
    from ..pictures import tile_width
    tw = tile_width(COLS)
    w = min(W, tw // 2)
    return min(H, max(8, round(w * H / W))), w, max(1, tw // w)


# What a demo run writes into OUT: replaced as a whole by --overwrite (the method folders
# are added by name; rules/ and net/ are where earlier versions wrote CLSS).
OUTPUT_SET = ("input/*", "rules/*", "net/*", "debug/*", "side_by_side.png",
              "side_by_side_crop.png", "demo.png", "demo.gif", "temporal_profile.png",
              "metrics.json", "metrics.md")
WARM_FROM = 2      # frames before this pay for builds and first allocations


def scene_methods(scale=None, weights=None):
    """The methods the sample scene can feed (it writes every G-buffer of the contract),
    at `scale` when given (a method's spec says which scales it supports, and which it
    ships weights for: without `weights`, a method that has none for the scale is left
    out)."""
    from .. import methods
    from ..pipeline import contract
    have = set(contract.GBUFFERS)
    out = []
    for n in methods.names():
        s = methods.spec(n)
        if not set(s.gbuffers) <= have:
            continue
        if scale is not None:
            try:
                s.check_scale(scale)
                if weights is None:
                    s.resolve_weights(None, scale)
            except ValueError:
                continue
        out.append(n)
    return out


def _parser():
    from .args import ArgParser, positive_int
    from .upscaler_common import add_upscaler_args
    p = ArgParser(
        prog="clss demo",
        description="Render the built-in sample scene, upscale it with every method it can feed "
                    "(`clss methods`), and write frames, a side-by-side, a temporal profile, "
                    "debug views and PSNR/SSIM against the scene's 16-spp reference.",
        epilog="examples:\n  clss demo\n  clss demo --methods jbicubic,clss-rules,clss -n 12\n"
               "  clss demo --size 240x136 --scale 3 --precision fp16",
        formatter_class=argparse.RawDescriptionHelpFormatter)
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
    p.add_argument("--methods", "-m", default=None,
                   help="comma-separated methods (default: every method the scene can feed; "
                        "`clss methods` lists them)")
    p.add_argument("--modes", default=None, help="older spelling of --methods (rules,net)")
    p.add_argument("--workers", type=positive_int, default=2, help="processes rendering the scene")
    p.add_argument("--exr", action="store_true",
                   help="also write the full sequences: input/ (EXR with G-buffers, which "
                        "`clss upscale` reads), each method's frames (half EXR and PNG) and "
                        "debug/ (by default only the pictures, the GIF and the metrics)")
    return p


def _pick_methods(p, a):
    from .. import methods
    text = a.methods if a.methods is not None else a.modes
    if a.methods is not None and a.modes is not None:
        p.error("give --methods or --modes, not both")
    if text is None:
        return scene_methods(a.scale, a.weights)
    flag = "--methods" if a.methods is not None else "--modes"
    try:
        picked = []
        for m in (m.strip() for m in text.split(",") if m.strip()):
            c = methods.canonical(m)
            if c not in picked:
                picked.append(c)
    except ValueError as e:
        p.error(f"{flag}: {e}")
    if not picked:
        p.error(f"{flag}: expected methods, e.g. {','.join(scene_methods())}")
    feedable = scene_methods()
    for m in picked:
        if m not in feedable:
            p.error(f"{flag}: the sample scene cannot feed {m!r} (it needs "
                    f"{', '.join(methods.spec(m).gbuffers)})")
    return picked


def main(argv=None) -> int:
    from .args import prepare_output_dir, start_output
    from .upscaler_common import FrameFiles, check_weights_mode, precision_label
    from .. import methods as registry
    p = _parser()
    a = p.parse_args(argv)
    names = _pick_methods(p, a)
    trainable = [m for m in names if registry.spec(m).weights() != "none needed"]
    check_weights_mode(a.weights, bool(trainable))

    from .. import io as cio
    from ..device import get_device
    from ..upscaler import Upscaler
    from ..pipeline.contract import output_size

    h, w = a.size
    H, W = output_size(h, w, a.scale)
    outputs = OUTPUT_SET + tuple(f"{m}/*" for m in names)
    stale = prepare_output_dir(a.out, "-o", overwrite=a.overwrite, outputs=outputs)
    dev = get_device(a.device)
    ups = {}
    for m in names:
        # the debug views (--exr) of the methods that have them (jbicubic's would be rule mode's)
        kw = registry.options(m, weights=a.weights, debug=a.exr and m != "jbicubic")
        ups[m] = Upscaler(method=m, scale=a.scale, device=dev, precision=a.precision,
                          profile=True, **kw)
    a.precision = precision_label(a.precision, [u.precision for u in ups.values()])
    start_output(a.out, stale)
    # whether the methods with weights run trained ones (None: no such method in the run)
    with_weights = [getattr(up, "trained", None) for up in ups.values()]
    with_weights = [t for t in with_weights if t is not None]
    trained = all(with_weights) if with_weights else None
    out = a.out
    print(f"clss demo: {a.frames} frames {w}x{h} -> {W}x{H} (x{a.scale:g}), {a.precision}, "
          f"device {dev.info.name}, methods {','.join(names)}; writing to {out}",
          file=sys.stderr)

    # What the frames leave for the pictures and the summary.
    run = _Run(scores={m: {"psnr": [], "ssim": []} for m in names},
               lines={m: [] for m in names + ["reference"]}, step_s={m: [] for m in names})
    t_all = time.perf_counter()
    in_dir = os.path.join(out, "input")
    files = FrameFiles()
    try:
        _upscale_frames(a, ups, names, (H, W), in_dir, files, run)
    except KeyboardInterrupt:
        files.discard()
        sidecar = run.sidecar
        if sidecar is not None:     # the sidecar of the whole frames only
            k = files.done_frames
            cio.write_json(os.path.join(in_dir, "jitter.json"),
                        dict(sidecar, frames=sidecar["frames"][:k], jitter=sidecar["jitter"][:k],
                             resets=[r for r in sidecar["resets"] if r in sidecar["frames"][:k]]))
        done = f"; {files.done_frames} frames written to {out}" if a.exr else \
            f" after {files.done_frames} frames"
        print(f"\nclss demo: interrupted{done} (no pictures or metrics)", file=sys.stderr)
        return 130
    total_s = time.perf_counter() - t_all
    side = _write_pictures(a, ups, names, trained, (H, W), run)
    _write_summary(a, dev, ups, names, trained, (h, w), (H, W), run, total_s, side)
    return 0


@dataclass
class _Run:
    """The per-method state a demo run gathers frame by frame."""
    scores: dict            # method: {"psnr": [...], "ssim": [...]} from frame SKIP on
    lines: dict             # method (and "reference"): the window's middle column, each frame
    step_s: dict            # method: seconds of each frame's step
    render_s: float = 0.0   # seconds rendering the scene
    io_s: float = 0.0       # seconds writing files
    score_s: float = 0.0    # seconds computing PSNR and SSIM
    last: dict = field(default_factory=dict)    # the last frame's pictures, by name
    sidecar: dict | None = None                 # input/jitter.json so far
    box: tuple | None = None                    # the inset window (y0, y1, x0, x1)
    clips: dict = field(default_factory=dict)   # name: the window of each frame (GIF)


def _write_input(f, in_dir, files, run):
    """input/: the frame (with its G-buffers, so that `clss upscale --method M` can rerun
    any method on it) and the sequence's sidecar so far. write_sample_sequence writes a
    one-frame jitter.json each time; it is gathered into the sequence's sidecar, rewritten
    after every frame so that input/ is always a readable sequence."""
    from .. import io as cio
    files.add(*[q for q in cio.write_sample_sequence([f], in_dir, gbuffers=True)
                if not q.endswith("jitter.json")])
    with open(os.path.join(in_dir, "jitter.json")) as fh:
        one = json.load(fh)
    if run.sidecar is None:
        run.sidecar = dict(one, frames=[], jitter=[], resets=[])
    sidecar = run.sidecar
    for k in ("frames", "jitter", "resets"):
        sidecar[k] += one[k]
    cio.write_json(os.path.join(in_dir, "jitter.json"), sidecar)


def _gif_names(names):
    """The GIF's panels: the input, a baseline, CLSS (else the first learned method) and
    the reference, those of them this run has."""
    base = next((m for m in ("bicubic", "jbicubic") if m in names), None)
    best = next((m for m in ("clss", "clss-rules") if m in names),
                next((m for m in names if m != base), None))
    return list(dict.fromkeys(n for n in ("input", base, best, "reference") if n))


def _upscale_frames(a, ups, names, out_hw, in_dir, files, run):
    """Render, upscale with every method and score each frame; keep the window of the
    pictures (found on the first frame), and with --exr write every frame."""
    from .. import io as cio
    from .. import metrics
    from ..pictures import error_map, hardest_box
    from ..progress import progress
    from ..demo.scene import iter_sequence
    H, W = out_hw
    out = a.out
    scores, lines = run.scores, run.lines
    gif = _gif_names(names)
    frames = iter_sequence(a.frames, a.size, a.scale, spp_ref=a.spp, workers=a.workers)
    t = time.perf_counter()
    for f in progress(frames, desc="demo", unit="frame", total=a.frames):
        run.render_s += time.perf_counter() - t
        t_io = time.perf_counter()
        if a.exr:
            _write_input(f, in_dir, files, run)
        run.io_s += time.perf_counter() - t_io
        results = {}
        gbuffers = getattr(f, "gbuffers", None) or {}
        for m in names:
            t = time.perf_counter()
            results[m] = ups[m].step(f.color, f.depth, f.motion, f.jitter, reset=f.reset,
                                     **gbuffers)
            run.step_s[m].append(time.perf_counter() - t)
        pics = dict(results, reference=f.reference, input=metrics.nearest(f.color, H, W))
        if run.box is None:     # the wires; else where a per-frame upscale errs most
            wh, ww, _ = _window(H, W)
            base = next((m for m in ("bicubic", "jbicubic") if m in results), "input")
            run.box = _wire_window(a.frames, out_hw, (wh, ww)) or hardest_box(
                error_map(metrics.display(pics[base]), metrics.display(f.reference)), wh, ww)
        y0, y1, x0, x1 = run.box
        col = (x0 + x1) // 2            # the profile's line: across the wires
        t_io = time.perf_counter()
        for m, img in results.items():
            if a.exr:
                stem = os.path.join(out, m, f"frame.{f.index:04d}")
                files.add(stem + ".exr", stem + ".png")
                cio.write_exr(stem + ".exr", img)
                cio.write_png(stem + ".png", img)
            if f.index >= min(SKIP, a.frames - 1):
                t_score = time.perf_counter()
                scores[m]["psnr"].append(metrics.psnr(img, f.reference))
                scores[m]["ssim"].append(metrics.ssim(img, f.reference))
                run.score_s += time.perf_counter() - t_score
                t_io += time.perf_counter() - t_score      # not file writing
            lines[m].append(img[y0:y1, col:col + 1].copy())   # not a view: the frame goes
        files.done()
        run.io_s += time.perf_counter() - t_io
        lines["reference"].append(f.reference[y0:y1, col:col + 1].copy())
        for n in gif:
            run.clips.setdefault(n, []).append(metrics.display(pics[n][y0:y1, x0:x1]))
        run.last = pics
        t = time.perf_counter()


def _label(m, ups):
    from .. import methods
    lab = methods.spec(m).label
    return lab + " (untrained)" if getattr(ups[m], "trained", None) is False else lab


def _write_pictures(a, ups, names, trained, out_hw, run) -> str:
    """demo.png (the labelled grid), temporal_profile.png, demo.gif and, with --exr, the
    debug views; returns demo.png's path."""
    from .. import io as cio
    from .. import metrics
    from ..pictures import grid, overview, save_gif, tile_width
    from .upscaler_common import write_debug_views
    t_io = time.perf_counter()
    H, W = out_hw
    out = a.out
    box = run.box
    _, _, z = _window(H, W)
    psnr = {m: np.mean(run.scores[m]["psnr"]) for m in names}
    labels = {"input": f"input {a.size[1]}x{a.size[0]} (nearest)",
              "reference": f"reference {a.spp} spp",
              **{m: f"{_label(m, ups)}  {psnr[m]:.2f} dB" for m in names}}
    order = ["input"] + list(names) + ["reference"]
    disp = {k: metrics.display(run.last[k]) for k in order}
    tiles = [overview(disp["reference"], tile_width(COLS), box)]
    tiles += [metrics.crop_zoom(disp[k], box, z) for k in order]
    path = os.path.join(out, "demo.png")
    cio.write_png_ldr(path, grid(tiles, [f"frame {a.frames - 1}, whole"] + [labels[k] for k in order],
                                 COLS))
    # The column through the window's middle over time: line down, time across.
    rep = max(1, tile_width(COLS) // a.frames)
    profiles = [np.repeat(metrics.display(metrics.temporal_profile(run.lines[k], col=0, repeat=rep)),
                          z, 0) for k in order[1:]]
    cio.write_png_ldr(os.path.join(out, "temporal_profile.png"),
                      grid(profiles, [labels[k] for k in order[1:]], COLS))
    gif = list(run.clips)
    save_gif(os.path.join(out, "demo.gif"),
             [grid([metrics.crop_zoom(run.clips[n][i], None, z) for n in gif],
                   [labels[n] for n in gif], len(gif)) for i in range(a.frames)], GIF_FPS)
    if a.exr:
        for m in names:
            if getattr(ups[m], "debug", False):
                write_debug_views(os.path.join(out, "debug"), ups[m], a.frames - 1, prefix=f"{m}_")
    run.io_s += time.perf_counter() - t_io
    return path


def _write_summary(a, dev, ups, names, trained, render_hw, out_hw, run, total_s, side):
    """The metrics table, times and per-stage times on stdout, metrics.json and the same
    table as metrics.md (for an issue or a README)."""
    from .. import io as cio
    from .upscaler_common import format_stage_table
    (h, w), (H, W) = render_hw, out_hw
    scores = run.scores
    stage = {m: ups[m].stage_ms() for m in names}
    stage = {m: v for m, v in stage.items() if v}
    summary = {"frames": a.frames, "render_size": [h, w], "output_size": [H, W], "scale": a.scale,
               "precision": a.precision, "device": dev.info.name, "metrics_from_frame":
               min(SKIP, a.frames - 1), "net_weights": None if trained is None else
               ("trained" if trained else "untrained (seeded)"),
               "methods": {}, "stage_ms": stage, "render_s": run.render_s, "io_s": run.io_s,
               "score_s": run.score_s,
               "total_s": total_s, "warm_from_frame": min(WARM_FROM, a.frames - 1),
               "window": list(run.box)}
    backends = {m: up.classifier_backend_name for m, up in ups.items()
                if getattr(up, "classifier_backend_name", None)}
    if backends:        # where a method's classifier runs (CLSS net: clss.Model or a kernel)
        summary["classifier_backend"] = next(iter(backends.values()))
    print(f"\nsample scene, {a.frames} frames {w}x{h} -> {W}x{H}; metrics on tone-mapped frames "
          f"{summary['metrics_from_frame']}..{a.frames - 1} against the {a.spp}-spp reference; "
          f"ms/frame: the median step from frame {summary['warm_from_frame']} on (warm); "
          "first frame: the step that built the kernels")
    lw = max(len("method"), *(len(_label(m, ups)) for m in names)) + 1
    print(f"{'method':{lw}s} {'PSNR dB':>8s} {'SSIM':>7s} {'ms/frame':>9s} {'first frame ms':>15s}")
    md = ["| method | PSNR dB | SSIM | ms/frame | first frame ms |", "|---|---:|---:|---:|---:|"]
    for m in names:
        ps, ss = np.mean(scores[m]["psnr"]), np.mean(scores[m]["ssim"])
        st = run.step_s[m]
        warm = float(np.median(st[summary["warm_from_frame"]:])) * 1e3
        first = st[0] * 1e3
        print(f"{_label(m, ups):{lw}s} {ps:8.2f} {ss:7.4f} {warm:9.1f} {first:15.1f}")
        md.append(f"| {_label(m, ups)} | {ps:.2f} | {ss:.4f} | {warm:.1f} | {first:.1f} |")
        summary["methods"][m] = {"psnr": scores[m]["psnr"], "ssim": scores[m]["ssim"],
                                 "psnr_mean": float(ps), "ssim_mean": float(ss),
                                 "ms_per_frame": warm, "first_frame_ms": first,
                                 "step_ms": [v * 1e3 for v in st]}
    untrained = [m for m in names if getattr(ups[m], "trained", None) is False]
    if untrained:
        print(f"note: the weights of {', '.join(untrained)} are untrained (seeded init); their "
              "numbers show the pipeline runs, not the quality of the trained method")
    for m, st in stage.items():
        print(f"\n{_label(m, ups)}, per-stage time per frame ({dev.info.name}; OpenCL events, "
              f"classifier wall time):")
        print(format_stage_table(st))
    if backends:
        print(f"classifier backend: {summary['classifier_backend']}")
    cio.write_json(os.path.join(a.out, "metrics.json"), summary)
    with open(os.path.join(a.out, "metrics.md"), "w") as fh:
        fh.write("\n".join(
            [f"`clss demo`: sample scene, {a.frames} frames {w}x{h} -> {W}x{H}, {a.precision}, "
             f"{dev.info.name}; PSNR and SSIM on tone-mapped frames "
             f"{summary['metrics_from_frame']}..{a.frames - 1} against the {a.spp}-spp "
             "reference", ""] + md) + "\n")
    size = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(a.out) for f in fs)
    print(f"\nscene rendering {run.render_s:.1f} s, scoring {run.score_s:.1f} s, file writing "
          f"{run.io_s:.1f} s, total "
          f"{total_s:.1f} s; {size / 2**20:.1f} MB in {a.out}; pictures: {side}")


if __name__ == "__main__":
    sys.exit(main())
