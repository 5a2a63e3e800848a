"""Evaluation of any set of methods on rendered sequences against their references: the
one scoring code of `clss eval` and `python -m weights_tools eval` (and of `seeds`, which
scores the torch twins through `evaluate_sequence(run=...)`).

    clss eval SEQ.npz [SEQ.npz ...] [--methods bicubic,jbicubic,clss-rules,clss]
        [--weights PATH|untrained] [--precision fp32|fp16] [--warmup 4] [--out DIR] [--json FILE]

Sequences are .npz files in the format of weights_tools/DATA.md (inputs in clss's frame
contract, optional G-buffers, plus the supersampled reference). Methods are the names of
clss.methods (`clss methods` lists them; the older `rules` and `net` are aliases of
clss-rules and clss), each run through clss.Upscaler(method=...) at the sequence's scale;
--weights goes to the method with trained weights (`untrained`: to every such method).

Scores (clss.metrics, on tone-mapped display values, as every clss metric): PSNR and SSIM
per frame, averaged; tPSNR, the PSNR of the frame differences (out_t - out_{t-1} against
ref_t - ref_{t-1}, one MSE over all scored pairs: flicker the reference does not have
lowers it); LDR-FLIP, mean per frame; disocclusion PSNR, the PSNR over the pixels whose
reprojection to the previous frame fails the depth test (clss.metrics.disocclusion_mask:
off screen, or a view depth 10 % away), one MSE over the sequence: where a history can
only ghost, so a temporal method scores below the jitter-aware bicubic there exactly when
it ghosts. A frame is scored once `warmup` frames have passed since the last reset (the
history has warmed up); no difference is taken across a reset.

This module is part of the runtime: it never imports torch (an integrator scores methods on
their own captures without the [train] extra).
"""
from __future__ import annotations

import json
import os
import sys
import time

import numpy as np

from . import methods as method_registry
from .pipeline.method import UNTRAINED

# The default set: every method that needs no G-buffer.
METHODS = ("bicubic", "jbicubic", "clss-rules", "clss")
INPUT_KEYS = ("color", "depth", "motion", "jitter", "reset", "reference")


class SequenceError(ValueError):
    """A sequence file that is not in the weights_tools/DATA.md format."""


def load_sequence(path) -> dict:
    """The arrays of one DATA.md sequence, checked: {"name", "path", "color" [T,h,w,3],
    "depth" [T,h,w], "motion" [T,h,w,2], "jitter" [T,2], "reset" [T] bool, "reference"
    [T,H,W,3], "scale" float}. Raises SequenceError naming the file and the key."""
    from .pipeline import contract
    from .pipeline.contract import output_size
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
        seq["gbuffers"] = {k: z[k] for k in getattr(contract, "GBUFFERS", ()) if k in z.files}
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

def canonical_methods(names) -> list[str]:
    """Registry names (aliases resolved, order kept, duplicates dropped); a ValueError
    names an unknown one and lists the methods."""
    out = []
    for n in names:
        c = method_registry.canonical(n)
        if c not in out:
            out.append(c)
    if not out:
        raise ValueError(f"methods: expected a comma-separated subset of "
                         f"{','.join(method_registry.names())}, got none")
    return out


def label(name) -> str:
    try:
        return method_registry.spec(name).label
    except ValueError:
        return str(name)


class Pipeline:
    """An upscaler with clss.Upscaler's `step` (any method's, or the torch twin's
    TorchUpscaler in `seeds`) over a sequence; the sequence's G-buffers go with each frame."""

    def __init__(self, upscaler):
        self.up = upscaler

    def __call__(self, seq, t):
        gb = {k: v[t] for k, v in seq.get("gbuffers", {}).items()}
        return self.up.step(seq["color"][t], seq["depth"][t], seq["motion"][t],
                            tuple(float(v) for v in seq["jitter"][t]),
                            reset=bool(seq["reset"][t]), **gb)


