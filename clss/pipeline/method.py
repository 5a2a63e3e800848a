"""What a method says about itself, and what every method's upscaler shares.

A method (clss/methods/<room>/) describes itself with a `MethodSpec`: the inputs of the
frame contract it reads, the G-buffers it needs or uses, the scales and precisions it
supports, whether its weights are trained, and how to build its upscaler. `clss methods`
prints the specs; `clss.Upscaler(method=NAME)` builds through them.

Every method's upscaler derives from `MethodUpscaler`, which holds what they share and
must not be copied into each room: the argument checks (scale, precision, exposure,
motion scale), the pending reset of a camera cut, the rule that a new render size needs
a reset, and the G-buffer check of the contract (a missing one is a named error before
anything runs).
"""
from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .contract import FrameInputError, check_exposure, check_motion_scale, validate_frame

# The frame contract's inputs (docs/input-contract.md) in the order `step` takes them.
CONTRACT_INPUTS = ("color", "depth", "motion", "jitter")
PRECISIONS = ("fp32", "fp16")


@dataclass(frozen=True)
class MethodSpec:
    """One method, as `clss methods` lists it and `clss.Upscaler(method=...)` builds it.

    name: the registry name (`--method NAME`); label: how tables and pictures call it;
    summary: one line; inputs: the contract inputs it reads; gbuffers: the optional
    inputs it needs (refused without them); optional: those it uses when given;
    scales: (lowest, highest) scale; precisions: what `precision=` accepts; temporal:
    whether it carries a history between frames; weights: callable -> "trained",
    "untrained" or "none needed" (the state of the package's weights); create:
    callable(**kwargs) -> MethodUpscaler; doc: its page under docs/; twin: "module:name"
    of its whole-frame ONNX twin, a callable(method, render_size, scale, **kwargs) -> a
    runner with the same `step` on onnxruntime (clss.methods.twin builds it)."""
    name: str
    label: str
    summary: str
    create: Callable = field(repr=False)
    inputs: tuple = CONTRACT_INPUTS
    gbuffers: tuple = ()
    optional: tuple = ()
    scales: tuple = (1.0, 16.0)
    precisions: tuple = PRECISIONS
    temporal: bool = True
    weights: Callable = field(default=lambda: "none needed", repr=False)
    doc: str = ""
    twin: str = ""

    def check_scale(self, scale) -> float:
        try:
            s = float(scale)
        except (TypeError, ValueError):
            raise ValueError(f"scale: expected a number >= 1, got {scale!r}") from None
        lo, hi = self.scales
        if not math.isfinite(s) or s < lo or s > hi:
            raise ValueError(f"scale: expected a number in [{lo:g}, {hi:g}] (method "
                             f"{self.name!r}), got {scale!r}")
        return s

    def check_precision(self, precision) -> str:
        if precision not in self.precisions:
            raise ValueError(f"precision: expected {' or '.join(repr(p) for p in self.precisions)} "
                             f"(method {self.name!r}), got {precision!r}")
        return precision


def summed_event_ms(events, stages) -> dict:
    """{stage: milliseconds} of [(stage, pyopencl.Event)] (profiled events), in the order
    of `stages`; waits for each event and empties the list."""
    tot = {}
    for name, e in events:
        e.wait()
        tot[name] = tot.get(name, 0.0) + (e.profile.end - e.profile.start) * 1e-6
    events.clear()
    return {s: tot[s] for s in stages if s in tot}


