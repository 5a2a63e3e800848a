"""`python -m weights_tools blender`: render the Blender scene families (families.py) into
DATA.md sequences, one shard (.npz) per sequence, fanned out on Ray (the [data] extra:
bpy and ray; the runtime never imports either).

    python -m weights_tools blender --out DIR [--split train,validation,test]
        [--sequences 2] [--families a,b] [--frames 12] [--size 90x160] [--scale 2]
        [--spp 16] [--ref-spp 32] [--hr-spp 1] [--jitter-mix MIX]
        [--twin DIR:MIX[:HxW] ...] [--jobs 2] [--threads 1] [--ray-address ADDR] [--no-ray]

Per split, DIR/<split>/<family>_<seed>.npz (seed = families.SEED_BASE[split] + k for the
k-th sequence of a family), a READY file once the split is complete and stats.json
(timings). Each sequence is one Ray task that renders its EXRs into DIR/.exr/<name>/
(render_validation.render_scene, bpy in the task's process), converts them
(convert.convert_scene: the contract's colour, depth, motion, G-buffers, reference) and
writes its shard atomically (scenegen.write_sequence: a temporary file, then a rename);
a killed run started again skips the shards that exist and renders only the rest.

--twin DIR:MIX[:HxW] (repeatable) also writes each sequence to DIR/<split>/<name>.npz with
another low-resolution input of the same frames: jitter drawn from MIX (e.g. `zero`), at
render size HxW (default --size; the scale is the output size over it, e.g. 45x80 for a 4x
twin of 90x160 at 2x). The twins share the reference and the output-resolution G-buffers
(render_validation.render_scene's `twins`), so a jitter-free or a 4x copy of a held-out
set costs its low-resolution renders only (make validation-data-game).

ray.init() starts a local Ray with --jobs worker slots unless --ray-address names a
cluster (its nodes need this package with the [data] extra installed); each task asks
Ray for --threads CPUs and gives Cycles that many threads (default 1 when --jobs > 1:
one Cycles thread per task, the tasks side by side). --no-ray renders the sequences one
after the other in this process (tests, debugging).
"""
from __future__ import annotations

import json
import os
import shutil
import sys
import time

from .. import jitter_mix
from . import families as fam

DEFAULTS = dict(frames=12, size=(90, 160), scale=2.0, spp=16, ref_spp=32, hr_spp=1,
                jitter_mix=jitter_mix.DEFAULT_MIX)


class UsageError(ValueError):
    """A mistake in the command line, said in its flags' words."""


def plan(out, splits, family_names, sequences):
    """[(split, family, seed, path)] of every shard asked for; a UsageError names a
    split or family that does not exist, or a test family asked for in another split."""
    jobs = []
    for split in splits:
        if split not in fam.SPLITS:
            raise UsageError(f"--split: unknown split {split!r} (have {', '.join(fam.SPLITS)})")
        names = family_names or fam.DEFAULT_FAMILIES[split]
        for f in names:
            if f not in fam.FAMILIES:
                raise UsageError(f"--families: unknown family {f!r} (have "
                                 f"{', '.join(fam.FAMILIES)})")
            if f not in fam.SPLITS[split]:
                where = "test" if f in fam.HELD_OUT else "train and validation"
                raise UsageError(f"--families: {f} belongs to the {where} split(s), not "
                                 f"{split} (held-out families never render into training)")
            for k in range(sequences):
                seed = fam.SEED_BASE[split] + k
                jobs.append((split, f, seed,
                             os.path.join(out, split, f"{f}_{seed:06d}.npz")))
    return jobs


def parse_twin(text, size, scale):
    """--twin DIR:MIX[:HxW] -> {"dir", "mix", "size": (h, w), "scale"}; the scale makes the
    twin's output size the main one's (floor(h * scale + 0.5) as everywhere). UsageError
    naming what is wrong."""
    parts = text.split(":")
    if len(parts) not in (2, 3) or not parts[0] or not parts[1]:
        raise UsageError(f"--twin: {text!r}: expected DIR:MIX or DIR:MIX:HxW")
    try:
        jitter_mix.check_arg("--twin", parts[1])
    except ValueError as e:
        raise UsageError(str(e)) from None
    h, w = size
    H, W = int(h * scale + 0.5), int(w * scale + 0.5)
    th, tw = size
    if len(parts) == 3:
        try:
            th, tw = (int(v) for v in parts[2].lower().split("x"))
        except ValueError:
            raise UsageError(f"--twin: {text!r}: size {parts[2]!r} is not HxW") from None
    tscale = H / th
    if not 1.0 <= tscale <= 4.0 or (int(th * tscale + 0.5), int(tw * tscale + 0.5)) != (H, W):
        raise UsageError(f"--twin: {text!r}: {th}x{tw} does not scale to the output size "
                         f"{H}x{W} by one factor in [1, 4]")
    return {"dir": parts[0], "mix": parts[1], "size": (th, tw), "scale": tscale}


