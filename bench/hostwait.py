"""Host waits: the wall time of one frame step against the OpenCL event time it enqueues.

Per method whose step enqueues kernels and times its stages (those its bench room names in
HOST_WAITS, bench/methods/: today clss, clss-rules, jbicubic, nsrr, nsrd and nss, whose
G-buffers come from its bench room's `synthetic_gbuffers`) and size: two upscalers on the
same synthetic frame, warmed with a few frames first (PoCL compiles and specialises kernels
on their first launches):

* profile=False: wall milliseconds of `step_device` plus the queue draining after it,
  per frame (what an application waits for);
* profile=True: the summed event milliseconds of the same step (`stage_ms`).

wall / event near 1 means the frame is enqueued without host round trips between its
ops; each host wait shows as a gap between events (issue 19, section 4).
"""
from __future__ import annotations

import statistics
import time

import numpy as np

from .methods import host_wait_methods

# A method whose bench room has `enqueue_frame` also gets the enqueue column (the host's
# time to enqueue one frame); another method's row has wall and event time only. (The MLP
# upscaler times no stage events yet, so its room asks for no row.)
# (render size, scale): 270p -> 540p, where launch cost shows, and 540p -> 1080p
SIZES = (((270, 480), 2.0), ((540, 960), 2.0))
TARGET = 1.15       # wall <= 1.15x event at 540p -> 1080p


def make_upscaler(dev, method, scale, prec, profile):
    from clss import Upscaler, methods
    # timing only: a method whose package has no weights for this scale (nss, until it
    # ships some) runs its seeded init, which enqueues the same kernels
    spec = methods.spec(method)
    kw = {"weights": "untrained"} if spec.shipped and spec.shipped_file(scale) is None else {}
    return Upscaler(method=method, scale=scale, device=dev, precision=prec, profile=profile, **kw)


def measure(dev, method: str, render_size, scale: float, prec: str = "fp32", warm: int = 3,
            frames: int = 5) -> dict:
    """{"method", "shape", "wall_ms", "wall_min_ms", "event_ms", "ratio", "enqueue_ms",
    "stages"} (medians over `frames` warm frames)."""
    from clss.pipeline.contract import output_size
    from .netcases import synthetic_frame
    h, w = render_size
    H, W = output_size(h, w, scale)
    color, depth, motion = synthetic_frame(h, w)
    d = [dev.to_device(a, "fp32") for a in (color, depth, motion)]
    out = dev.empty((H, W, 3), dtype=np.float32)
    jitter = (0.25, -0.125)
    q = dev.queue

    room = host_wait_methods()[method]
    gb = {}
    if hasattr(room, "synthetic_gbuffers"):     # a method that reads G-buffers
        gb = {k: dev.to_device(v, "fp32") for k, v in room.synthetic_gbuffers(h, w, scale).items()}

    def step(up, i):
        up.step_device(*d, jitter, reset=i == 0, out=out, **gb)

    # Both upscalers warmed, then their frames alternate, so that a machine whose load
    # drifts (a shared CI host) weighs on the wall and the event time alike.
    ups = [make_upscaler(dev, method, scale, prec, p) for p in (False, True)]
    walls, events, stages = [], [], {}
    for i in range(warm + frames):
        q.finish()
        t0 = time.perf_counter()
        step(ups[0], i)
        q.finish()
        walls.append((time.perf_counter() - t0) * 1e3)
        step(ups[1], i)
        q.finish()
        st = ups[1].stage_ms()      # this frame's stages (means since the last reset)
        ups[1].reset_timings()
        if i >= warm:
            events.append(sum(st.values()))
            for k, v in st.items():
                stages.setdefault(k, []).append(v)
    walls = walls[warm:]
    # The host's share: milliseconds to enqueue one frame (FrameStep.run returns once
    # everything is queued; the flags event it returns is then waited for, untimed).
    # On a GPU, where kernels are fast, this is what bounds a frame.
    enq = []
    for _ in range(frames if hasattr(room, "enqueue_frame") else 0):
        q.finish()
        t0 = time.perf_counter()
        ev, then = room.enqueue_frame(ups[0], d[0], d[1], d[2], jitter, out)
        enq.append((time.perf_counter() - t0) * 1e3)
        ev.wait()
        then()
    wall, event = statistics.median(walls), statistics.median(events)
    return {"method": method, "precision": prec, "shape": f"{h}x{w}->{H}x{W}",
            "wall_ms": round(wall, 3), "wall_min_ms": round(min(walls), 3),
            "event_ms": round(event, 3), "ratio": round(wall / event, 3) if event else None,
            "enqueue_ms": round(statistics.median(enq), 3) if enq else None,
            "stages": {k: round(statistics.median(v), 3) for k, v in stages.items()}}


def run(dev, prec: str = "fp32", methods=None, sizes=SIZES, log=None, **kw) -> list[dict]:
    """Host-wait rows of `methods` (default: every method whose bench room asks for them)."""
    methods = list(host_wait_methods()) if methods is None else methods
    rows = []
    for (h, w), scale in sizes:
        for m in methods:
            r = measure(dev, m, (h, w), scale, prec, **kw)
            if log:
                log(f"host waits {m} {r['shape']} {prec}: wall {r['wall_ms']:.2f} ms, event "
                    f"{r['event_ms']:.2f} ms, {r['ratio']:.2f}x, enqueue {_ms(r['enqueue_ms'])} ms")
            rows.append(r)
    return rows


def _ms(v):
    return "-" if v is None else f"{v:.2f}"


def format_table(rows) -> str:
    lines = [f"{'method':12s} {'shape':20s} {'prec':5s} {'wall ms':>9s} {'event ms':>9s} {'wall/event':>10s} {'enqueue ms':>10s}"]
    for r in rows:
        lines.append(f"{r['method']:12s} {r['shape']:20s} {r['precision']:5s} {r['wall_ms']:9.2f} "
                     f"{r['event_ms']:9.2f} {r['ratio']:10.2f} "
                     + (f"{r['enqueue_ms']:10.2f}" if r['enqueue_ms'] is not None else f"{'-':>10s}"))
    return "\n".join(lines)


def markdown(rows) -> str:
    out = ["| method | shape | precision | wall ms | event ms | wall / event | enqueue ms |",
           "|---|---|---|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['method']} | {r['shape']} | {r['precision']} | {r['wall_ms']:.2f} | "
                   f"{r['event_ms']:.2f} | {r['ratio']:.2f} | {_ms(r['enqueue_ms'])} |")
    return "\n".join(out)
