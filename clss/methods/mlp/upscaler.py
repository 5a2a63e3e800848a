"""The shader MLP upscaler (seed 004, Spencer 2022) on an OpenCL device, frame by frame:
methods "mlp" (beauty + the depth feature pass at output resolution) and "mlp-nofeature"
(the seed's ablation: the feature inputs zeroed, its own weights; it needs no G-buffer).

    up = clss.Upscaler(method="mlp", scale=2)             # the shipped generalist
    up = clss.Upscaler(method="mlp", scale=3, weights="scene.safetensors")
    out = up.step(color, depth, motion, jitter, depth_hr=depth_hr)     # H x W x 3

    # online training on the device (online.py): a frame with a full-resolution reference
    # trains the network (forward, backward, Adam) before it is upscaled
    up = clss.Upscaler(method="mlp", scale=2, online=True)   # from the shipped weights
    out = up.step(color, depth_hr=depth_hr, reference=full_res)   # trains, then upscales
    loss = up.train_step(color, full_res, depth_hr=depth_hr)       # trains only
    up.save_weights("learnt.safetensors")

Not temporal: each frame is upscaled on its own (depth, motion and jitter are accepted,
as the contract's step, and not used). The frame step is two kernels
(kernels/mlp_upscale.cl, launched by clss.ops.mlp_upscale): the fused gather + transform
+ MLP per render pixel, and the overlap average + PQ decode per output pixel; the
geometry and transform are transform.py's (docs/methods/mlp.md).
"""
from __future__ import annotations

import numpy as np

from ...pipeline.contract import PQ_NITS, output_size
from ...pipeline.method import MethodSpec, MethodUpscaler
from . import transform as tf
from . import fastpath  # noqa: F401 (registers the kernel's fast path)


