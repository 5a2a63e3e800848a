"""The worker side of `clss batch`: which OpenCL devices of a machine get a worker
(`node_devices`), and the worker that upscales whole sequences on one of them
(`SequenceWorker`, a Ray actor in batch.py; nothing here imports Ray, so the worker
runs without it too). A sequence is upscaled exactly as `clss upscale` does it (the
same option checks, upscaler and frame loop, from upscale.py), resuming from its
output directory's journal (batch_resume.py)."""
from __future__ import annotations

import argparse
import os
import time
import traceback

from ..errors import cli_message


def node_devices(spec=None):
    """([(device spec, description)], why none) of the devices on this machine that get
    a worker: the one --device (or $CLSS_DEVICE, $PYOPENCL_CTX) names; else every GPU
    or accelerator that builds kernels, or, where there is none, the default CPU device
    (the CPU devices of one machine share its cores, so one is enough; oclgrind is a
    simulator)."""
    from ..device import DeviceError, compiler_problem, describe, get_device, list_devices
    try:
        found = list_devices()
        if spec is None and not (os.environ.get("CLSS_DEVICE") or os.environ.get("PYOPENCL_CTX")):
            from pyopencl import device_type
            gpus = [(str(i), describe(i, p, d)) for i, (p, d) in enumerate(found)
                    if not d.type & device_type.CPU and "oclgrind" not in p.name.lower()
                    and not compiler_problem(d)]
            if gpus:
                return gpus, None
        chosen = get_device(spec).cl_device
        i = next(i for i, (p, d) in enumerate(found) if d == chosen)
        return [(str(i), describe(i, *found[i]))], None
    except DeviceError as e:
        return [], cli_message(e).splitlines()[0]


def summary(job: dict, device=None, error=None) -> dict:
    """What a worker returns for a sequence (the driver makes one where a worker died)."""
    return dict(index=job["index"], name=job["name"], written=0, skipped=0, warmed=0,
                error=error, trace=None, seconds=0.0, device=device)


class SequenceWorker:
    """Upscales whole sequences, one after the other, on one device."""

    def __init__(self, device: str):
        self.device = device

    def run(self, job: dict, events=None) -> dict:
        """Upscale job["input"] into job["out"] with the options job["args"] (vars() of
        `clss batch`'s arguments), resuming from the journal there. Puts ("skipped", i,
        count) and ("frame", i) on `events` as frames are found finished or written.
        Returns a summary; a failure is its one-line "error", never an exception."""
        out = summary(job, self.device)
        t0 = time.perf_counter()
        from ..device import DeviceError, KernelBuildError
        from ..errors import ArgumentError
        try:
            self._run(job, out, events)
        except (ValueError, OSError, DeviceError, ArgumentError, KernelBuildError) as e:
            out["error"] = cli_message(e).splitlines()[0]
        except Exception as e:      # a bug in clss: the driver shows the trace on request
            out["error"] = f"{type(e).__name__}: {e}".splitlines()[0]
            out["trace"] = traceback.format_exc()
        out["seconds"] = time.perf_counter() - t0
        return out

    def _run(self, job, out, events):
        from .. import methods
        from ..io import read_sequence
        from ..pipeline.contract import output_size
        from .batch_resume import Journal, settings_of
        from .upscale import (OUTPUT_SET, _upscale_frames, build_upscaler, check_inputs,
                              parse_channels)
        from .upscaler_common import FrameFiles
        a = argparse.Namespace(**dict(job["args"], device=self.device, out=job["out"]))
        name, spec = job["method"], methods.spec(job["method"])
        seq = read_sequence(job["input"], channels=parse_channels(a.channels), jitter=a.jitter,
                            scale=a.scale)
        n = len(seq) if a.frames is None else min(len(seq), a.frames)
        first = seq[0]
        check_inputs(a, name, spec, first)
        inputs = seq.files + ([a.jitter] if a.jitter and os.path.isfile(a.jitter) else [])
        journal = Journal(a.out)
        done = journal.open(settings_of(job["args"]), a.overwrite, inputs,
                            output_size(*first.color.shape[:2], a.scale), OUTPUT_SET)
        numbers = seq.frame_numbers[:n]
        missing = [i for i, number in enumerate(numbers) if number not in done]
        out["skipped"] = n - len(missing)
        _put(events, ("skipped", job["index"], out["skipped"]))
        if not missing:
            return
        # A method with a history is stepped from the sequence's start through the frames
        # already written (not writing them), so that the frames it writes are those of a
        # run that was never interrupted; a method without one starts at the first missing.
        indices = range(missing[-1] + 1) if spec.temporal else missing
        out["warmed"] = len(indices) - len(missing)
        up = build_upscaler(a, name, first)
        files, delay = FrameFiles(), float(job.get("delay", 0.0))

        def on_frame(number, paths):
            journal.record(number, paths)
            out["written"] += 1
            _put(events, ("frame", job["index"]))
            if delay:
                time.sleep(delay)       # tests: a batch slow enough to kill mid-run
        try:
            _upscale_frames(a, seq, first, n, up, files, [], [],
                            lambda: f"{out['written']} frames written to {a.out}",
                            indices=indices, keep=done, on_frame=on_frame)
        finally:
            files.discard()     # a frame left half-written (it is not journalled either)


def _put(events, item):
    if events is not None:
        events.put(item)
