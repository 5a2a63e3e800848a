"""NSRD (Li et al. 2024) behind clss.Upscaler: method "nsrd".

    up = clss.Upscaler(method="nsrd", scale=4)
    out = up.step(color, depth, motion, jitter, reset=cut,
                  albedo=a, normal=n, albedo_hr=a_hr)                 # H x W x 3 linear

Inputs follow the frame contract (docs/input-contract.md) plus three G-buffers: the
material component at render and at output resolution (albedo, albedo_hr) and the
render-resolution normal. Without them the step stops with MissingInputError naming
them. The frame step is frame.py (kernels/nsrd.cl around one clss.Model network); its
history (state, previous output, ConvLSTM) stays on the device. Weights: the package's
clss/weights/nsrd_x{2,3,4}.safetensors for the scale, or the seeded init ("untrained").
"""
from __future__ import annotations

import os

import numpy as np

from ...pipeline.contract import PQ_NITS, check_jitter, validate_frame
from ...pipeline.method import (UNTRAINED, MethodSpec, MethodUpscaler, weights_file,
                               weights_or_shipped)
from . import networks as nets
from .frame import STAGES, NsrdFrameStep

WEIGHTS_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(
    __file__)))), "weights")
GBUFFERS = ("albedo", "normal", "albedo_hr")
_warned = []


def shipped_weights(scale) -> str | None:
    p = os.path.join(WEIGHTS_DIR, f"nsrd_x{int(round(float(scale)))}.safetensors")
    return p if os.path.isfile(p) else None


def load_weights(weights, scale, widths="default") -> tuple[dict, dict, bool]:
    """(config, weights, trained). weights: None (the shipped file for the scale, else the
    seeded init with one warning), "untrained", a .safetensors path, or a (config,
    weights dict) pair. The config's scale must be the upscaler's."""
    cfg0 = nets.make_config(scale, widths)        # checks the scale (integer, 2..4)
    weights = weights_or_shipped(weights, shipped_weights(scale), "nsrd", scale, _warned,
                                 WEIGHTS_DIR)
    if isinstance(weights, str) and weights == UNTRAINED:
        return cfg0, nets.init_weights(cfg0), False
    if isinstance(weights, tuple):
        cfg, w = weights
        nets.check_weights(cfg, w)
        trained = True
    else:
        cfg, w = nets.load(weights_file(weights, "an NSRD .safetensors file"))
        trained = True
    if int(cfg["scale"]) != int(cfg0["scale"]):
        raise ValueError(f"weights: the network was trained for scale {cfg['scale']}, the "
                         f"upscaler runs at {cfg0['scale']}")
    return cfg, w, trained