def twin_paths(job, opts):
    """The paths of a job's twin shards (opts["twins"])."""
    split, _, _, path = job
    return [os.path.join(t["dir"], split, os.path.basename(path)) for t in opts.get("twins", ())]


def render_shard(job, opts):
    """Render one sequence and write its shard (runs in a Ray worker, or here with
    --no-ray), and its twins' (opts["twins"]). Returns {"path", "frames", "seconds",
    "render_seconds"}."""
    import numpy as np

    from .. import scenegen
    from . import convert
    from . import render_validation as rv
    split, family, seed, path = job
    t0 = time.perf_counter()
    drawn = shard_jitter(job, opts)
    twins = opts.get("twins", ())
    twin_drawn = [shard_jitter(job, dict(opts, jitter_mix=t["mix"])) for t in twins]
    name = os.path.splitext(os.path.basename(path))[0]
    exr = os.path.join(os.path.dirname(os.path.dirname(path)), ".exr", f"{split}_{name}")
    shutil.rmtree(exr, ignore_errors=True)
    os.makedirs(exr)
    # Blender writes its render log (and bpy's import its warnings) to the C stdout and
    # stderr: into the shard's log file, not over the progress bar.
    log_path = os.path.join(exr, "blender.log")
    saved = [os.dup(1), os.dup(2)]
    try:
        with open(log_path, "w") as log:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(log.fileno(), 1)
            os.dup2(log.fileno(), 2)
            try:
                h, w = opts["size"]
                rec = rv.render_scene(family, exr, opts["frames"], (w, h), opts["scale"],
                                      opts["spp"], opts["ref_spp"], opts["hr_spp"],
                                      build=fam.builder(family, seed), threads=opts["threads"],
                                      log=None, jitter=jitter_mix.sequence_jitter(
                                          drawn, opts["frames"], opts["scale"]).tolist(),
                                      twins=[dict(name=f"twin{k}", size=(t["size"][1],
                                                                         t["size"][0]),
                                                  scale=t["scale"],
                                                  jitter=jitter_mix.sequence_jitter(
                                                      d, opts["frames"], t["scale"]).tolist())
                                             for k, (t, d) in enumerate(zip(twins, twin_drawn))])
            finally:
                sys.stdout.flush()
                sys.stderr.flush()
                os.dup2(saved[0], 1)
                os.dup2(saved[1], 2)
    finally:
        for fd in saved:
            os.close(fd)
    outs = [(path, None, drawn, opts.get("jitter_mix", DEFAULTS["jitter_mix"]))]
    outs += [(p, f"twin{k}", d, t["mix"]) for k, (p, t, d) in
             enumerate(zip(twin_paths(job, opts), twins, twin_drawn))]
    # the twins first: the main shard's presence says the job is done (a resumed run)
    for out_path, twin, jit, mix in outs[1:] + outs[:1]:
        data = convert.convert_scene(exr, twin=twin)
        meta = json.loads(str(data["meta"]))
        meta.update(generator="weights_tools.blender.shards", family=family, seed=seed,
                    split=split, frames=opts["frames"], jitter=jit, jitter_mix=mix)
        if twin is not None:
            meta["twin_of"] = os.path.relpath(path, os.path.dirname(os.path.dirname(
                os.path.dirname(out_path))))
        data["meta"] = np.array(json.dumps(meta))
        os.makedirs(os.path.dirname(out_path), exist_ok=True)
        scenegen.write_sequence(out_path, data)
    shutil.rmtree(exr, ignore_errors=True)
    render_s = sum(rec["seconds"].values())
    return {"path": path, "frames": opts["frames"], "seconds": time.perf_counter() - t0,
            "render_seconds": render_s}


