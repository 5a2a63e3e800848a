"""Evaluation of the upscaling methods on rendered sequences against their references.

    python -m weights_tools eval SEQ.npz [SEQ.npz ...] [--methods bicubic,jbicubic,rules,net]
        [--weights PATH|untrained] [--precision fp32|fp16] [--warmup 4] [--out DIR] [--json FILE]

Sequences are .npz files in the format of weights_tools/DATA.md (inputs in clss's frame
contract plus the supersampled reference). Methods, all at the sequence's scale:

    bicubic    plain Keys bicubic (a = -0.75) of each render frame, jitter-unaware, in the
               PQ domain (clss.pipeline.baselines.Bicubic): a spatial upscaler that ignores the jitter
    jbicubic   jitter-aware bicubic: the frame step's upsampled colour without history
               (rule mode reset every frame, so out = up; reference.md s5)
    rules      CLSS rule mode (clss.Upscaler(mode="rules"))
    net        CLSS net mode (clss.Upscaler(mode="net")): the package's weights, a
               --weights directory/.safetensors, or `untrained` (the seeded init)

Scores (clss.metrics, on tone-mapped display values, as every clss metric): PSNR and SSIM
per frame, averaged; tPSNR, the PSNR of the frame differences (out_t - out_{t-1} against
ref_t - ref_{t-1}, one MSE over all scored pairs: flicker the reference does not have
lowers it); LDR-FLIP, mean per frame. A frame is scored once `warmup` frames have passed
since the last reset (the history has warmed up); no difference is taken across a reset.

This module imports clss, never torch.
"""
from __future__ import annotations

import json
import os
import sys
import time

import numpy as np

METHODS = ("bicubic", "jbicubic", "rules", "net")
METHOD_LABELS = {"bicubic": "bicubic", "jbicubic": "jitter-aware bicubic",
                 "rules": "CLSS rules", "net": "CLSS net"}
INPUT_KEYS = ("color", "depth", "motion", "jitter", "reset", "reference")
UNTRAINED = "untrained"


class SequenceError(ValueError):
    """A sequence file that is not in the weights_tools/DATA.md format."""


def load_sequence(path) -> dict:
    """The arrays of one DATA.md sequence, checked: {"name", "path", "color" [T,h,w,3],
    "depth" [T,h,w], "motion" [T,h,w,2], "jitter" [T,2], "reset" [T] bool, "reference"
    [T,H,W,3], "scale" float}. Raises SequenceError naming the file and the key."""
    from clss.pipeline.contract import output_size
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise SequenceError(f"{path}: no such file")
    try:
        z = np.load(path, allow_pickle=False)
    except Exception as e:       # not a zip, truncated, pickled objects ...
        raise SequenceError(f"{path}: not a readable .npz sequence ({e})") from None
    with z:
        missing = [k for k in INPUT_KEYS + ("scale",) if k not in z.files]
        if missing:
            raise SequenceError(f"{path}: missing {', '.join(missing)} (the keys of "
                                "weights_tools/DATA.md)")
        seq = {k: z[k] for k in INPUT_KEYS}
        scale = z["scale"]
    name = os.path.splitext(os.path.basename(path))[0]
    seq.update(name=name, path=path)
    try:
        seq["scale"] = float(scale)
    except (TypeError, ValueError):
        raise SequenceError(f"{path}: scale: expected a number, got {scale!r}") from None
    c = seq["color"]
    if c.ndim != 4 or c.shape[3] != 3 or c.shape[0] < 1:
        raise SequenceError(f"{path}: color: expected [T, h, w, 3], got shape {c.shape}")
    T, h, w = c.shape[:3]
    H, W = output_size(h, w, seq["scale"])
    want = {"depth": (T, h, w), "motion": (T, h, w, 2), "jitter": (T, 2), "reset": (T,),
            "reference": (T, H, W, 3)}
    for k, shape in want.items():
        if seq[k].shape != shape:
            raise SequenceError(f"{path}: {k}: expected shape {list(shape)} (T={T}, render "
                                f"{h}x{w}, output {H}x{W} at scale {seq['scale']:g}), got "
                                f"{list(seq[k].shape)}")
    for k in ("color", "depth", "motion", "reference"):
        if seq[k].dtype not in (np.float16, np.float32):
            raise SequenceError(f"{path}: {k}: expected float32 or float16, got {seq[k].dtype}")
    seq["reset"] = seq["reset"].astype(bool)
    seq["jitter"] = seq["jitter"].astype(np.float32)
    return seq


