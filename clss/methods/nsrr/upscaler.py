"""NSRR (Xiao et al. 2020) behind clss.Upscaler: method "nsrr".

    up = clss.Upscaler(method="nsrr", scale=4)
    out = up.step(color, depth, motion, jitter, reset=cut)        # H x W x 3 linear

Inputs follow the frame contract (docs/input-contract.md). The frame step is frame.py
(kernels/nsrr.cl around two clss.Model networks); the history (the previous frames'
zero-upsampled, accumulatively warped features) stays on the device. Weights: the
package's clss/weights/nsrr_x{2,4}.safetensors for the nearest trained scale, or the
seeded init ("untrained") when the package has none.
"""
from __future__ import annotations

import os

import numpy as np

from ...pipeline.contract import PQ_NITS, check_jitter, validate_frame
from ...pipeline.method import (UNTRAINED, MethodSpec, MethodUpscaler, weights_file,
                               weights_or_shipped)
from . import networks as nets
from .frame import RESET_FILLS, STAGES, NsrrFrameStep

WEIGHTS_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(
    __file__)))), "weights")
TRAINED_SCALES = (2, 4)
_warned = []


def shipped_weights(scale) -> str | None:
    """The package's weights file for `scale`: the trained scale nearest to it (2 for
    scales below 3, 4 above), if the file exists."""
    s = 2 if float(scale) < 3.0 else 4
    p = os.path.join(WEIGHTS_DIR, f"nsrr_x{s}.safetensors")
    return p if os.path.isfile(p) else None


def load_weights(weights, scale, widths="default") -> tuple[dict, dict, bool]:
    """(config, weights, trained). weights: None (the shipped file for the scale, else the
    seeded init with one warning), "untrained", a .safetensors path, or a (config,
    weights dict) pair."""
    weights = weights_or_shipped(weights, shipped_weights(scale), "nsrr", scale, _warned,
                                 WEIGHTS_DIR)
    if isinstance(weights, tuple):
        cfg, w = weights
        nets.check_weights(cfg, w)
        return cfg, w, True
    if isinstance(weights, str) and weights == UNTRAINED:
        cfg = nets.make_config(widths)
        return cfg, nets.init_weights(cfg), False
    cfg, w = nets.load(weights_file(weights, "an NSRR .safetensors file"))
    return cfg, w, True


class NsrrUpscaler(MethodUpscaler):
    """NSRR temporal supersampling (see the module doc).

    scale: 2 to 4 (any value in between; weights from the nearest trained scale).
    weights: see `load_weights`. widths: the architecture of the untrained init
    ("default", "fast" = the paper's Ours-Fast, "paper"). history: previous frames used
    (0..4; default all the network was built for). reset_fill: what stands for the
    previous frames after a reset: "zero" (empty features, as zero-upsampling marks a
    missing sample) or "duplicate" (the current frame's). precision "fp32" / "fp16".
    """

    STAGES = STAGES     # the per-stage timings (MethodUpscaler.stage_ms)

    def __init__(self, scale=4.0, weights=None, device=None, precision="fp32",
                 depth_inverted=True, motion_scale=(1, 1), *, widths="default", history=None,
                 reset_fill="zero", exposure=1.0, nits=PQ_NITS, sanitize=False, profile=False,
                 **unused):
        self.spec = SPEC
        self._init_common(scale, device, precision, depth_inverted=depth_inverted,
                          motion_scale=motion_scale, exposure=exposure, sanitize=sanitize,
                          profile=profile)
        if reset_fill not in RESET_FILLS:
            raise ValueError(f"reset_fill: expected {' or '.join(map(repr, RESET_FILLS))}, "
                             f"got {reset_fill!r}")
        self.cfg, self.weights, self.trained = load_weights(weights, self.scale, widths)
        self.history, self.reset_fill, self.nits = history, reset_fill, float(nits)
        self._fs: NsrrFrameStep | None = None

    def device_bytes(self) -> int:
        return 0 if self._fs is None else self._fs.device_bytes()

    def _frame_step(self, hw, reset):
        return self._frame_step_for(hw, reset, lambda h, w: NsrrFrameStep(
            self.dev, self.precision, (h, w), self.scale, self.cfg, self.weights,
            history=self.history, reset_fill=self.reset_fill, nits=self.nits,
            profile=self.profile))

    def step(self, color, depth, motion, jitter, reset=False, reactive=None,
             **gbuffers) -> np.ndarray:
        """One frame from host arrays; returns H x W x 3 float32 linear. `reactive` and
        G-buffers are not used by NSRR."""
        if reset:
            self._pending_reset = True
        if isinstance(color, np.ndarray) and color.ndim == 3:
            self._check_render_size(color.shape[:2], reset)
        frame = validate_frame(color, depth, motion, jitter, None,
                               render_size=None if reset or self._fs is None else self.render_size,
                               sanitize=self.sanitize, depth_inverted=self.depth_inverted)
        fs = self._frame_step(frame["depth"].shape, reset)
        fs.in_color.set(frame["color"])
        fs.in_depth.set(frame["depth"])
        fs.in_motion.set(frame["motion"])
        out = self._run(fs, fs.in_color, fs.in_depth, fs.in_motion, frame["jitter"], None)
        self.last_report = frame["sanitized"]
        return out.get()

    def step_device(self, color, depth, motion, jitter, reset=False, reactive=None, out=None,
                    **gbuffers):
        """One frame from pyopencl arrays (float32, image layout: color h x w x 3, depth
        h x w, motion h x w x 2); returns the H x W x 3 float32 output on the device
        (`out` if given). Values are not checked here: non-finite ones become 0 colour,
        far depth and 0 motion on the device."""
        hw = self._device_frame(reset, color=color, depth=depth, motion=motion, out=out)
        fs = self._frame_step(hw, reset)
        self._check_device_arrays((("color", color, (*hw, 3)), ("depth", depth, hw),
                                   ("motion", motion, (*hw, 2))), out, (fs.H, fs.W, 3))
        return self._run(fs, color, depth, motion, check_jitter(jitter), out)

    def _run(self, fs, color, depth, motion, jitter, out):
        res, ev = fs.run(color, depth, motion, jitter, self._pending_reset,
                         depth_inverted=self.depth_inverted, motion_scale=self.motion_scale,
                         exposure=self.exposure, out=out)
        self._frame_done(ev)
        return res


def _weights_state():
    return "trained" if shipped_weights(2) or shipped_weights(4) else "untrained"


SPEC = MethodSpec(
    "nsrr", "NSRR", "NSRR (Xiao et al. 2020): per-frame features, zero-upsampling, "
    "accumulative warping of 4 previous frames, learned reweighting, a U-Net",
    lambda **kw: NsrrUpscaler(**kw), scales=(2.0, 4.0), weights=_weights_state,
    doc="docs/methods/nsrr.md", twin="clss.methods.nsrr.oracle:twin")
SPECS = {"nsrr": SPEC}