def shard_jitter(job, opts):
    """The shard's jitter draw (jitter_mix.draw): its own stream of (family, seed), so a
    shard renders the same whatever else is rendered beside it."""
    import zlib

    import numpy as np
    _, family, seed, _ = job
    key = [int(seed), zlib.crc32(family.encode()), 0x717]
    return jitter_mix.draw(opts.get("jitter_mix", DEFAULTS["jitter_mix"]),
                           np.random.default_rng(key))


def _ray_results(todo, opts, address, jobs):
    """Yield render_shard's results as the Ray tasks finish."""
    import ray
    if address:
        ray.init(address=address, log_to_driver=False)
    else:
        ray.init(num_cpus=jobs * opts["threads"], include_dashboard=False,
                 log_to_driver=False, configure_logging=False)
    try:
        task = ray.remote(render_shard).options(num_cpus=opts["threads"], max_retries=1)
        pending = [task.remote(j, opts) for j in todo]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            yield ray.get(ready[0])
    finally:
        ray.shutdown()


def run(out, splits, family_names=None, sequences=2, jobs=2, threads=None, ray_address=None,
        use_ray=True, log=sys.stderr, **render):
    """Render every missing shard of `splits`; returns the stats dict."""
    from clss.progress import progress
    opts = dict(DEFAULTS, **render)
    jobs = jobs if use_ray else 1
    opts["threads"] = threads or (1 if jobs > 1 or ray_address else max(1, os.cpu_count() or 1))
    all_jobs = plan(out, splits, family_names, sequences)
    todo = [j for j in all_jobs
            if not all(os.path.isfile(p) for p in [j[3]] + twin_paths(j, opts))]
    if len(todo) < len(all_jobs):
        print(f"{len(all_jobs) - len(todo)} of {len(all_jobs)} shards already rendered "
              f"(kept)", file=log, flush=True)
    done = {"n": 0, "frames": 0, "task_s": 0.0, "render_s": 0.0}
    t0 = time.perf_counter()
    results = (_ray_results(todo, opts, ray_address, jobs) if use_ray and todo
               else (render_shard(j, opts) for j in todo))

    def status():
        dt = time.perf_counter() - t0
        return f"{done['frames']} frames, {done['frames'] / dt:.3f} frames/s"
    # One item per finished sequence (a task reports when its shard is written); the
    # status gives the frames and frames per second.
    for r in progress(results, desc="blender", unit="sequence", total=len(todo), file=log,
                      status=status):
        done["n"] += 1
        done["frames"] += r["frames"]
        done["task_s"] += r["seconds"]
        done["render_s"] += r["render_seconds"]
    wall = time.perf_counter() - t0
    stats = dict(sequences=len(todo), kept=len(all_jobs) - len(todo), frames=done["frames"],
                 seconds=round(wall, 1), task_seconds=round(done["task_s"], 1),
                 render_seconds=round(done["render_s"], 1),
                 seconds_per_frame=round(wall / done["frames"], 2) if done["frames"] else None,
                 fanout=round(done["task_s"] / wall, 2) if done["frames"] else None,
                 jobs=jobs, threads=opts["threads"], ray=bool(use_ray),
                 ray_address=ray_address,
                 render={k: list(v) if k == "size" else v for k, v in opts.items()})
    for split in splits:
        for k, root in enumerate([out] + [t["dir"] for t in opts.get("twins", ())]):
            d = os.path.join(root, split)
            paths = [j[3] if k == 0 else twin_paths(j, opts)[k - 1]
                     for j in all_jobs if j[0] == split]
            if all(os.path.isfile(p) for p in paths):
                with open(os.path.join(d, "stats.json"), "w") as fh:
                    json.dump(dict(stats, split=split, **({"twin_of": out} if k else {})),
                              fh, indent=1)
                with open(os.path.join(d, "READY"), "w") as fh:
                    fh.write(json.dumps({"shards": len(paths)}) + "\n")
    shutil.rmtree(os.path.join(out, ".exr"), ignore_errors=True)
    return stats


