"""`clss batch IN... -o OUT`: many sequences through Ray, one worker per OpenCL device
(batch_work.py), each sequence into OUT/<its name>/ as `clss upscale` would write it;
a killed batch run again resumes (batch_resume.py). Ray is the [batch] extra: it is
imported here when the command runs, never by `import clss` (.importlinter)."""
from __future__ import annotations

import argparse
import os
import re
import sys
import time
from collections import deque
from contextlib import contextmanager

from .args import ArgParser, UsageError
from .upscale import _method_options, add_upscale_options, check_method, parse_channels

RAY_MISSING = ("clss batch runs on Ray, which is not installed: pip install 'clss[batch]' "
               "(or pip install 'ray>=2.9')")
# Seconds a worker waits after each frame it writes: tests kill a batch mid-run with it.
DELAY_ENV = "CLSS_BATCH_FRAME_DELAY"


def _parser() -> ArgParser:
    p = ArgParser(
        prog="clss batch",
        description="Upscale many sequences on Ray, one worker per OpenCL device (every GPU, "
                    "else the default CPU device, on every machine of the Ray cluster; "
                    "--device picks one). Each IN is a sequence as `clss upscale` reads it; its "
                    "frames go to OUT/<name>/, name being its directory's. Run the same command "
                    "again after a kill and it resumes: finished frames are kept, not redone. "
                    "A sequence that fails is reported and the others go on; the exit status is "
                    "1 if any failed. docs/batch.md has the details.",
        epilog="examples:\n  clss batch shots/*/ -o out/ --method clss-rules\n"
               "  clss batch shots/a shots/b -o out/ --ray-address auto --png",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inputs", nargs="+", metavar="IN",
                   help="sequences: directories, globs or numbered patterns, as `clss upscale` "
                        "takes them")
    p.add_argument("-o", "--out", required=True,
                   help="output directory: each sequence's frames go to OUT/<name>/")
    p.add_argument("--overwrite", action="store_true",
                   help="make every frame again, replacing a previous run's output (default: "
                        "keep the finished frames of a run with the same options, resuming it)")
    p.add_argument("--ray-address", default=None, metavar="ADDR",
                   help="the Ray cluster to run on ('auto', or host:port); default: a local Ray "
                        "started for this run (its machines need clss[batch] and see IN and OUT "
                        "at the same paths)")
    return add_upscale_options(p)


def output_names(inputs) -> list:
    """OUT/<name> for each input: its directory's name (a pattern's or glob's directory
    and file stem), with as many parent names as it takes to tell them apart."""
    parts = []
    for src in inputs:
        path = os.path.abspath(src)
        if not os.path.isdir(path):
            stem = re.split(r"[#%*?\[{]|\d+\.", os.path.basename(path))[0].rstrip("._-")
            path = os.path.join(os.path.dirname(path), stem or "frames")
        parts.append([c for c in path.split(os.sep) if c] or ["root"])
    k = [1] * len(parts)
    while True:
        names = ["_".join(p[-j:]) for p, j in zip(parts, k)]
        clash = [i for i, n in enumerate(names) if names.count(n) > 1]
        if not clash:
            return names
        grow = [i for i in clash if k[i] < len(parts[i])]
        if not grow:
            raise UsageError(f"IN: {inputs[clash[0]]} is given twice")
        for i in grow:
            k[i] += 1


def cmd_batch(argv) -> int:
    p = _parser()
    a = p.parse_args(argv)
    name, _ = check_method(p, a)
    for ext in _method_options():
        taken = ext.check(a, name, UsageError)
        if taken:   # a learner per sequence, saved where? one run, one sequence
            raise UsageError(f"--{next(iter(taken)).replace('_', '-')}: not in clss batch; "
                             "run clss upscale for each sequence")
    parse_channels(a.channels)
    if os.path.exists(a.out) and not os.path.isdir(a.out):
        raise UsageError(f"-o {a.out}: is a file, expected a directory")
    jobs, total = _plan(a, name)
    try:
        import ray
    except ImportError:
        raise UsageError(RAY_MISSING) from None
    print(f"clss batch: {len(jobs)} sequences, {total} frames -> {a.out}, method {name}, "
          f"x{a.scale:g}, {a.precision}", file=sys.stderr)
    results, written, t0 = [], [0], time.perf_counter()
    try:
        with _session(ray, a.ray_address):
            workers = _start_workers(ray, a.device)
            try:
                _progress(ray, workers, jobs, total, results, written)
            finally:
                for w in workers:
                    ray.kill(w)
    except KeyboardInterrupt:
        print(f"\nclss batch: interrupted; {written[0]} frames written to {a.out}; the "
              "same command resumes", file=sys.stderr)
        return 130
    return _summary(a, jobs, results, time.perf_counter() - t0)