class NsrdUpscaler(MethodUpscaler):
    """NSRD neural supersampling with radiance demodulation (see the module doc).

    scale: 2, 3 or 4 (the sub-pixel output is per integer scale). weights: see
    `load_weights`. widths: the untrained init's ("default", "fast"). precision "fp32" /
    "fp16" (half storage, float accumulation)."""

    STAGES = STAGES     # the per-stage timings (MethodUpscaler.stage_ms)

    def __init__(self, scale=4.0, weights=None, device=None, precision="fp32",
                 depth_inverted=True, motion_scale=(1, 1), *, widths="default",
                 exposure=1.0, nits=PQ_NITS, sanitize=False, profile=False, **unused):
        self.spec = SPEC
        self._init_common(scale, device, precision, depth_inverted=depth_inverted,
                          motion_scale=motion_scale, exposure=exposure, sanitize=sanitize,
                          profile=profile)
        self.cfg, self.weights, self.trained = load_weights(weights, self.scale, widths)
        self.nits = float(nits)
        self._fs: NsrdFrameStep | None = None

    def device_bytes(self) -> int:
        return 0 if self._fs is None else self._fs.device_bytes()

    def _frame_step(self, hw, reset):
        return self._frame_step_for(hw, reset, lambda h, w: NsrdFrameStep(
            self.dev, self.precision, (h, w), self.cfg, self.weights, nits=self.nits,
            profile=self.profile))

    def step(self, color, depth, motion, jitter, reset=False, reactive=None,
             **gbuffers) -> np.ndarray:
        """One frame from host arrays with the G-buffers albedo, normal (h x w x 3) and
        albedo_hr (H x W x 3) as keywords; returns H x W x 3 float32 linear. `reactive`
        is not used."""
        if reset:
            self._pending_reset = True
        if isinstance(color, np.ndarray) and color.ndim == 3:
            self._check_render_size(color.shape[:2], reset)
        frame = validate_frame(color, depth, motion, jitter, None,
                               render_size=None if reset or self._fs is None else self.render_size,
                               sanitize=self.sanitize, depth_inverted=self.depth_inverted)
        hw = frame["depth"].shape
        s = int(self.cfg["scale"])
        gb = self._gbuffers(gbuffers, hw, (hw[0] * s, hw[1] * s))
        fs = self._frame_step(hw, reset)
        for a, v in ((fs.in_color, frame["color"]), (fs.in_depth, frame["depth"]),
                     (fs.in_motion, frame["motion"]), (fs.in_albedo, gb["albedo"]),
                     (fs.in_normal, gb["normal"]), (fs.in_albedo_hr, gb["albedo_hr"])):
            a.set(v)
        out = self._run(fs, fs.in_color, fs.in_depth, fs.in_motion, fs.in_albedo,
                        fs.in_normal, fs.in_albedo_hr, frame["jitter"], None)
        self.last_report = frame["sanitized"]
        return out.get()

    def step_device(self, color, depth, motion, jitter, reset=False, reactive=None, out=None,
                    **gbuffers):
        """One frame from pyopencl arrays (float32, image layout: color, albedo, normal
        h x w x 3, depth h x w, motion h x w x 2, albedo_hr H x W x 3); returns the
        H x W x 3 float32 output on the device (`out` if given)."""
        from ...pipeline.contract import MissingInputError, gbuffer_sources
        missing = [n for n in GBUFFERS if gbuffers.get(n) is None]
        if missing:
            raise MissingInputError(f"method 'nsrd' needs {', '.join(missing)}, which the "
                                    "frame does not carry; pass "
                                    + "; ".join(gbuffer_sources(n) for n in missing))
        hw = self._device_frame(reset, color=color, depth=depth, motion=motion, out=out,
                                **{n: gbuffers[n] for n in GBUFFERS})
        fs = self._frame_step(hw, reset)
        H, W = fs.H, fs.W
        self._check_device_arrays((("color", color, (*hw, 3)), ("depth", depth, hw),
                                   ("motion", motion, (*hw, 2)),
                                   ("albedo", gbuffers["albedo"], (*hw, 3)),
                                   ("normal", gbuffers["normal"], (*hw, 3)),
                                   ("albedo_hr", gbuffers["albedo_hr"], (H, W, 3))),
                                  out, (H, W, 3))
        return self._run(fs, color, depth, motion, gbuffers["albedo"], gbuffers["normal"],
                         gbuffers["albedo_hr"], check_jitter(jitter), out)

    def _run(self, fs, color, depth, motion, albedo, normal, albedo_hr, jitter, out):
        res, ev = fs.run(color, depth, motion, albedo, normal, albedo_hr, jitter,
                         self._pending_reset, depth_inverted=self.depth_inverted,
                         motion_scale=self.motion_scale, exposure=self.exposure, out=out)
        self._frame_done(ev)
        return res


def _weights_state():
    return "trained" if any(shipped_weights(s) for s in (2, 3, 4)) else "untrained"


SPEC = MethodSpec(
    "nsrd", "NSRD", "NSRD (Li et al. 2024): radiance demodulation, a depth-test occlusion "
    "mask, gated-conv warping of 2 previous frames, ConvLSTM, U-shaped RCAB reconstruction, "
    "sub-pixel upsampling, re-modulation",
    lambda **kw: NsrdUpscaler(**kw), gbuffers=GBUFFERS, scales=(2.0, 4.0),
    weights=_weights_state, doc="docs/methods/nsrd.md", twin="clss.methods.nsrd.oracle:twin")
SPECS = {"nsrd": SPEC}