def add_parser(sub, _size):
    """The `blender` sub-command; `_size`: the HxW argument type of `gen`."""
    p = sub.add_parser("blender", help="render the Blender scene families into DATA.md "
                       "shards on Ray (needs the [data] extra: bpy, ray)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="directory (created; kept shards are skipped)")
    p.add_argument("--split", default="train,validation,test",
                   help=f"comma-separated splits of {','.join(fam.SPLITS)}")
    p.add_argument("--families", default=None,
                   help=f"comma-separated families (default: the split's, the test split's "
                   f"{','.join(fam.TEST_FAMILIES)}; {','.join(fam.FAMILIES)})")
    p.add_argument("--sequences", type=int, default=2, help="sequences per family and split")
    p.add_argument("--frames", type=int, default=DEFAULTS["frames"])
    p.add_argument("--size", type=_size, default=DEFAULTS["size"], help="render size HxW")
    p.add_argument("--scale", type=float, default=DEFAULTS["scale"])
    p.add_argument("--spp", type=int, default=DEFAULTS["spp"],
                   help="samples per render pixel (point-sampled colour)")
    p.add_argument("--ref-spp", type=int, default=DEFAULTS["ref_spp"],
                   help="samples per output pixel of the reference")
    p.add_argument("--hr-spp", type=int, default=DEFAULTS["hr_spp"],
                   help="samples of the output-resolution G-buffer render")
    p.add_argument("--jitter-mix", default=DEFAULTS["jitter_mix"],
                   help="each sequence's jitter pattern drawn from NAME[:WEIGHT],... as `gen "
                   "--jitter-mix` (one name: that pattern; the shards before issue 53: halton)")
    p.add_argument("--twin", action="append", default=[], metavar="DIR:MIX[:HxW]",
                   help="also write each sequence to DIR/<split>/ with its own low-resolution "
                   "input: jitter from MIX (e.g. zero), render size HxW (default --size; "
                   "e.g. 45x80 for a 4x twin of 90x160 at 2x), the same reference and "
                   "output-resolution G-buffers; repeatable")
    p.add_argument("--jobs", type=int, default=2, help="tasks side by side on a local Ray")
    p.add_argument("--threads", type=int, default=None,
                   help="Cycles threads (and Ray CPUs) per task; default 1 when fanned out")
    p.add_argument("--ray-address", default=None, help="a Ray cluster's address "
                   "(default: a local Ray of --jobs slots)")
    p.add_argument("--no-ray", action="store_true",
                   help="render here, one sequence after the other")
    p.set_defaults(fn=main_args)
    return p


def main_args(a):
    for flag, v in (("--sequences", a.sequences), ("--frames", a.frames), ("--spp", a.spp),
                    ("--ref-spp", a.ref_spp), ("--hr-spp", a.hr_spp), ("--jobs", a.jobs),
                    ("--threads", a.threads or 1)):
        if v < 1:
            print(f"error: {flag} must be at least 1, got {v}", file=sys.stderr)
            return 2
    if not 1.0 <= a.scale <= 4.0:
        print(f"error: --scale must be in [1, 4], got {a.scale}", file=sys.stderr)
        return 2
    try:
        jitter_mix.check_arg("--jitter-mix", a.jitter_mix)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    splits = [s for s in a.split.split(",") if s]
    families = [f for f in a.families.split(",") if f] if a.families else None
    try:
        plan(a.out, splits, families, a.sequences)   # a flag's mistake first, bpy or not
        twins = [parse_twin(t, a.size, a.scale) for t in a.twin]
    except UsageError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    missing = [m for m in ("bpy",) + (() if a.no_ray else ("ray",)) if not _importable(m)]
    if missing:
        print(f"error: blender needs {' and '.join(missing)} (pip install -e '.[data]')",
              file=sys.stderr)
        return 2
    try:
        stats = run(a.out, splits, families, a.sequences, a.jobs, a.threads,
                    a.ray_address, not a.no_ray,
                    frames=a.frames, size=a.size, scale=a.scale, spp=a.spp,
                    ref_spp=a.ref_spp, hr_spp=a.hr_spp, jitter_mix=a.jitter_mix,
                    **({"twins": twins} if twins else {}))
    except UsageError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if stats["frames"]:
        print(f"rendered {stats['sequences']} sequences ({stats['frames']} frames) into "
              f"{a.out} in {stats['seconds']:.1f} s: {stats['seconds_per_frame']:.2f} s per "
              f"frame wall, {stats['task_seconds'] / stats['frames']:.2f} s per frame per "
              f"task; fan-out {stats['fanout']:.2f} tasks busy on average "
              f"({stats['jobs']} slots x {stats['threads']} Cycles thread(s))")
    else:
        print(f"nothing to render: every shard of {a.split} is in {a.out}")
    return 0


def _importable(name):
    import importlib.util
    return importlib.util.find_spec(name) is not None
