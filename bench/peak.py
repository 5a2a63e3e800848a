"""The machine's measured peak on one device: FMA throughput and stream bandwidth
(kernels/peak.cl), the denominators of the bench's "share of peak" column.

Each probe first runs briefly to estimate its rate, then sizes one launch (FMA: the
loop count; stream: the number of launches) to last about `target_s`, and keeps the
best of a few repeats, as clpeak and STREAM do: the peak is what the machine can do,
so noise only ever lowers a sample."""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np
import pyopencl as cl

from clss.device import Device

FMA_WIDTHS = (1, 4, 8, 16)
# Independent chains per work-item: enough to hide the FMA latency, few enough to
# stay in registers; the best differs per width and machine, so both are tried.
FMA_CHAINS = (4, 8)
WIDTH_NAMES = {1: "float", 2: "float2", 4: "float4", 8: "float8", 16: "float16"}


@dataclass
class Peak:
    fma_gflops: dict = field(default_factory=dict)    # {"float": x, "float4": ..., "float8": ...}
    stream_gbs: dict = field(default_factory=dict)    # {"copy": x, "triad": y}
    seconds: float = 0.0

    @property
    def gflops(self) -> float:
        """Compute peak: the best FMA variant."""
        return max(self.fma_gflops.values()) if self.fma_gflops else float("nan")

    @property
    def gbs(self) -> float:
        """Bandwidth peak: the best stream kernel."""
        return max(self.stream_gbs.values()) if self.stream_gbs else float("nan")

    @property
    def ridge(self) -> float:
        """Arithmetic intensity (FLOP/byte) where the two roofs meet."""
        return self.gflops / self.gbs

    def as_dict(self) -> dict:
        return asdict(self) | {"gflops": self.gflops, "gbs": self.gbs, "ridge_flop_per_byte": self.ridge}

    @classmethod
    def from_dict(cls, d: dict) -> "Peak":
        return cls(dict(d.get("fma_gflops", {})), dict(d.get("stream_gbs", {})), float(d.get("seconds", 0)))


def _event_s(ev: cl.Event) -> float:
    ev.wait()
    return (ev.profile.end - ev.profile.start) * 1e-9


def fma_gflops(dev: Device, vw: int = 8, target_s: float = 0.2, repeats: int = 3,
               chains: int = 8, repeat: int = 16) -> float:
    """FMA throughput in GFLOP/s (one FMA = 2 FLOP) for chains of width vw."""
    k = dev.kernel("peak", "fma_peak", "fp32", VW=vw, CHAINS=chains, REPEAT=repeat)
    # Enough work-groups for every compute unit several times over.
    n = 512 * max(4, dev.info.compute_units)
    out = dev.empty((n,), "fp32")
    m, c = np.float32(0.999999), np.float32(1e-7)

    def launch(iters):
        return _event_s(dev.launch(k, (n,), (out.data, m, c, np.int32(iters))))

    iters = 4
    launch(iters)  # compile / specialise for this launch shape
    t = launch(iters)
    while t < target_s / 20 and iters < 2**24:
        iters *= 4
        t = launch(iters)
    iters = int(min(2**28, max(1, iters * target_s / max(t, 1e-9))))
    best = min(launch(iters) for _ in range(repeats))
    out_host = out.get()
    if not np.all(np.isfinite(out_host)):  # the chains must stay in range to be representative
        raise RuntimeError("fma probe produced non-finite values")
    return 2.0 * n * iters * repeat * chains * vw / best * 1e-9


def stream_gbs(dev: Device, kind: str = "triad", mib: int = 128, target_s: float = 0.3,
               repeats: int = 3) -> float:
    """Stream bandwidth in GB/s (1e9 bytes) over arrays of `mib` MiB each,
    well beyond the last-level cache of current CPUs."""
    nbytes = min(mib * 2**20, dev.info.max_alloc // 2)
    n4 = nbytes // 16
    a = dev.empty((n4 * 4,), "fp32")
    b = dev.to_device(np.full(n4 * 4, 1.0, np.float32))
    c = dev.to_device(np.full(n4 * 4, 2.0, np.float32))
    if kind == "copy":
        k = dev.kernel("peak", "stream_copy", "fp32")
        args, accesses = (b.data, a.data, np.int32(n4)), 2
    elif kind == "triad":
        k = dev.kernel("peak", "stream_triad", "fp32")
        args, accesses = (a.data, b.data, c.data, np.float32(3.0), np.int32(n4)), 3
    else:
        raise ValueError(f"stream kind must be copy or triad, got {kind!r}")

    def launch():
        return _event_s(dev.launch(k, (n4,), args))

    launch()
    launch()  # first touch of the pages, and the launch-shape specialisation
    t = launch()
    per_repeat = max(1, int(round(target_s / max(t, 1e-9))))
    best = min(min(launch() for _ in range(per_repeat)) for _ in range(repeats))
    if kind == "triad" and not np.allclose(a.get()[:: max(1, n4)], 7.0):
        raise RuntimeError("stream triad probe produced wrong values")
    return accesses * n4 * 16 / best * 1e-9


def measure(dev: Device, quick: bool = False, log=None, target_s: float | None = None,
            mib: int | None = None, stream: bool = True) -> Peak:
    """The probe set: FMA chains of float, float4, float8, float16 (best over the
    chain counts); stream copy and triad (stream=False: the FMA peak alone). `target_s`
    and `mib` shrink it for smoke tests (a stream array must exceed the last-level cache
    to mean anything)."""
    t0 = time.perf_counter()
    target = target_s or (0.1 if quick else 0.3)
    repeats = 2 if quick or target_s else 3
    p = Peak()
    for vw in FMA_WIDTHS:
        name = WIDTH_NAMES[vw]
        p.fma_gflops[name] = max(fma_gflops(dev, vw, target_s=target, repeats=repeats, chains=ch)
                                 for ch in FMA_CHAINS)
        if log:
            log(f"peak: FMA {name:7s} {p.fma_gflops[name]:8.1f} GFLOP/s")
    for kind in ("copy", "triad") if stream else ():
        p.stream_gbs[kind] = stream_gbs(dev, kind, mib=mib or (64 if quick else 128), target_s=target * 2,
                                        repeats=repeats)
        if log:
            log(f"peak: stream {kind:5s} {p.stream_gbs[kind]:8.1f} GB/s")
    p.seconds = time.perf_counter() - t0
    return p
