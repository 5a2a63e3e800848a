"""NSRD (Li et al. 2024) behind clss.Upscaler: method "nsrd".

    up = clss.Upscaler(method="nsrd", scale=4)
    out = up.step(color, depth, motion, jitter, reset=cut,
                  albedo=a, normal=n, albedo_hr=a_hr)                 # H x W x 3 linear

Inputs follow the frame contract (docs/input-contract.md) plus three G-buffers: the
material component at render and at output resolution (albedo, albedo_hr) and the
render-resolution normal. Without them the step stops with MissingInputError naming
them. The frame step is frame.py (nsrd.cl, beside it, around one clss.Model network); its
history (state, previous output, ConvLSTM) stays on the device. Weights: the package's
clss/weights/nsrd_x{2,3,4}.safetensors for the scale; a scale without its file (3 today)
needs weights= or allow_untrained=True (the seeded init).
"""
from __future__ import annotations

from ...pipeline.contract import CANNOT
from ...pipeline.method import MethodSpec, MethodUpscaler, conventions
from . import networks as nets
from .frame import KERNEL, STAGES, NsrdFrameStep

GBUFFERS = ("albedo", "normal", "albedo_hr")


def load_weights(weights, scale, widths="default", allow_untrained=False) -> tuple[dict, dict, bool]:
    """(config, weights, trained). weights: None (the shipped file for the scale),
    "untrained", a .safetensors path, or a (config, weights dict) pair. A scale the
    package has no file for is refused unless allow_untrained (the seeded init;
    MethodSpec.resolve_weights). The config's scale must be the upscaler's."""
    cfg0 = nets.make_config(scale, widths)        # checks the scale (integer, 2..4)
    cfg, w, trained = SPEC.load_network(nets, weights, scale, lambda: cfg0, allow_untrained,
                                        "an NSRD .safetensors file")
    if not trained:
        return cfg, w, False
    if int(cfg["scale"]) != int(cfg0["scale"]):
        raise ValueError(f"weights: the network was trained for scale {cfg['scale']}, the "
                         f"upscaler runs at {cfg0['scale']}")
    return cfg, w, True


class NsrdUpscaler(MethodUpscaler):
    """NSRD neural supersampling with radiance demodulation (see the module doc).

    scale: 2, 3 or 4 (the sub-pixel output is per integer scale). weights: see
    `load_weights`. widths: the untrained init's ("default", "fast"). precision "fp32" /
    "fp16" (half storage, float accumulation). allow_untrained: run the seeded init where
    the package has no weights for the scale. contract: clss.Contract (all but LDR
    honoured: the network was trained on PQ-encoded HDR)."""

    STAGES = STAGES     # the per-stage timings (MethodUpscaler.stage_ms)

    def __init__(self, scale=4.0, weights=None, device=None, precision="auto", *,
                 contract=None, widths="default", sanitize=False, profile=False,
                 allow_untrained=False):
        self.spec = SPEC
        self._init_common(scale, device, precision, contract=contract, sanitize=sanitize,
                          profile=profile)
        self.cfg, self.weights, self.trained = load_weights(weights, self.scale, widths,
                                                            allow_untrained)
        self._fs: NsrdFrameStep | None = None

    def _build_frame_step(self, h, w):
        return NsrdFrameStep(self.dev, self.precision, (h, w), self.cfg, self.weights,
                             nits=self.nits, profile=self.profile)

    def _enqueue(self, fs, arrays, jitter, out):
        a = arrays
        return fs.run(a["color"], a["depth"], a["motion"], a["albedo"], a["normal"],
                      a["albedo_hr"], jitter, self._pending_reset,
                      depth_inverted=self.depth_inverted, motion_scale=self.motion_scale,
                      exposure=self.exposure, out=out)


SPEC = MethodSpec(
    "nsrd", "NSRD", "NSRD (Li et al. 2024): radiance demodulation, a depth-test occlusion "
    "mask, gated-conv warping of 2 previous frames, ConvLSTM, U-shaped RCAB reconstruction, "
    "sub-pixel upsampling, re-modulation",
    NsrdUpscaler, gbuffers=GBUFFERS, scales=(2.0, 4.0), kernels=(KERNEL.name,), doc="docs/methods/nsrd.md",
    twin="clss.methods.nsrd.oracle:twin",
    shipped=tuple((float(s), f"nsrd_x{s}.safetensors") for s in (2, 3, 4)),
    fast_paths="clss.methods.nsrd.frame", conventions=conventions(
        hdr=(CANNOT, "its network was trained on PQ-encoded HDR colour; no LDR path")))
SPECS = {"nsrd": SPEC}