def _plan(a, name):
    """(jobs, frames in all): a job per sequence, after the checks that are the command
    line's mistake rather than one sequence's, so that they end the run before Ray starts:
    an output directory of another run, a flag the method cannot honour (checked on the
    first sequence that reads; each worker checks its own again)."""
    from .. import methods
    from ..io import read_sequence
    from .batch_resume import Journal, settings_of
    from .upscaler_common import contract_of_args
    # Paths as the workers see them: their working directory is not this one.
    args = dict(vars(a), method=name, mode=None,    # --mode rules = --method clss-rules
                **{k: os.path.abspath(getattr(a, k)) for k in ("jitter", "weights")
                   if getattr(a, k) and os.path.exists(getattr(a, k))})
    jobs = [dict(index=i, name=n, input=os.path.abspath(src), given=src, method=name,
                 out=os.path.join(os.path.abspath(a.out), n), args=args,
                 delay=float(os.environ.get(DELAY_ENV) or 0))
            for i, (src, n) in enumerate(zip(a.inputs, output_names(a.inputs)))]
    total, checked = 0, False
    for job in jobs:
        Journal(job["out"]).check(settings_of(args), a.overwrite)
        try:        # what cannot be read here is its worker's to report
            seq = read_sequence(job["input"], channels=parse_channels(a.channels),
                                jitter=a.jitter, scale=a.scale)
            first = None if checked else seq[0]
        except (ValueError, OSError):
            continue
        total += len(seq) if a.frames is None else min(len(seq), a.frames)
        if first is not None:
            methods.check_contract(name, contract_of_args(a, first.color.shape[:2]))
            checked = True
    return jobs, total


@contextmanager
def _session(ray, address):
    """A local Ray for this run, the cluster at `address`, or the caller's (tests)."""
    if ray.is_initialized():
        yield
        return
    try:
        if address:
            ray.init(address=address, log_to_driver=False, configure_logging=False)
        else:
            ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False)
    except Exception as e:      # Ray raises several kinds (ConnectionError, RuntimeError...)
        flag = f"--ray-address {address}: " if address else ""
        raise UsageError(f"{flag}cannot start Ray ({str(e).strip().splitlines()[0]})") from None
    try:
        yield
    finally:
        ray.shutdown()


def _start_workers(ray, device) -> list:
    """One SequenceWorker actor per device that node_devices picks on each machine."""
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy as On
    from .batch_work import SequenceWorker, node_devices
    nodes = [n["NodeID"] for n in ray.nodes() if n.get("Alive")]
    probe = ray.remote(num_cpus=0)(node_devices)
    found = ray.get([probe.options(scheduling_strategy=On(n, soft=False)).remote(device)
                     for n in nodes])
    actor = ray.remote(num_cpus=0)(SequenceWorker)
    workers, why = [], set()
    for node, (devices, problem) in zip(nodes, found):
        why.add(problem)
        for spec, desc in devices:
            where = f" (node {node[:8]})" if len(nodes) > 1 else ""
            print(f"clss batch: worker on {desc}{where}", file=sys.stderr)
            workers.append(actor.options(scheduling_strategy=On(node, soft=False)).remote(spec))
    if not workers:
        flag = f"--device {device}: " if device else ""
        why = "; ".join(sorted(map(str, why)))
        raise UsageError(f"{flag}no OpenCL device for a worker ({why})")
    return workers


def _progress(ray, workers, jobs, total, results, written):
    """Run the jobs under one progress bar of frames (finished ones count when found);
    written[0] counts the frames written."""
    from ..progress import progress

    def status():
        failed = sum(r["error"] is not None for r in results)
        return f"{len(results)}/{len(jobs)} sequences" + (f", {failed} failed" if failed else "")
    for event in progress(_events(ray, workers, jobs, results), desc="clss batch",
                          unit="frame", total=total, status=status):
        written[0] += event == "frame"


def _events(ray, workers, jobs, results):
    """Hand each idle worker the next sequence; yield "frame" per frame written and
    "skipped" per frame found finished; append each sequence's summary to `results` as it
    ends."""
    from ray.util.queue import Queue

    from .batch_work import summary
    queue = Queue(actor_options={"num_cpus": 0})
    todo, idle, running = deque(jobs), list(workers), {}
    try:
        while todo or running:
            while idle and todo:
                w, job = idle.pop(), todo.popleft()
                running[w.run.remote(job, queue)] = (w, job)
            ready, _ = ray.wait(list(running), num_returns=1, timeout=0.25)
            for event in queue.get_nowait_batch(queue.qsize()):
                yield from [event[0]] * (event[2] if event[0] == "skipped" else 1)
            for ref in ready:
                w, job = running.pop(ref)
                try:
                    r = ray.get(ref)
                    idle.append(w)
                except ray.exceptions.RayActorError as e:   # the worker's process died
                    r = summary(job, error=f"its worker died ({str(e).strip().splitlines()[0]})")
                _report(r, job, results)
            if todo and not idle and not running:
                for job in todo:
                    _report(summary(job, error="no worker left"), job, results)
                todo.clear()
    finally:
        queue.shutdown(force=True)


def _report(r, job, results):
    results.append(r)
    if r["error"] is not None:
        print(f"\nclss batch: {job['name']} ({job['given']}) failed: {r['error']}",
              file=sys.stderr)
        if r["trace"] and os.environ.get("CLSS_TRACEBACK"):
            print(r["trace"], file=sys.stderr)


def _summary(a, jobs, results, seconds) -> int:
    by_index = {r["index"]: r for r in results}
    failed = [by_index[j["index"]] for j in jobs if by_index[j["index"]]["error"] is not None]
    print(f"\n{len(jobs) - len(failed)} of {len(jobs)} sequences done in {seconds:.1f} s "
          f"-> {a.out}")
    for j in jobs:
        r = by_index[j["index"]]
        state = f"FAILED: {r['error']}" if r["error"] is not None else "done"
        print(f"  {j['name']}: {r['written']} frames written, {r['skipped']} kept"
              + (f" ({r['warmed']} stepped for the history)" if r["warmed"] else "")
              + f", {r['seconds']:.1f} s: {state}")
    return 1 if failed else 0