class MlpUpscaler(MethodUpscaler):
    """weights: None (the shipped weights of the variant, else the seeded init),
    "untrained", "scratch" (the seeded init with a small random output layer, where online
    training starts from nothing), a .safetensors path or a dict of arrays
    (transform.check_weights).
    online: train on the device on frames given a `reference` (online.py); online_lr,
    online_batch (patches per step), online_steps (steps per training frame),
    online_seed."""

    def __init__(self, scale=2.0, device=None, precision="fp32", *, weights=None,
                 feature=True, exposure=1.0, sanitize=False, profile=False, online=False,
                 online_lr=None, online_batch=None, online_steps=None, online_seed=0,
                 **unused):
        self.spec = SPECS["mlp" if feature else "mlp-nofeature"]
        self._init_common(scale, device, precision, exposure=exposure, sanitize=sanitize,
                          profile=profile)
        self.s = tf.check_scale(self.scale)
        self.feature = bool(feature)
        if isinstance(weights, str) and weights == "scratch":
            from .online import scratch_weights
            self.tensors, self.trained = scratch_weights(online_seed), False
        else:
            self.tensors, self.trained = tf.load_weights(weights, feature=self.feature,
                                                         scale=self.s)
        self.defines = tf.kernel_defines(self.s, self.feature)
        self.pq_scale, self.inv_pq_scale = tf.pq_scales(PQ_NITS)
        from .mlp_upscale import pack_weights
        self._w = pack_weights(self.dev, self.precision, tf.packed(self.tensors))
        self.online = None
        self.last_loss = None
        if online:
            from . import online as ol
            # the fp32 master weights; in fp32 the frame step reads them in place
            master = self._w if self.precision == "fp32" else \
                self.dev.to_device(tf.packed(self.tensors), "fp32")
            self.online = ol.OnlineTrainer(
                self.dev, self.s, self.feature, master,
                lr=ol.DEFAULT_LR if online_lr is None else online_lr,
                batch=ol.DEFAULT_BATCH if online_batch is None else online_batch,
                steps=ol.DEFAULT_STEPS if online_steps is None else online_steps,
                seed=online_seed)
        self._hw = None
        self._blocks = None
        self._zero_feat = None

    def set_weights(self, tensors):
        """Swap the network (a dict of arrays); the next frame uses it."""
        from .mlp_upscale import pack_weights
        self.tensors = tf.check_weights(tensors)
        if self.online is not None:
            self.online.weights.set(tf.packed(self.tensors))
            if self.precision == "fp32":
                return
        self._w = pack_weights(self.dev, self.precision, tf.packed(self.tensors))

    # ---- online training (online.py) ------------------------------------------------------
    def train_step(self, color, reference, depth_hr=None, **unused) -> float:
        """Train on one frame with its full-resolution reference (online=True): `steps`
        forward/backward/Adam steps on the device; returns the mean L1 loss (PQ)."""
        if self.online is None:
            raise ValueError("train_step: this upscaler was made without online=True")
        color = np.asarray(color, np.float32)
        if self.feature and depth_hr is None:
            h, w = color.shape[:2]
            self._gbuffers({}, (h, w), output_size(h, w, self.s))   # the named error
        loss = self.online.train_frame(color, depth_hr, reference, self.defines,
                                       exposure=self.exposure, frame=self.frame_index)
        if self.precision != "fp32":       # the frame step's half-rounded copy
            from .mlp_upscale import pack_weights
            self._w = pack_weights(self.dev, self.precision, self.online.weights.get())
        self.trained = True
        return loss

    def learnt_tensors(self) -> dict:
        """The weights the frame step runs now (online: as learnt so far)."""
        return self.online.tensors() if self.online is not None else dict(self.tensors)

    def save_weights(self, path, metadata=None):
        """The current weights as an mlp .safetensors (the format --weights reads)."""
        meta = {"scale": self.s, "feature": self.feature}
        if self.online is not None:
            meta.update(online_steps=self.online.t, lr=self.online.lr,
                        batch=self.online.batch)
        meta.update(metadata or {})
        tf.save_weights(self.learnt_tensors(), path, meta)

    @property
    def render_size(self):
        return self._hw

    @property
    def output_size(self):
        return None if self._hw is None else output_size(*self._hw, self.s)

    def device_bytes(self) -> int:
        return int(self._blocks.nbytes) if self._blocks is not None else 0

    def _prepare(self, hw, reset):
        self._check_render_size(hw, reset or self._pending_reset)
        if self._hw != tuple(hw):
            self._hw = tuple(hw)
            b = tf.block(self.s)
            self._blocks = self.dev.empty((3, b * b) + self._hw, self.precision)
            self._zero_feat = None

    def _run(self, color_d, feat_d, out=None):
        from . import mlp_upscale as ops
        if feat_d is None:          # the ablation: the kernel reads no feature
            if self._zero_feat is None:
                H, W = self.output_size
                self._zero_feat = self.dev.empty((H, W), self.precision)
            feat_d = self._zero_feat
        ops.blocks(self.dev, self.precision, color_d, feat_d, self._w, self.defines,
                   inv_exposure=1.0 / self.exposure, pq_scale=self.pq_scale, out=self._blocks)
        return ops.fold(self.dev, self.precision, self._blocks, self.defines,
                        exposure=self.exposure, inv_pq_scale=self.inv_pq_scale, out=out)

    def step(self, color, depth=None, motion=None, jitter=(0.0, 0.0), reset=False,
             reactive=None, reference=None, **gbuffers) -> np.ndarray:
        """reference: a full-resolution frame [H, W, 3]; with online=True the step trains
        on it first (train_step), then upscales with the updated weights; else unused."""
        frame, (h, w) = self._color_frame(color, reset)
        gb = self._gbuffers(gbuffers, (h, w), output_size(h, w, self.s))
        self._prepare((h, w), reset)
        self.last_report = frame["sanitized"]
        self._pending_reset = False
        if self.online is not None and reference is not None:
            self.last_loss = self.train_step(frame["color"], reference,
                                             gb.get("depth_hr") if self.feature else None)
        self.frame_index += 1
        c = self.dev.to_device(frame["color"], self.precision)
        f = self.dev.to_device(gb["depth_hr"], self.precision) if self.feature else None
        return self.dev.to_host(self._run(c, f))

    def step_device(self, color, depth=None, motion=None, jitter=(0.0, 0.0), reset=False,
                    reactive=None, out=None, depth_hr=None, **gbuffers):
        """The step on pyopencl arrays in the precision's storage type: color [h, w, 3],
        depth_hr [H, W]; no host copies. Non-finite values are not checked here."""
        if color.ndim != 3 or color.shape[2] != 3:
            raise ValueError(f"color: expected [h, w, 3], got {color.shape}")
        hw = color.shape[:2]
        if self.feature and depth_hr is None:
            self._gbuffers({}, hw, output_size(*hw, self.s))       # the named error
        self._prepare(hw, reset)
        self._pending_reset = False
        self.frame_index += 1
        return self._run(color, depth_hr if self.feature else None, out=out)


def _weights_state(feature):
    def fn():
        import os
        return "trained" if all(os.path.isfile(tf.shipped_path(feature, s))
                                for s in tf.SCALES) else "untrained"
    return fn


SPECS = {
    "mlp": MethodSpec(
        "mlp", "shader MLP",
        "per-pixel 50-50-50-25 MLP on the 5x5 beauty and 5x5 output-res depth "
        "neighbourhoods (Spencer 2022)",
        lambda **kw: MlpUpscaler(feature=True, **kw), inputs=("color",),
        gbuffers=("depth_hr",), scales=(2.0, 3.0), precisions=("fp32", "fp16"),
        temporal=False, weights=_weights_state(True), doc="docs/methods/mlp.md",
        twin="clss.methods.mlp.oracle:twin"),
    "mlp-nofeature": MethodSpec(
        "mlp-nofeature", "shader MLP, no feature pass",
        "the shader MLP with its feature inputs zeroed (the seed's ablation); needs no "
        "G-buffer", lambda **kw: MlpUpscaler(feature=False, **kw), inputs=("color",),
        scales=(2.0, 3.0), precisions=("fp32", "fp16"), temporal=False,
        weights=_weights_state(False), doc="docs/methods/mlp.md",
        twin="clss.methods.mlp.oracle:twin"),
}