def _trainable(name) -> bool:
    """Whether method `name` has weights (False for a name the registry does not know: a
    caller's own runner)."""
    try:
        return method_registry.spec(name).weights() != "none needed"
    except ValueError:
        return False


def method_kwargs(weights, methods=()):
    """(Upscaler keyword arguments for --weights, trained): None = the package default,
    `untrained` = the seeded init asked for explicitly (every method with trained
    weights), else a weights file or directory, for the one such method among `methods`
    (a ValueError if several would share it); each method reads its own format."""
    if weights is None:
        return {}, None
    if weights == UNTRAINED:
        return {"weights": UNTRAINED}, False
    takers = [m for m in methods if _trainable(m)]
    if len(takers) > 1:
        raise ValueError(f"weights: a weights file is one method's, but {', '.join(takers)} "
                         f"all take weights; evaluate them in separate runs")
    return {"weights": os.fspath(weights)}, True


def make_method(name, seq, dev, precision="fp32", net_kwargs=None):
    """The runner of method `name` on `seq`: clss.Upscaler(method=name) at its scale;
    `net_kwargs` go to the methods with trained weights, each getting those it takes."""
    from .upscaler import Upscaler
    kw = method_registry.options(name, **(net_kwargs or {})) if _trainable(name) else {}
    return Pipeline(Upscaler(method=name, scale=seq["scale"], device=dev, precision=precision,
                             **kw))


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
    from . import metrics
    from .progress import progress
    T, h, w = seq["color"].shape[:3]
    H, W = seq["reference"].shape[1:3]
    scored = scored_frames(seq["reset"], warmup)
    if not scored:
        raise ValueError(f"{seq['path']}: no frame left to score after a warm-up of {warmup} "
                         f"frames per reset ({T} frames); lower --warmup")
    scored_set = set(scored)
    if run is None:
        run = {m: make_method(m, seq, dev, precision, net_kwargs) for m in methods}
    # Each method with weights says whether they are trained (its upscaler's `trained`; the
    # package's default weights unless --weights chose), or `net_trained` says it for all.
    trained = {m: bool(net_trained) if net_trained is not None else
               getattr(getattr(run[m], "up", None), "trained", None)
               for m in methods if _trainable(m)}
    acc = {m: {"psnr": [], "ssim": [], "flip": [], "tpsnr": metrics.TemporalPSNR(), "s": 0.0,
               "dis": [0.0, 0]} for m in methods}
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
        dis = None
        if t in scored_set and t > 0 and not seq["reset"][t]:
            dis = metrics.disocclusion_mask(seq["depth"][t - 1], seq["depth"][t],
                                            seq["motion"][t], (H, W))
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
            if dis is not None:
                se, n = metrics.masked_psnr_terms(disp[m], ref, dis)
                a["dis"][0] += se
                a["dis"][1] += n
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
            "disocclusion_psnr": _psnr_of(*a["dis"]), "disocclusion_pixels": a["dis"][1] // 3,
            "ms_per_frame": a["s"] / max(T - 1, 1) * 1e3,
            "psnr_frames": a["psnr"], "ssim_frames": a["ssim"], "flip_frames": a["flip"],
            "trained": trained.get(m)}
        record["tpsnr_pairs"] = a["tpsnr"].pairs // (H * W * 3)
    if trained:     # the keys of earlier records: every method with weights trained?
        record["net_trained"] = all(v is not False for v in trained.values())
        record["net_weights"] = "trained" if record["net_trained"] else "untrained (seeded)"
    if out_dir is not None:
        record["pictures"] = _write_pictures(out_dir, seq, methods, lines, last, place,
                                             _untrained(record["methods"]))
    return record


def _psnr_of(se, n):
    """PSNR (peak 1) of a summed squared error over n values; None without values."""
    if n == 0:
        return None
    mse = se / n
    return float("inf") if mse == 0 else float(10.0 * np.log10(1.0 / mse))


def _nearest(img, H, W):
    from . import metrics
    return metrics.display(metrics.nearest(np.asarray(img, np.float32), H, W))