# ---------------------------------------------------------------- methods

class _Bicubic:
    """Plain bicubic, jitter-unaware (one instance per output size)."""

    def __init__(self, dev, out_hw):
        from clss.pipeline.baselines import Bicubic
        self.up = Bicubic(dev, out_hw)

    def __call__(self, seq, t):
        return self.up(seq["color"][t].astype(np.float32))


class Pipeline:
    """An upscaler with clss.Upscaler's `step` (clss.Upscaler, or the torch twin's
    TorchUpscaler in `seeds`) over a sequence; `always_reset` turns rule mode into the
    jitter-aware bicubic (reset: no history, out = up)."""

    def __init__(self, upscaler, always_reset=False):
        self.up, self.always_reset = upscaler, always_reset

    def __call__(self, seq, t):
        return self.up.step(seq["color"][t], seq["depth"][t], seq["motion"][t],
                            tuple(float(v) for v in seq["jitter"][t]),
                            reset=self.always_reset or bool(seq["reset"][t]))


def _networks(weights):
    """Upscaler keyword arguments for --weights: None = the package default, `untrained`
    = the seeded init asked for explicitly, else a directory or .safetensors file."""
    if weights == UNTRAINED:
        from clss.networks import build_classifier, build_composition
        return {"classifier": build_classifier(), "composition": build_composition()}, False
    from clss.pipeline.upscaler import load_networks
    if weights is None:
        return {}, None
    cls, comp, trained = load_networks(weights)
    return {"classifier": cls, "composition": comp}, trained


def make_method(name, seq, dev, precision="fp32", net_kwargs=None):
    from clss.pipeline import Upscaler
    from clss.pipeline.contract import output_size
    h, w = seq["color"].shape[1:3]
    if name == "bicubic":
        return _Bicubic(dev, output_size(h, w, seq["scale"]))
    if name in ("jbicubic", "rules"):
        return Pipeline(Upscaler(seq["scale"], mode="rules", device=dev, precision=precision),
                         always_reset=name == "jbicubic")
    if name == "net":
        return Pipeline(Upscaler(seq["scale"], mode="net", device=dev, precision=precision,
                                  **(net_kwargs or {})))
    raise ValueError(f"method: expected one of {', '.join(METHODS)}, got {name!r}")


# ---------------------------------------------------------------- scoring

def scored_frames(reset, warmup):
    """Indices t scored: at least `warmup` frames after the last reset (frame 0 counts
    as one)."""
    out, since = [], 0
    for t, r in enumerate(reset):
        since = 0 if (r or t == 0) else since + 1
        if since >= warmup:
            out.append(t)
    return out


def _profile_place(ref_display):
    """(row, (x0, x1)) of the temporal profile: the row with the most horizontal detail
    (thin geometry, fine texture: where flicker shows) in the middle 80 % of the frame,
    over at most 320 columns centred on that row's most detailed part."""
    g = np.abs(np.diff(ref_display.mean(-1), axis=1))
    H, W = g.shape[0], g.shape[1] + 1
    lo, hi = H // 10, max(H - H // 10, H // 10 + 1)
    row = lo + int(np.argmax(g[lo:hi].sum(1)))
    n = min(W, 320)
    c = np.convolve(g[row], np.ones(n), mode="valid") if W > n else np.zeros(1)
    x0 = int(np.argmax(c))
    return row, (x0, x0 + n)


