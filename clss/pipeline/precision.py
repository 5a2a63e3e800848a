"""precision="auto", every method's default: what `precision=` resolves to on a device.

- A CPU runs fp32. On the PoCL CPUs measured (bench/results), fp16 storage is slower: each
  load and store converts, and the vectors it saves bandwidth for are not the bottleneck.
- Any other device (a GPU) runs fp16 storage: half tensors and history, float arithmetic
  (the `fp16` precision). It halves the bytes every stage moves, the bound of most stages
  on a GPU. But it does so only where the method's fp16 frame step *verifies on that
  device*, and not where `clss tune --level` measured its fp16 frame step slower than its
  fp32 one there (or the device class's shipped table says so: clss.tuning.FP16_OP; on an
  H200 the MLP upscaler's fp16 step was slower); elsewhere it runs fp32.

The check (`check`): the method runs FRAMES frames of a seeded synthetic sequence (a moving
HDR texture with a hard edge, jittered, with every G-buffer) in fp32 and in fp16. It
verifies when every fp16 frame is within MIN_PSNR dB of the fp32 frame, on display values
(x / (1 + x)). The verdict is stored beside the fast paths' (selfcheck.json, keyed by device,
driver, the method and the hash of its kernel sources); `clss verify` lists it. fp16 and fp32
frames differ by storage rounding, 67-69 dB on pip's PoCL; a miscompiled or overflowing fp16 kernel
differs by far more.
"""
from __future__ import annotations

import hashlib

import numpy as np

from .contract import GBUFFERS, output_size

AUTO = "auto"
FRAMES = 6
RENDER = (32, 48)
MIN_PSNR = 50.0


def resolve(spec, dev, precision: str) -> str:
    """The precision a method built with `precision` runs on dev: itself, unless "auto"."""
    if precision != AUTO:
        return precision
    if getattr(dev, "is_cpu", True) or "fp16" not in spec.precisions:
        return "fp32"
    from ..tuning import FP16_OP, measured_choice
    if measured_choice(dev, FP16_OP, spec.name) is False:     # measured slower here: no check
        return "fp32"
    v = verdict(spec, dev)
    return "fp16" if v is not None and v.ok else "fp32"


def sequence(spec, scale: float, frames: int = FRAMES, render=RENDER):
    """[(color, depth, motion, jitter, gbuffers)]: the seeded synthetic frames of the check.
    The texture moves (1.5, 0.75) render pixels a frame; motion points to the previous
    position (the contract's); depth is reversed-Z; every G-buffer the method reads."""
    h, w = render
    H, W = output_size(h, w, scale)
    shift = np.array([1.5, 0.75], np.float32)
    jit = [(0.0, -1 / 6), (-0.25, 1 / 6), (0.25, -0.39), (-0.375, 0.06), (0.125, 0.28), (-0.125, -0.17)]

    def scene(u, v):            # u, v: scene coordinates in render pixels
        r = 1.5 + np.sin(0.37 * u) * np.cos(0.23 * v)
        g = 1.0 + 0.8 * np.sin(0.11 * u + 0.19 * v)
        b = np.where(u + 0.5 * v > 30.0, 3.0, 0.2)         # a hard edge the history must keep
        return np.stack([r, g, b], -1).astype(np.float32)

    out = []
    for i in range(frames):
        jx, jy = jit[i % len(jit)]
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        u, v = xx + 0.5 + jx + shift[0] * i, yy + 0.5 + jy + shift[1] * i
        color = scene(u, v)
        depth = (0.4 + 0.05 * np.sin(0.05 * u)).astype(np.float32)
        motion = np.broadcast_to(-shift, (h, w, 2)).astype(np.float32)
        Y, X = np.mgrid[0:H, 0:W].astype(np.float32)
        U, V = (X + 0.5) * (w / W) + shift[0] * i, (Y + 0.5) * (h / H) + shift[1] * i
        albedo_of = (lambda c: np.clip(c / 3.0, 0.05, 1.0))
        normal = np.zeros((h, w, 3), np.float32)
        normal[..., 2] = 1.0
        normal_hr = np.zeros((H, W, 3), np.float32)
        normal_hr[..., 2] = 1.0
        have = {"albedo": albedo_of(color), "normal": normal, "albedo_hr": albedo_of(scene(U, V)),
                "depth_hr": (0.4 + 0.05 * np.sin(0.05 * U)).astype(np.float32), "normal_hr": normal_hr}
        gb = {n: np.ascontiguousarray(have[n], np.float32) for n in GBUFFERS
              if n in spec.gbuffers or n in spec.optional}
        out.append((color, depth, motion, (jx, jy), gb))
    return out


