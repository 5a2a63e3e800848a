"""The soak: every method (`clss methods`) runs many frames in one process, and its memory
and time per frame stay flat (issue 52 part 3; before it only NSRD, NSS and CLSS had a
300-frame test of their own, in their test modules).

The default suite runs the short soak, 20 frames at 16x24 -> 32x48 per method (a few
seconds in all once the kernels are built); `make soak` runs 300 frames at 48x80 -> 96x160
(CLSS_SOAK_FRAMES, CLSS_SOAK_SIZE) and prints each method's figures. The frames are 8
rendered frames of the sample scene, cycled, through `Upscaler.step` (upload, frame step,
read back: what a caller runs), reset on the first frame only.

Flat means, after a warm-up of WARMUP frames (first builds, lazily made state):
- the frame step's device buffers (`Upscaler.device_bytes()`) do not change, and neither
  does the number of live pyopencl arrays and OpenCL buffers in the process;
- the process's resident memory grows by under RSS_SLACK_MIB;
- the median CPU time per frame (every thread of the process: PoCL's workers too, so that
  the other processes on a shared machine count less than in wall time) of the last
  quarter of the frames is within TIME_RATIO of the first quarter's after the warm-up,
  plus TIME_SLACK_MS for the timer's noise on frames of a millisecond.
"""
from __future__ import annotations

import gc
import os
import resource
import statistics
import sys
import time

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

import clss
from clss import methods

FRAMES = int(os.environ.get("CLSS_SOAK_FRAMES", "20"))
SIZE = tuple(int(v) for v in os.environ.get("CLSS_SOAK_SIZE", "16x24").split("x"))
WARMUP = 5
RSS_SLACK_MIB = 8.0
TIME_RATIO = 1.5 if FRAMES >= 100 else 2.0      # the short soak's windows are 4 frames
TIME_SLACK_MS = 2.0


def _rss_mib() -> float:
    """Resident memory now (Linux: /proc), else the peak (getrusage; KiB on Linux, bytes
    on macOS), which only shows growth past it."""
    try:
        with open("/proc/self/status") as fh:
            return next(int(ln.split()[1]) for ln in fh if ln.startswith("VmRSS")) / 1024
    except (OSError, StopIteration):
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return peak / 2**20 if sys.platform == "darwin" else peak / 1024


def _live_opencl() -> tuple[int, int]:
    """(live pyopencl arrays, live OpenCL buffers) in the process."""
    gc.collect()
    objs = gc.get_objects()
    return (sum(isinstance(o, cla.Array) for o in objs),
            sum(isinstance(o, cl.Buffer) for o in objs))


@pytest.fixture(scope="module")
def scene():
    from clss.demo.scene import render_sequence
    return render_sequence(8, SIZE, 2.0, spp_ref=0)


def soak(name: str, frames, n: int) -> dict:
    """Run `n` frames of method `name` at 2x; what was measured (see the module doc)."""
    up = clss.Upscaler(method=name, scale=2)
    cpu, wall, bytes_seen = [], [], set()
    for i in range(n):
        f = frames[i % len(frames)]
        if i == WARMUP:
            live0, rss0 = _live_opencl(), _rss_mib()
        c, w = time.process_time(), time.perf_counter()
        out = up.step(f.color, f.depth, f.motion, f.jitter, reset=i == 0, **f.gbuffers)
        cpu.append(time.process_time() - c)
        wall.append(time.perf_counter() - w)
        if i >= WARMUP:
            bytes_seen.add(up.device_bytes())
    k = max(4, (n - WARMUP) // 4)
    return dict(method=name, frames=n, out=out, device_bytes=sorted(bytes_seen),
                live=(live0, _live_opencl()), rss_growth_mib=_rss_mib() - rss0,
                cpu_ms=(1e3 * statistics.median(cpu[WARMUP:WARMUP + k]), 1e3 * statistics.median(cpu[-k:])),
                wall_ms=(1e3 * statistics.median(wall[WARMUP:WARMUP + k]), 1e3 * statistics.median(wall[-k:])))


@pytest.mark.parametrize("name", methods.names())
def test_memory_and_time_per_frame_stay_flat(name, scene):
    r = soak(name, scene, FRAMES)
    (c0, c1), (w0, w1) = r["cpu_ms"], r["wall_ms"]
    print(f"\nsoak {name}: {r['frames']} frames at {SIZE[0]}x{SIZE[1]}, device {r['device_bytes']} B, "
          f"live arrays/buffers {r['live'][0]} -> {r['live'][1]}, RSS {r['rss_growth_mib']:+.1f} MiB, "
          f"CPU {c0:.1f} -> {c1:.1f} ms/frame, wall {w0:.1f} -> {w1:.1f} ms/frame")
    assert np.isfinite(r["out"]).all()
    assert len(r["device_bytes"]) == 1, f"{name}: device bytes changed: {r['device_bytes']}"
    assert r["live"][0] == r["live"][1], f"{name}: live (arrays, buffers) {r['live'][0]} -> {r['live'][1]}"
    assert r["rss_growth_mib"] < RSS_SLACK_MIB, f"{name}: RSS grew {r['rss_growth_mib']:.1f} MiB"
    assert c1 <= TIME_RATIO * c0 + TIME_SLACK_MS, \
        f"{name}: CPU time per frame {c0:.1f} -> {c1:.1f} ms (over {TIME_RATIO}x)"
