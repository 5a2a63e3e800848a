"""NSRR (Xiao et al. 2020) behind clss.Upscaler: method "nsrr".

    up = clss.Upscaler(method="nsrr", scale=4)
    out = up.step(color, depth, motion, jitter, reset=cut)        # H x W x 3 linear

Inputs follow the frame contract (docs/input-contract.md). The frame step is frame.py
(nsrr.cl, beside it, around two clss.Model networks); the history (the previous frames'
zero-upsampled, accumulatively warped features) stays on the device. Weights: the
package's clss/weights/nsrr_x{2,4}.safetensors for the nearest trained scale (the networks
do not depend on the scale); weights="untrained" or allow_untrained=True for the seeded
init.
"""
from __future__ import annotations

from ...pipeline.contract import CANNOT
from ...pipeline.method import MethodSpec, MethodUpscaler, conventions
from . import networks as nets
from .frame import KERNEL, RESET_FILLS, STAGES, NsrrFrameStep


def load_weights(weights, scale, widths="default", allow_untrained=False) -> tuple[dict, dict, bool]:
    """(config, weights, trained). weights: None (the shipped file of the trained scale
    nearest to `scale`: 2 below 3, else 4), "untrained", a .safetensors path, or a
    (config, weights dict) pair. Without a shipped file, the seeded init only with
    allow_untrained (MethodSpec.resolve_weights)."""
    return SPEC.load_network(nets, weights, scale, lambda: nets.make_config(widths), allow_untrained,
                             "an NSRR .safetensors file")


class NsrrUpscaler(MethodUpscaler):
    """NSRR temporal supersampling (see the module doc).

    scale: 2 to 4 (any value in between; weights from the nearest trained scale).
    weights: see `load_weights`. widths: the architecture of the untrained init
    ("default", "fast" = the paper's Ours-Fast, "paper"). history: previous frames used
    (0..4; default all the network was built for). reset_fill: what stands for the
    previous frames after a reset: "zero" (empty features, as zero-upsampling marks a
    missing sample) or "duplicate" (the current frame's). precision "fp32" / "fp16".
    allow_untrained: run the seeded init where the package has no weights. contract:
    clss.Contract (all but LDR honoured: the networks were trained on PQ-encoded HDR).
    """

    STAGES = STAGES     # the per-stage timings (MethodUpscaler.stage_ms)

    def __init__(self, scale=4.0, weights=None, device=None, precision="auto", *,
                 contract=None, widths="default", history=None, reset_fill="zero",
                 sanitize=False, profile=False, allow_untrained=False):
        self.spec = SPEC
        self._init_common(scale, device, precision, contract=contract, sanitize=sanitize,
                          profile=profile)
        if reset_fill not in RESET_FILLS:
            raise ValueError(f"reset_fill: expected {' or '.join(map(repr, RESET_FILLS))}, "
                             f"got {reset_fill!r}")
        self.cfg, self.weights, self.trained = load_weights(weights, self.scale, widths,
                                                            allow_untrained)
        self.history, self.reset_fill = history, reset_fill
        self._fs: NsrrFrameStep | None = None

    def _build_frame_step(self, h, w):
        return NsrrFrameStep(self.dev, self.precision, (h, w), self.scale, self.cfg,
                             self.weights, history=self.history, reset_fill=self.reset_fill,
                             nits=self.nits, profile=self.profile)

    def _enqueue(self, fs, arrays, jitter, out):
        return fs.run(arrays["color"], arrays["depth"], arrays["motion"], jitter,
                      self._pending_reset, depth_inverted=self.depth_inverted,
                      motion_scale=self.motion_scale, exposure=self.exposure, out=out)


SPEC = MethodSpec(
    "nsrr", "NSRR", "NSRR (Xiao et al. 2020): per-frame features, zero-upsampling, "
    "accumulative warping of 4 previous frames, learned reweighting, a U-Net",
    NsrrUpscaler, scales=(2.0, 4.0), kernels=(KERNEL.name,), doc="docs/methods/nsrr.md",
    twin="clss.methods.nsrr.oracle:twin",
    shipped=((2.0, "nsrr_x2.safetensors"), (4.0, "nsrr_x4.safetensors")), nearest_scale=True,
    fast_paths="clss.methods.nsrr.frame", conventions=conventions(
        hdr=(CANNOT, "its networks were trained on PQ-encoded HDR colour; no LDR path")))
SPECS = {"nsrr": SPEC}