def psnr_display(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR dB of two linear frames on display values x / (1 + x) (peak 1)."""
    da = np.clip(a, 0, None) / (1 + np.clip(a, 0, None))
    db = np.clip(b, 0, None) / (1 + np.clip(b, 0, None))
    mse = float(np.mean((da.astype(np.float64) - db) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)


def check(spec, dev) -> tuple[bool, str]:
    """(verifies, detail): the method's fp16 frame step against its fp32 one on dev."""
    scale = _scale(spec)
    frames = sequence(spec, scale)
    outs = {}
    for prec in ("fp32", "fp16"):
        up = spec.create(scale=scale, device=dev, precision=prec)
        outs[prec] = [np.asarray(up.step(c, d, m, j, reset=i == 0, **gb), np.float32)
                      for i, (c, d, m, j, gb) in enumerate(frames)]
    worst = min(psnr_display(a, b) for a, b in zip(outs["fp16"], outs["fp32"]))
    finite = all(np.isfinite(o).all() for o in outs["fp16"])
    ok = finite and worst >= MIN_PSNR
    detail = (f"fp16 within {worst:.1f} dB of fp32 over {FRAMES} frames at {scale:g}x"
              + ("" if finite else "; non-finite fp16 output"))
    return ok, detail if ok else f"{detail} (needs {MIN_PSNR:g} dB)"


def _scale(spec) -> float:
    """2x where the method takes it (its shipped weights' scale), else its smallest scale."""
    lo, hi = spec.scales
    return 2.0 if lo <= 2.0 <= hi else float(lo)


_memo: dict = {}


def verdict(spec, dev):
    """The cached or fresh check of spec's fp16 frame step on dev, as a selfcheck.Verdict
    named "precision.<method>", kept in selfcheck.json under the hash of the kernel sources
    (the method's room and the shared kernels/). None where it is deferred: inside
    selfcheck.deferring() (clss upscale's first frame on a cold cache waits for no check) the
    run keeps fp32 and the background checker checks it for the next run."""
    from .. import selfcheck
    base = getattr(dev, "base", dev)
    memo = (id(base), spec.name)
    if memo not in _memo:
        v = selfcheck.remembered(base, f"{PREFIX}.{spec.name}", spec.name, "fp16", _sources_digest(spec),
                                 "precision=auto", lambda: check(spec, base), defer=True)
        if v is None:       # deferred: fp32 in this process
            return None
        _memo[memo] = v
    return _memo[memo]


PREFIX = "precision"


def check_deferred(dev, prec: str, name: str, spec_of) -> None:
    """The background checker's call for a deferred "precision.<method>" (spec_of: the method
    registry's spec(), which this floor does not import: clss.selfcheck_runner passes it)."""
    verdict(spec_of(name.partition(".")[2]), dev)


def _sources_digest(spec) -> str:
    from pathlib import Path
    from ..device import kernels_dir
    room = Path(__file__).resolve().parent.parent / "methods" / spec.room
    h = hashlib.sha1()
    for d in (room, Path(kernels_dir())):
        for f in sorted(list(d.glob("*.cl")) + list(d.glob("*.h"))):
            h.update(f.name.encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:16]