def _untrained(methods_record, net_trained=None) -> set:
    """The methods of a record whose weights are the seeded init (each method's own
    "trained"; net_trained=False marks every method with weights)."""
    return {m for m, r in methods_record.items()
            if r.get("trained") is False or (net_trained is False and _trainable(m))}


def _labels(methods, untrained=()):
    return [label(m) + (" (untrained)" if m in untrained else "") for m in methods]


def _write_pictures(out_dir, seq, methods, lines, last, place, untrained):
    from . import metrics
    d = os.path.join(out_dir, seq["name"])
    os.makedirs(d, exist_ok=True)
    labels = _labels(methods, untrained)
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
           ("disocc dB", "disocclusion_psnr", "{:10.2f}"),
           ("ms/frame", "ms_per_frame", "{:9.1f}"))


def format_table(methods_record, net_trained=None) -> str:
    names = list(methods_record)
    labels = dict(zip(names, _labels(names, _untrained(methods_record, net_trained))))
    width = max(len(v) for v in labels.values()) + 2
    head = f"{'method':{width}s}" + "".join(f"{c:>{len(f.format(0.0))}s}" for c, _, f in COLUMNS)
    rows = [head]
    for m in names:
        r = methods_record[m]
        rows.append(f"{labels[m]:{width}s}" + "".join(
            f.format(r[k]) if r.get(k) is not None else f"{'-':>{len(f.format(0.0))}s}"
            for _, k, f in COLUMNS))
    return "\n".join(rows)


def mean_over_sequences(records) -> dict:
    """Per method, the mean of each column over the sequences (those that have it: FLIP
    may be off, a sequence may have no disoccluded pixel, and a method may have been
    skipped on a sequence without the G-buffers it needs)."""
    def mean(values):
        v = [x for x in values if x is not None]
        return float(np.mean(v)) if v else None
    methods = []
    for r in records:
        methods += [m for m in r["methods"] if m not in methods]
    return {m: {k: mean([r["methods"][m].get(k) for r in records if m in r["methods"]])
                for _, k, _ in COLUMNS}
            for m in methods}


def missing_gbuffers(name, seq) -> tuple:
    """The G-buffers method `name` needs (its spec's `gbuffers`) that `seq` does not
    carry; () for a name the registry does not know (a caller's own runner)."""
    try:
        needs = method_registry.spec(name).gbuffers
    except ValueError:
        return ()
    return tuple(g for g in needs if g not in seq.get("gbuffers", {}))


