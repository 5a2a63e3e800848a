"""NSS (Arm Neural Super Sampling, 2025) behind clss.Upscaler: method "nss".

    up = clss.Upscaler(method="nss", scale=2)
    out = up.step(color, depth, motion, jitter, reset=cut)            # H x W x 3 linear

Inputs: the frame contract's colour, depth, motion and jitter, and the exposure; no
G-buffers. 2x only. Any render size: the network runs on the size padded to multiples of
8 (the padding repeats the edge). The frame step is frame.py (nss.cl beside it, around
one clss.Model network); its history (output, temporal parameters, luma derivative) stays
on the device. Weights: the package's clss/weights/nss_x2.safetensors where it ships
one; without it weights= or allow_untrained=True (the seeded init).
"""
from __future__ import annotations

from ...pipeline.contract import CANNOT, CONVERTS, PQ_NITS
from ...pipeline.method import MethodSpec, MethodUpscaler, conventions
from . import networks as nets
from .frame import KERNEL, STAGES, NssFrameStep


def load_weights(weights, scale, quality="mid", allow_untrained=False) -> tuple[dict, dict, bool]:
    """(config, weights, trained). weights: None (the shipped file), "untrained", a
    .safetensors path, or a (config, weights dict) pair."""
    cfg0 = nets.make_config(scale, quality)        # checks the scale (2) and the preset
    return SPEC.load_network(nets, weights, scale, lambda: cfg0, allow_untrained, "an NSS .safetensors file")


class NssUpscaler(MethodUpscaler):
    """NSS neural temporal supersampling (see the module doc).

    scale: 2. weights: see `load_weights`. quality: the untrained init's preset ("low" /
    "mid": 4x4 kernel taps, "high": 6x6; trained weights carry their own). precision
    "fp32" / "fp16" (half storage of the network's tensors, float accumulation).
    depth_scatter: "atomic" (the reprojected depth by 32-bit atomic max) or "gather" (the
    portable path without atomics). allow_untrained: the seeded init where the package
    has no weights. contract: clss.Contract (all but LDR; nits becomes an exposure)."""

    STAGES = STAGES

    def __init__(self, scale=2.0, weights=None, device=None, precision="auto", *,
                 contract=None, quality="mid", depth_scatter="atomic", sanitize=False,
                 profile=False, allow_untrained=False):
        self.spec = SPEC
        self._init_common(scale, device, precision, contract=contract, sanitize=sanitize,
                          profile=profile)
        self.cfg, self.weights, self.trained = load_weights(weights, self.scale, quality,
                                                            allow_untrained)
        from .frame import DEPTH_PATHS
        if depth_scatter not in DEPTH_PATHS:
            raise ValueError(f"depth_scatter: expected one of {', '.join(DEPTH_PATHS)}, "
                             f"got {depth_scatter!r}")
        self.depth_scatter = depth_scatter
        self._fs: NssFrameStep | None = None

    def _build_frame_step(self, h, w):
        return NssFrameStep(self.dev, self.precision, (h, w), self.cfg, self.weights,
                            depth_scatter=self.depth_scatter, profile=self.profile)

    def _enqueue(self, fs, arrays, jitter, out):
        a = arrays
        # its frame step has no PQ transfer: linear 1.0 = nits cd/m2 is linear nits / 100
        # in the 100-nit units it was trained on, an exposure of 100 / nits
        return fs.run(a["color"], a["depth"], a["motion"], jitter, self._pending_reset,
                      depth_inverted=self.depth_inverted, motion_scale=self.motion_scale,
                      exposure=self.exposure * PQ_NITS / self.nits, out=out)


SPEC = MethodSpec(
    "nss", "NSS", "NSS (Arm 2025): depth-scatter disocclusion, warped history and feedback, "
    "luma derivative; a 14-conv U-Net predicts kernel weights and temporal parameters; "
    "jitter-aware kernel filter, Catmull-Rom history, clamp, tonemapped accumulation",
    NssUpscaler, scales=(2.0, 2.0), kernels=(KERNEL.name,), doc="docs/methods/nss.md",
    twin="clss.methods.nss.oracle:twin", shipped=((2.0, "nss_x2.safetensors"),),
    conventions=conventions(
        hdr=(CANNOT, "its network was trained on HDR colour in a tonemapped domain; no "
                     "LDR path"),
        nits=(CONVERTS, "an exposure of 100 / nits: its frame step has no PQ transfer")))
SPECS = {"nss": SPEC}