class MethodUpscaler:
    """The part of every method's upscaler that is the same for all (see the module doc).

    Subclasses set `spec` and implement `step` / `step_device` with the contract's
    arguments (color, depth, motion, jitter, reset=False, reactive=None, **gbuffers),
    `render_size` / `output_size` (None before the first frame) and, where they time
    their stages, `stage_ms` / `reset_timings`."""
    spec: MethodSpec

    def _init_common(self, scale, device, precision, *, depth_inverted=True,
                     motion_scale=(1, 1), exposure=1.0, sanitize=False, profile=False):
        from ..device import get_device
        self.scale = self.spec.check_scale(scale)
        self.dev = get_device(device)
        self.precision = self.spec.check_precision(precision)
        self.depth_inverted = bool(depth_inverted)
        self.motion_scale = tuple(float(v) for v in check_motion_scale(motion_scale))
        self.exposure = check_exposure(exposure)
        self.sanitize = bool(sanitize)
        self.profile = bool(profile)
        self._pending_reset = True
        self.frame_index = 0
        self.last_report: dict = {}
        self._fs = None             # the frame step of the current render size
        self._totals: dict[str, float] = {}     # per-stage ms summed over flushed frame steps
        self._timed = 0             # frames those sums cover (the subclass counts them)

    @property
    def method(self) -> str:
        return self.spec.name

    # A method with a device frame step (`_fs`, with h, w, H, W) has its sizes from it;
    # None before the first frame.
    @property
    def render_size(self):
        fs = getattr(self, "_fs", None)
        return None if fs is None else (fs.h, fs.w)

    @property
    def output_size(self):
        fs = getattr(self, "_fs", None)
        return None if fs is None else (fs.H, fs.W)

    def reset(self):
        """The next frame starts afresh (a camera cut)."""
        self._pending_reset = True

    def _check_render_size(self, hw, reset):
        """A render size other than the sequence's needs a reset (a camera cut)."""
        have = self.render_size
        if have is not None and not reset and tuple(have) != tuple(int(v) for v in hw):
            raise FrameInputError(
                f"color: the frame is {hw[0]}x{hw[1]} (h x w) but this sequence renders at "
                f"{have[0]}x{have[1]}; a new render size needs reset=True (a camera cut)")

    def _frame_step_for(self, hw, reset, build):
        """The device frame step (`self._fs`, with .h and .w) for render size hw: the
        current one, or `build(h, w)` after `_release_frame_step()` (a new size is a new
        sequence: buffers and programs built anew, and the next frame a reset)."""
        self._check_render_size(hw, reset)
        fs = getattr(self, "_fs", None)
        if fs is not None and (fs.h, fs.w) == tuple(hw):
            return fs
        h, w = int(hw[0]), int(hw[1])
        if h < 1 or w < 1:
            raise FrameInputError(f"color: expected a non-empty h x w x 3 frame, got {h}x{w}")
        if fs is not None:
            self._release_frame_step()
        self._fs = None         # release the old buffers first
        self._fs = build(h, w)
        self._pending_reset = True
        return self._fs

    def _release_frame_step(self):
        """Called before the frame step of another render size replaces the current one:
        its per-stage timings are kept."""
        self._flush_timings()

    def _device_frame(self, reset, **arrays):
        """step_device's common entry: a reset is remembered (kept if the frame is then
        refused), every given array must be a pyopencl array, the colour h x w x 3;
        returns (h, w)."""
        import pyopencl.array as cla
        if reset:
            self._pending_reset = True
        for name, a in arrays.items():
            if a is not None and not isinstance(a, cla.Array):
                raise FrameInputError(f"{name}: expected a pyopencl.array.Array, got "
                                      f"{type(a).__name__} (use step() for numpy arrays)")
        color = arrays["color"]
        if color.ndim != 3 or color.shape[2] != 3:
            raise FrameInputError(f"color: expected shape (h, w, 3), got {color.shape}")
        return tuple(color.shape[:2])

    @staticmethod
    def _check_device_arrays(shaped, out=None, out_shape=None):
        """step_device's per-array check: each (name, array, shape) float32 of that many
        values, and `out` (if given) a float32 array of `out_shape`."""
        for name, a, shape in shaped:
            if a.size != int(np.prod(shape)) or a.dtype != np.float32:
                raise FrameInputError(f"{name}: expected float32 of shape {tuple(shape)}, got "
                                      f"{a.dtype} {a.shape}")
        if out is not None and (out.shape != tuple(out_shape) or out.dtype != np.float32):
            raise FrameInputError(f"out: expected a float32 array of shape {tuple(out_shape)}")

    def _frame_done(self, event):
        """After a frame step enqueued a whole frame: wait for its last event, then count
        the frame (the pending reset is spent; a timed frame for stage_ms)."""
        event.wait()
        self._pending_reset = False
        self.frame_index += 1
        if self.profile:
            self._timed += 1

    def _color_frame(self, color, reset):
        """For a method that reads the colour alone: (validate_frame's dict, (h, w)), the
        colour checked as the contract says and the render size held to the sequence's."""
        color = np.asarray(color)
        if color.ndim == 3:
            self._check_render_size(color.shape[:2], reset or self._pending_reset)
        h, w = color.shape[:2] if color.ndim >= 2 else (0, 0)
        # placeholders for the inputs such a method does not read
        frame = validate_frame(color, np.zeros((h, w), np.float32),
                               np.zeros((h, w, 2), np.float32), (0.0, 0.0),
                               sanitize=self.sanitize)
        return frame, (h, w)

    def _gbuffers(self, given: dict, render_size, output_size) -> dict:
        """The G-buffers this method needs or uses, checked against the contract; a
        missing needed one is a named error (nothing has run yet). Buffers the method
        does not use are ignored, so one caller can feed every method the same frame."""
        spec = self.spec
        if not spec.gbuffers and not spec.optional:
            return {}
        from . import contract
        return contract.validate_gbuffers(spec.name, spec.gbuffers, spec.optional,
                                          {k: v for k, v in given.items() if v is not None},
                                          render_size, output_size, sanitize=self.sanitize)

    # -- timings ----------------------------------------------------------------------
    # The stages a method's frame step times with OpenCL events (its `stage_ms()` gives the
    # milliseconds summed since its last call); a method without stage events names none
    # and reports none. The method counts each timed frame in `_timed`.
    STAGES: tuple = ()

    def _flush_timings(self):
        if self._fs is not None and self.profile and self.STAGES:
            for k, v in self._fs.stage_ms().items():
                self._totals[k] = self._totals.get(k, 0.0) + v

    def reset_timings(self):
        """Start the per-stage statistics afresh (e.g. after a first frame that paid for
        kernel compilation)."""
        self._flush_timings()
        self._totals, self._timed = {}, 0

    def stage_ms(self) -> dict:
        """Mean milliseconds per frame of each stage since construction or the last
        reset_timings (needs profile=True): OpenCL event times."""
        if not self.profile:
            raise RuntimeError("stage_ms needs Upscaler(..., profile=True)")
        self._flush_timings()
        n = max(self._timed, 1)
        return {k: self._totals[k] / n for k in self.STAGES if k in self._totals}

    def device_bytes(self) -> int:
        return 0


# ---- a method's weights= argument ----------------------------------------------------------
UNTRAINED = "untrained"


def weights_or_shipped(weights, shipped, method: str, scale, warned: list, where: str):
    """`weights` as given; for None the package's file `shipped`, and without one UNTRAINED
    with a warning (once per process: `warned`) that the seeded init runs."""
    if weights is not None:
        return weights
    if shipped is not None:
        return shipped
    if not warned:
        warned.append(True)
        warnings.warn(f"{method}: no trained weights for scale {float(scale):g} in the "
                      f"package ({where}); running the untrained (seeded) networks",
                      stacklevel=4)
    return UNTRAINED


def weights_file(weights, what: str) -> str:
    """weights= given as a path: it must be an existing .safetensors file (`what`, e.g.
    "an NSRR .safetensors file", names what was expected)."""
    path = os.fspath(weights)
    if not (os.path.isfile(path) and path.endswith(".safetensors")):
        raise ValueError(f"weights: expected {what}, got {path!r}"
                         + ("" if os.path.exists(path) else " (does not exist)"))
    return path