def run_eval(paths, methods=METHODS, weights=None, precision="fp32", warmup=4,
             out_dir=os.path.join("out", "eval"), json_path=None, device=None, flip_every=1,
             log=sys.stderr) -> dict:
    """Evaluate `methods` on every sequence in `paths`; print the tables, write the
    pictures and the JSON (out_dir/eval.json, and `json_path` when given)."""
    from .device import get_device
    if warmup < 0:
        raise ValueError(f"warmup: expected a number of frames >= 0, got {warmup}")
    methods = canonical_methods(methods)
    seqs_paths = list(paths)
    for p in seqs_paths:               # fail before any long run
        if not os.path.isfile(p):
            raise SequenceError(f"{p}: no such file")
    try:
        import flip_evaluator  # noqa: F401  (fail before any long run)
    except ImportError:
        raise ValueError("the FLIP column needs the flip-evaluator package: pip install "
                         "flip-evaluator (or pip install -e .[eval])") from None
    net_kwargs, trained = (method_kwargs(weights, methods) if any(map(_trainable, methods))
                           else ({}, None))
    dev = get_device(device)
    records, short = [], []
    for p in seqs_paths:
        seq = load_sequence(p)
        T, h, w = seq["color"].shape[:3]
        H, W = seq["reference"].shape[1:3]
        # A method that needs a G-buffer this sequence lacks skips this sequence only.
        skipped = {m: missing_gbuffers(m, seq) for m in methods}
        skipped = {m: g for m, g in skipped.items() if g}
        for m, g in skipped.items():
            print(f"skip {m} on {seq['name']}: it needs the G-buffer(s) {', '.join(g)}, "
                  f"which {seq['path']} does not carry", file=log, flush=True)
        these = [m for m in methods if m not in skipped]
        if not these:
            print(f"skip {seq['name']}: no method left to score", file=log, flush=True)
            continue
        if not scored_frames(seq["reset"], warmup):
            # (a sequence cut often, e.g. Blender's `cuts` family, next to longer shots)
            short.append(f"{seq['path']}: no frame left to score after a warm-up of {warmup} "
                         f"frames per reset ({T} frames); lower --warmup")
            print(f"skip {seq['name']}: {short[-1].split(': ', 1)[1]}", file=log, flush=True)
            continue
        print(f"{seq['name']}: {T} frames {w}x{h} -> {W}x{H} (x{seq['scale']:g}), "
              f"{len(these)} methods, {precision}", file=log, flush=True)
        rec = evaluate_sequence(seq, these, dev, precision=precision, warmup=warmup,
                                net_kwargs=net_kwargs, net_trained=trained, out_dir=out_dir,
                                flip_every=flip_every, log=log)
        rec["name"] = seq["name"]
        if skipped:
            rec["skipped"] = {m: {"missing_gbuffers": list(g)} for m, g in skipped.items()}
        records.append(rec)
        print(f"\n{seq['name']}: {T} frames, {w}x{h} -> {W}x{H} (x{seq['scale']:g}), "
              f"{len(rec['scored_frames'])} scored (warm-up {warmup} per reset), {precision}")
        trained = rec.get("net_trained", trained)
        print(format_table(rec["methods"], trained))
    if short and not records:
        raise ValueError(short[0])
    result = {"device": dev.info.name, "precision": precision, "warmup": warmup,
              "net_weights": None if "clss" not in methods else
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
                   help=f"comma-separated methods (`clss methods` lists them: "
                        f"{','.join(method_registry.names())}; rules and net are aliases of "
                        f"clss-rules and clss); default {','.join(METHODS)}")
    p.add_argument("--weights", default=None,
                   help="the trained methods' weights (clss): a weights directory or "
                        ".safetensors file, or 'untrained' (the seeded init); default: the "
                        "package's weights")
    p.add_argument("--precision", default="fp32", choices=("fp32", "fp16"))
    p.add_argument("--warmup", type=int, default=4,
                   help="frames after each reset that are not scored (default 4)")
    p.add_argument("--out", default=os.path.join("out", "eval"),
                   help="directory for eval.json and the per-sequence PNGs (default out/eval)")
    p.add_argument("--json", default=None, help="also write the JSON to this file")
    p.add_argument("--flip-every", type=int, default=1, metavar="K",
                   help="FLIP on every K-th scored frame (FLIP is the slowest metric; default 1)")
    p.add_argument("--device", default=None, help="OpenCL device (index or name substring)")


def main_args(a, parser, log=sys.stderr) -> int:
    try:
        methods = canonical_methods(m.strip() for m in a.methods.split(",") if m.strip())
    except ValueError as e:
        parser.error(f"--methods: expected a subset of {','.join(method_registry.names())} "
                     f"(`clss methods`), got {a.methods!r}: {e}")
    if a.warmup < 0:
        parser.error(f"--warmup: expected a number of frames >= 0, got {a.warmup}")
    if a.flip_every < 1:
        parser.error(f"--flip-every: expected an integer >= 1, got {a.flip_every}")
    if a.weights is not None and a.weights != UNTRAINED and not os.path.exists(a.weights):
        parser.error(f"--weights: {a.weights} does not exist (a weights directory, a "
                     f".safetensors file or '{UNTRAINED}')")
    run_eval(a.sequences, methods, weights=a.weights, precision=a.precision, warmup=a.warmup,
             out_dir=a.out, json_path=a.json, device=a.device, flip_every=a.flip_every,
             log=log)
    return 0