def _crop_box(ref_display, frac=4):
    """(y0, y1, x0, x1): an H/frac x W/frac region around the most detailed area."""
    g = np.abs(np.diff(ref_display.mean(-1), axis=1))
    H, W = ref_display.shape[:2]
    ch, cw = max(H // frac, 8), max(W // frac, 8)
    # detail per block of the crop's size, coarse grid of candidate positions
    best, box = -1.0, (0, min(ch, H), 0, min(cw, W))
    for y0 in range(0, max(H - ch, 0) + 1, max(ch // 2, 1)):
        for x0 in range(0, max(W - cw, 0) + 1, max(cw // 2, 1)):
            v = float(g[y0:y0 + ch, x0:x0 + cw].sum())
            if v > best:
                best, box = v, (y0, min(y0 + ch, H), x0, min(x0 + cw, W))
    return box


def evaluate_sequence(seq, methods, dev, *, precision="fp32", warmup=4, net_kwargs=None,
                      net_trained=None, out_dir=None, flip_every=1, log=sys.stderr, run=None):
    """Run every method over `seq` (load_sequence's dict) and score it. Returns the
    sequence's JSON record; writes the pictures under `out_dir` when given.
    `run`: {method: callable(seq, t) -> frame} to score instead of make_method's OpenCL
    runners (`seeds` passes the torch twin's); `flip_every=0` leaves FLIP out (None)."""
    from clss import metrics
    from clss.progress import progress
    T, h, w = seq["color"].shape[:3]
    H, W = seq["reference"].shape[1:3]
    scored = scored_frames(seq["reset"], warmup)
    if not scored:
        raise ValueError(f"{seq['path']}: no frame left to score after a warm-up of {warmup} "
                         f"frames per reset ({T} frames); lower --warmup")
    scored_set = set(scored)
    if run is None:
        run = {m: make_method(m, seq, dev, precision, net_kwargs) for m in methods}
    if "net" in run and net_trained is None:       # the package's default weights
        net_trained = run["net"].up.trained
    acc = {m: {"psnr": [], "ssim": [], "flip": [], "tpsnr": metrics.TemporalPSNR(), "s": 0.0}
           for m in methods}
    names = list(methods) + ["reference"]
    place = None
    lines = {m: [] for m in names}
    last = None
    flip_frames = scored[::int(flip_every)] if flip_every else []
    for t in progress(range(T), desc=seq["name"], unit="frame", total=T, file=log):
        ref = metrics.display(seq["reference"][t])
        if place is None and t in scored_set:
            place = _profile_place(ref)
        outs = {}
        for m in methods:
            t0 = time.perf_counter()
            outs[m] = run[m](seq, t)
            if t > 0 or T == 1:         # frame 0 pays for building the kernels
                acc[m]["s"] += time.perf_counter() - t0
        disp = {m: metrics.display(o) for m, o in outs.items()}
        for m in methods:
            a = acc[m]
            if t not in scored_set:
                a["tpsnr"].cut()
                continue
            a["psnr"].append(metrics.psnr(disp[m], ref, tonemapped=True))
            a["ssim"].append(metrics.ssim(disp[m], ref, tonemapped=True))
            if t in flip_frames:
                a["flip"].append(metrics.flip(disp[m], ref, tonemapped=True))
            a["tpsnr"].add(disp[m], ref)
        if t in scored_set:
            row, span = place
            for m in methods:
                lines[m].append(disp[m][row:row + 1, span[0]:span[1]])
            lines["reference"].append(ref[row:row + 1, span[0]:span[1]])
            last = dict(disp, reference=ref, input=_nearest(seq["color"][t], H, W), t=t)

    record = {"path": seq["path"], "frames": T, "render_size": [h, w], "output_size": [H, W],
              "scale": seq["scale"], "resets": int(np.sum(seq["reset"])), "warmup": warmup,
              "scored_frames": scored, "flip_frames": flip_frames,
              "tpsnr_pairs": None, "methods": {}}
    for m in methods:
        a = acc[m]
        record["methods"][m] = {
            "psnr": float(np.mean(a["psnr"])), "ssim": float(np.mean(a["ssim"])),
            "tpsnr": a["tpsnr"].value(), "flip": float(np.mean(a["flip"])) if a["flip"] else None,
            "ms_per_frame": a["s"] / max(T - 1, 1) * 1e3,
            "psnr_frames": a["psnr"], "ssim_frames": a["ssim"], "flip_frames": a["flip"]}
        record["tpsnr_pairs"] = a["tpsnr"].pairs // (H * W * 3)
    if "net" in methods:
        record["net_trained"] = bool(net_trained)
        record["net_weights"] = "trained" if net_trained else "untrained (seeded)"
    if out_dir is not None:
        record["pictures"] = _write_pictures(out_dir, seq, methods, lines, last, place,
                                             net_trained)
    return record


def _nearest(img, H, W):
    from clss.pipeline.baselines import nearest
    from clss import metrics
    return metrics.display(nearest(np.asarray(img, np.float32), H, W))


def _labels(methods, net_trained):
    out = []
    for m in methods:
        lab = METHOD_LABELS[m]
        if m == "net" and net_trained is False:
            lab += " (untrained)"
        out.append(lab)
    return out


def _write_pictures(out_dir, seq, methods, lines, last, place, net_trained):
    from clss import metrics
    d = os.path.join(out_dir, seq["name"])
    os.makedirs(d, exist_ok=True)
    labels = _labels(methods, net_trained)
    row, span = place
    T = len(lines["reference"])
    prof = os.path.join(d, "temporal_profile.png")
    metrics.save_temporal_profiles(prof, [lines[m] for m in list(methods) + ["reference"]],
                                   labels + ["reference"], row=0, repeat=max(1, 160 // T),
                                   tonemapped=True)
    order = ["input"] + list(methods) + ["reference"]
    pics = [last[k] for k in order]
    all_labels = ["input (nearest)"] + labels + ["reference"]
    side = os.path.join(d, "side_by_side.png")
    metrics.save_side_by_side(side, pics, all_labels, tonemapped=True)
    crop = _crop_box(last["reference"])
    side_crop = os.path.join(d, "side_by_side_crop.png")
    metrics.save_side_by_side(side_crop, pics, all_labels, tonemapped=True, crop=crop, zoom=3)
    return {"temporal_profile": prof, "profile_row": row, "profile_columns": list(span),
            "side_by_side": side, "side_by_side_crop": side_crop, "crop": list(crop),
            "frame": last["t"]}


# ---------------------------------------------------------------- report

COLUMNS = (("PSNR dB", "psnr", "{:8.2f}"), ("SSIM", "ssim", "{:7.4f}"),
           ("tPSNR dB", "tpsnr", "{:9.2f}"), ("FLIP", "flip", "{:7.4f}"),
           ("ms/frame", "ms_per_frame", "{:9.1f}"))


def format_table(methods_record, net_trained=None) -> str:
    names = list(methods_record)
    labels = dict(zip(names, _labels(names, net_trained)))
    width = max(len(v) for v in labels.values()) + 2
    head = f"{'method':{width}s}" + "".join(f"{c:>{len(f.format(0.0))}s}" for c, _, f in COLUMNS)
    rows = [head]
    for m in names:
        r = methods_record[m]
        rows.append(f"{labels[m]:{width}s}" + "".join(f.format(r[k]) for _, k, f in COLUMNS))
    return "\n".join(rows)


def mean_over_sequences(records) -> dict:
    """Per method, the mean of each column over the sequences."""
    methods = list(records[0]["methods"])
    return {m: {k: float(np.mean([r["methods"][m][k] for r in records])) for _, k, _ in COLUMNS}
            for m in methods}


def run_eval(paths, methods=METHODS, weights=None, precision="fp32", warmup=4,
             out_dir=os.path.join("out", "eval"), json_path=None, device=None, flip_every=1,
             log=sys.stderr) -> dict:
    """Evaluate `methods` on every sequence in `paths`; print the tables, write the
    pictures and the JSON (out_dir/eval.json, and `json_path` when given)."""
    from clss.device import get_device
    if warmup < 0:
        raise ValueError(f"warmup: expected a number of frames >= 0, got {warmup}")
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise ValueError(f"methods: expected a subset of {','.join(METHODS)}, got "
                         f"{','.join(methods)!r}")
    seqs_paths = list(paths)
    for p in seqs_paths:               # fail before any long run
        if not os.path.isfile(p):
            raise SequenceError(f"{p}: no such file")
    try:
        import flip_evaluator  # noqa: F401  (fail before any long run)
    except ImportError:
        raise ValueError("the FLIP column needs the flip-evaluator package: pip install "
                         "flip-evaluator (or pip install -e .[eval])") from None
    net_kwargs, trained = _networks(weights) if "net" in methods else ({}, None)
    dev = get_device(device)
    records = []
    for p in seqs_paths:
        seq = load_sequence(p)
        T, h, w = seq["color"].shape[:3]
        H, W = seq["reference"].shape[1:3]
        print(f"{seq['name']}: {T} frames {w}x{h} -> {W}x{H} (x{seq['scale']:g}), "
              f"{len(methods)} methods, {precision}", file=log, flush=True)
        rec = evaluate_sequence(seq, methods, dev, precision=precision, warmup=warmup,
                                net_kwargs=net_kwargs, net_trained=trained, out_dir=out_dir,
                                flip_every=flip_every, log=log)
        rec["name"] = seq["name"]
        records.append(rec)
        print(f"\n{seq['name']}: {T} frames, {w}x{h} -> {W}x{H} (x{seq['scale']:g}), "
              f"{len(rec['scored_frames'])} scored (warm-up {warmup} per reset), {precision}")
        trained = rec.get("net_trained", trained)
        print(format_table(rec["methods"], trained))
    result = {"device": dev.info.name, "precision": precision, "warmup": warmup,
              "net_weights": None if "net" not in methods else
              (os.fspath(weights) if weights not in (None, UNTRAINED) else
               weights or "package default"),
              "metrics": "tone-mapped (clss.io.tonemap) display values: PSNR, SSIM (scikit-image), "
                         "tPSNR (PSNR of frame differences), LDR-FLIP (flip-evaluator)",
              "sequences": records}
    if len(records) > 1:
        result["mean"] = mean_over_sequences(records)
        print(f"\nmean over {len(records)} sequences")
        print(format_table(result["mean"], trained))
    if out_dir is not None:
        os.makedirs(out_dir, exist_ok=True)
        _write_json(os.path.join(out_dir, "eval.json"), result)
    if json_path:
        _write_json(json_path, result)
    return result


def _write_json(path, obj):
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    tmp = path + ".tmp"
    with open(tmp, "w") as fh:
        json.dump(obj, fh, indent=1, default=_jsonable)
    os.replace(tmp, path)


def _jsonable(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    raise TypeError(f"not JSON serialisable: {type(v).__name__}")


# ---------------------------------------------------------------- command line

def add_arguments(p):
    p.add_argument("sequences", nargs="+", metavar="SEQ.npz",
                   help="sequences in the weights_tools/DATA.md format")
    p.add_argument("--methods", default=",".join(METHODS),
                   help=f"comma-separated subset of {','.join(METHODS)} (default: all)")
    p.add_argument("--weights", default=None,
                   help="net mode: a weights directory or .safetensors file, or 'untrained' "
                        "(the seeded init); default: the package's weights")
    p.add_argument("--precision", default="fp32", choices=("fp32", "fp16"))
    p.add_argument("--warmup", type=int, default=4,
                   help="frames after each reset that are not scored (default 4)")
    p.add_argument("--out", default=os.path.join("out", "eval"),
                   help="directory for eval.json and the per-sequence PNGs (default out/eval)")
    p.add_argument("--json", default=None, help="also write the JSON to this file")
    p.add_argument("--flip-every", type=int, default=1, metavar="K",
                   help="FLIP on every K-th scored frame (FLIP is the slowest metric; default 1)")
    p.add_argument("--device", default=None, help="OpenCL device (index or name substring)")


def main_args(a, parser) -> int:
    methods = [m.strip() for m in a.methods.split(",") if m.strip()]
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        parser.error(f"--methods: expected a subset of {','.join(METHODS)}, got {a.methods!r}")
    if a.warmup < 0:
        parser.error(f"--warmup: expected a number of frames >= 0, got {a.warmup}")
    if a.flip_every < 1:
        parser.error(f"--flip-every: expected an integer >= 1, got {a.flip_every}")
    if a.weights is not None and a.weights != UNTRAINED and not os.path.exists(a.weights):
        parser.error(f"--weights: {a.weights} does not exist (a weights directory, a "
                     f".safetensors file or '{UNTRAINED}')")
    run_eval(a.sequences, methods, weights=a.weights, precision=a.precision, warmup=a.warmup,
             out_dir=a.out, json_path=a.json, device=a.device, flip_every=a.flip_every)
    return 0
