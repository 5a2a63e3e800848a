"""What the bench watches on a Device while the engine runs: the events of its
launches (OpenCL event time) and its allocations (reused across runs).

Both work by shadowing the bound methods `launch` and `empty` on the Device
instance for the duration of a `with` block, so the ops need no bench hooks."""
from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from clss.device import Device


class Capture:
    """Records every event `dev.launch` returns, and serves `dev.empty` from a pool
    keyed by (allocation order within a run, shape, dtype).

    Each engine run allocates the same tensors in the same order, so run k reuses
    run k-1's buffers: what a memory planner gives a real executor (onnxruntime
    has its arena), and it keeps first-touch page faults of fresh host memory out
    of the kernel timings. `local_size` forces a work-group size on every launch
    whose global size it divides (the tuner's candidates)."""

    def __init__(self, dev: Device, pool: bool = True):
        self.dev = dev
        self.pool_enabled = pool
        self.events = []
        self.launches = []            # (kernel name, global size) of the last run
        self.local_size = None
        self._pool: dict = {}
        self._n_alloc = 0

    # -- the shadowing methods ---------------------------------------------
    def _launch(self, kernel, global_size, args, local_size=None, wait_for=None):
        gs = tuple(int(max(1, g)) for g in global_size)
        if local_size is None and self.local_size is not None:
            local_size = fit_local(self.local_size, gs)
        ev = Device.launch(self.dev, kernel, global_size, args, local_size, wait_for)
        self.events.append(ev)
        self.launches.append((kernel.function_name, gs))
        return ev

    def _empty(self, shape, precision="fp32", dtype=None):
        if not self.pool_enabled:
            return Device.empty(self.dev, shape, precision, dtype)
        key = (self._n_alloc, tuple(int(s) for s in shape), precision if dtype is None else np.dtype(dtype).str)
        self._n_alloc += 1
        a = self._pool.get(key)
        if a is None:
            a = self._pool[key] = Device.empty(self.dev, shape, precision, dtype)
        return a

    # -- use ----------------------------------------------------------------
    @contextmanager
    def active(self):
        """Within: launches are recorded, allocations pooled. Nested use is fine."""
        if self.dev.__dict__.get("launch") is not None:   # already captured
            yield self
            return
        self.dev.launch = self._launch
        self.dev.empty = self._empty
        try:
            yield self
        finally:
            del self.dev.launch
            del self.dev.empty

    def start_run(self) -> None:
        self.events = []
        self.launches = []
        self._n_alloc = 0

    def event_ms(self) -> float:
        """Sum of the kernels' execution times (profiling start..end) of the run,
        in ms: device busy time, without host overhead and queue gaps."""
        total = 0
        for ev in self.events:
            ev.wait()
            total += ev.profile.end - ev.profile.start
        return total * 1e-6

    def per_kernel_ms(self) -> dict:
        """{kernel name: summed event ms} of the run, largest first."""
        tot: dict = {}
        for ev, (name, _) in zip(self.events, self.launches):
            ev.wait()
            tot[name] = tot.get(name, 0.0) + (ev.profile.end - ev.profile.start) * 1e-6
        return dict(sorted(tot.items(), key=lambda kv: -kv[1]))

    def release(self) -> None:
        self._pool.clear()


def fit_local(local, gs):
    """`local` padded/truncated to the rank of `gs`, or None where it does not divide
    the global size (OpenCL 1.2 requires that; the kernels use exact global sizes)."""
    loc = tuple(local)[: len(gs)] + (1,) * max(0, len(gs) - len(local))
    if any(g % l for g, l in zip(gs, loc)):
        return None
    return loc
