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

Not temporal: each frame is upscaled on its own (depth and motion are accepted, as the
contract's step, and not used; the jitter is used by a network with the jitter input,
transform.JITTER_KEY, the shipped "mlp" generalists). The frame step
(mlp_upscale.cl in this room, launched by its mlp_upscale.frame): a PQ pass and one kernel
that runs the MLP as a GEMM over render pixels and writes each output pixel once, the
overlapping blocks averaged in registers (the fast path, self-checked); its reference is
the pair of the fused gather + transform + MLP per render pixel and the overlap average +
PQ decode per output pixel; the geometry and transform are transform.py's
(docs/methods/mlp.md).
"""
from __future__ import annotations

import functools

import numpy as np

from ...pipeline.contract import CANNOT, CONVERTS, output_size
from ...pipeline.method import (MethodSpec, MethodUpscaler, conventions, convert_storage,
                                summed_event_ms)
from . import transform as tf
from . import fastpath  # noqa: F401 (registers the kernel's fast path)


class MlpFrame:
    """The device buffers of one frame at render size (h, w), scale s, in `precision`'s
    storage (the kernels read and write it): the inputs, the blocks and the output."""

    def __init__(self, dev, precision, render_size, s, feature):
        self.dev, self.prec = dev, precision
        self.h, self.w = (int(v) for v in render_size)
        self.H, self.W = output_size(self.h, self.w, s)
        b = tf.block(s)
        e = dev.empty
        self.in_color = e((self.h, self.w, 3), precision)
        # the ablation reads no feature: a buffer it never looks at stands for it
        self.in_depth_hr = e((self.H, self.W), precision)
        # the reference pair's blocks [3][B*B][h][w], made when that pair runs (the fused
        # frame step needs none)
        self.bb, self.blocks = b * b, None
        self.pq = None        # the fused step's PQ planes [3][h][w] float, made when it runs
        self.out = e((self.H, self.W, 3), precision)
        # the caller's float32 output when the storage is half
        self.out32 = None if precision == "fp32" else e((self.H, self.W, 3), dtype=np.float32)
        self.events = []        # (stage, event) of a profiled frame step

    def stage_ms(self) -> dict:
        return summed_event_ms(self.events, STAGES)

    def device_bytes(self) -> int:
        return sum(int(a.nbytes) for a in (self.in_color, self.in_depth_hr, self.blocks,
                                           self.pq, self.out, self.out32) if a is not None)


# The stage a profiled frame step times (MethodUpscaler.stage_ms): the network's kernels
# (the reference pair or the fused pair); the storage conversions are not timed.
STAGES = ("mlp",)


class MlpUpscaler(MethodUpscaler):
    """weights: None (the shipped weights of the variant and scale), "untrained",
    "scratch" (the seeded init with a small random output layer, where online training
    starts from nothing), a .safetensors path or a dict of arrays
    (transform.check_weights); allow_untrained: the seeded init where the package has no
    weights for the scale.
    online: train on the device on frames given a `reference` (online.py): `step(...,
    reference=full_res)` trains on it first (train_step), then upscales with the updated
    weights; online_lr, online_batch (patches per step), online_steps (steps per training
    frame), online_seed. contract: clss.Contract (depth_hr follows the depth convention
    and is turned to reversed-Z; exposure and nits honoured; LDR is not)."""

    STAGES = STAGES     # the per-stage timings (MethodUpscaler.stage_ms)

    def __init__(self, scale=2.0, device=None, precision="auto", *, contract=None,
                 weights=None, feature=True, sanitize=False, profile=False, online=False,
                 online_lr=None, online_batch=None, online_steps=None, online_seed=0,
                 allow_untrained=False):
        self.spec = SPECS["mlp" if feature else "mlp-nofeature"]
        self._init_common(scale, device, precision, contract=contract, sanitize=sanitize,
                          profile=profile)
        self.s = tf.check_scale(self.scale)
        self.feature = bool(feature)
        if isinstance(weights, str) and weights == "scratch":
            from .online import scratch_weights
            self.tensors, self.trained = scratch_weights(online_seed), False
        else:
            weights = self.spec.resolve_weights(weights, self.s, allow_untrained)
            self.tensors, self.trained = tf.load_weights(weights)
        self.defines = tf.kernel_defines(self.s, self.feature)
        self.pq_scale, self.inv_pq_scale = tf.pq_scales(self.nits)
        self.online = None
        self.last_loss = None
        self._pack()
        if online:
            from . import online as ol
            # the fp32 master weights; in fp32 the frame step reads them in place, unless
            # the network takes the jitter (the frame step's fc1 bias then holds the
            # frame's jitter term, the master the bias itself)
            master = self._w if self._w_is_master() else \
                self.dev.to_device(tf.packed(self.tensors), "fp32")
            self.online = ol.OnlineTrainer(
                self.dev, self.s, self.feature, master,
                lr=ol.DEFAULT_LR if online_lr is None else online_lr,
                batch=ol.DEFAULT_BATCH if online_batch is None else online_batch,
                steps=ol.DEFAULT_STEPS if online_steps is None else online_steps,
                seed=online_seed, jitter_weight=self.tensors.get(tf.JITTER_KEY),
                nits=self.nits)

    def _w_is_master(self):
        return self.precision == "fp32" and not tf.has_jitter(self.tensors)

    def _pack(self):
        """The frame step's weights buffer from self.tensors (half-rounded in fp16 storage
        mode); with the jitter input, fc1's bias and the jitter weights as packed (the
        same rounding), from which _frame_weights writes the frame's bias."""
        from .mlp_upscale import pack_weights
        self._w = pack_weights(self.dev, self.precision, tf.packed(self.tensors))
        keys = ("fc1.bias", tf.JITTER_KEY) if tf.has_jitter(self.tensors) else ()
        self._w_bias = {k: (self.tensors[k] if self.precision == "fp32" else
                            self.tensors[k].astype(np.float16).astype(np.float32)) for k in keys}
        self._w_jitter = None          # the jitter whose term fc1's bias holds now

    def _frame_weights(self, jitter):
        """The weights buffer for a frame with `jitter`: with the jitter input, fc1's bias
        rewritten as transform.jitter_bias (50 floats, where the jitter changed)."""
        if tf.has_jitter(self.tensors):
            j = tuple(float(v) for v in jitter)
            if j != self._w_jitter:
                import pyopencl as cl
                b = tf.jitter_bias(self._w_bias, j)
                # in queue order: after the frames that read the previous bias (the
                # event holds `b` until the copy is done)
                cl.enqueue_copy(self.dev.queue, self._w.base_data, b, is_blocking=False,
                                dst_offset=self._w.offset + 4 * tf.bias_offset())
                self._w_jitter = j
        return self._w

    def set_weights(self, tensors):
        """Swap the network (a dict of arrays); the next frame uses it."""
        self.tensors = tf.check_weights(tensors)
        if self.online is not None:
            self.online.weights.set(tf.packed(self.tensors))
            self.online.jitter_weight = self.tensors.get(tf.JITTER_KEY)
            if self._w_is_master():
                self._w = self.online.weights
                return
        self._pack()

    # ---- online training (online.py) ------------------------------------------------------
    def train_step(self, color, reference, depth_hr=None, jitter=(0.0, 0.0), **unused) -> float:
        """Train on one frame with its full-resolution reference (online=True): `steps`
        forward/backward/Adam steps on the device; returns the mean L1 loss (PQ). The
        jitter matters to a network with the jitter input (its jitter weights stay as
        they are; fc1's bias learns). depth_hr and the jitter in the caller's contract."""
        if depth_hr is not None:
            depth_hr = self._reversed_z(np.asarray(depth_hr, np.float32))
        return self._train(color, reference, depth_hr, self._jitter(jitter))

    def _train(self, color, reference, depth_hr, jitter) -> float:
        """train_step on depth_hr in reversed-Z and the jitter in render pixels."""
        if self.online is None:
            raise ValueError("train_step: this upscaler was made without online=True")
        color = np.asarray(color, np.float32)
        if self.feature and depth_hr is None:
            h, w = color.shape[:2]
            self._gbuffers({}, (h, w), output_size(h, w, self.s))   # the named error
        loss = self.online.train_frame(color, depth_hr, reference, self.defines,
                                       exposure=self.exposure, frame=self.frame_index,
                                       jitter=jitter)
        if not self._w_is_master():       # the frame step's own copy
            self.tensors = self.learnt_tensors()
            self._pack()
        self.trained = True
        return loss

    def learnt_tensors(self) -> dict:
        """The weights the frame step runs now (online: as learnt so far)."""
        if self.online is None:
            return dict(self.tensors)
        t = self.online.tensors()
        if tf.has_jitter(self.tensors):
            t[tf.JITTER_KEY] = self.tensors[tf.JITTER_KEY]
        return t

    def save_weights(self, path, metadata=None):
        """The current weights as an mlp .safetensors (the format --weights reads)."""
        meta = {"scale": self.s, "feature": self.feature}
        if self.online is not None:
            meta.update(online_steps=self.online.t, lr=self.online.lr,
                        batch=self.online.batch)
        meta.update(metadata or {})
        tf.save_weights(self.learnt_tensors(), path, meta)

    # ---- the frame step ------------------------------------------------------------------
    def _build_frame_step(self, h, w):
        return MlpFrame(self.dev, self.precision, (h, w), self.s, self.feature)

    def _host_frame_hook(self, frame, gbuffers, extra):
        """Online training: a frame given with its full-resolution `reference` trains the
        network first (train_step); the step then upscales with the updated weights."""
        reference = extra.get("reference")
        if self.online is not None and reference is not None:
            # the frame and G-buffers are in the frame step's conventions already
            self.last_loss = self._train(frame["color"], reference,
                                         gbuffers.get("depth_hr") if self.feature else None,
                                         frame["jitter"])

    def _enqueue(self, fs, arrays, jitter, out):
        import pyopencl as cl
        from . import mlp_upscale as ops
        # the kernels read the precision's storage: the device path's float32 inputs
        # are converted into the frame step's own buffers (the host path's are there);
        # inputs already in that storage are read in place
        color = arrays["color"]
        if color.dtype != fs.in_color.dtype:
            color = convert_storage(color, fs.in_color.dtype, out=fs.in_color)
        feat = arrays.get("depth_hr") if self.feature else fs.in_depth_hr
        if feat.dtype != fs.in_depth_hr.dtype:
            feat = convert_storage(feat, fs.in_depth_hr.dtype, out=fs.in_depth_hr)
        from ... import selfcheck
        fused = selfcheck.enabled(self.dev, self.precision, ops.FUSED)
        if not fused and fs.blocks is None:
            fs.blocks = fs.dev.empty((3, fs.bb, fs.h, fs.w), fs.prec)
        if fused and fs.pq is None:
            fs.pq = fs.dev.empty((3, fs.h, fs.w), "fp32")
        ev = [] if self.profile else None
        wts = self._frame_weights(jitter)
        kw = dict(exposure=self.exposure, pq_scale=self.pq_scale,
                  inv_pq_scale=self.inv_pq_scale, blk=fs.blocks, pq=fs.pq, fused=fused,
                  events=ev)
        if fs.out32 is None:
            res = ops.frame(self.dev, self.precision, color, feat, wts, self.defines,
                            out=fs.out if out is None else out, **kw)
        else:
            ops.frame(self.dev, self.precision, color, feat, wts, self.defines,
                      out=fs.out, **kw)
            res = convert_storage(fs.out, np.float32, out=fs.out32 if out is None else out)
        if ev:
            fs.events += [("mlp", e) for e in ev]
        return res, cl.enqueue_marker(self.dev.queue)


# The room's kernels (mlp_upscale.py and mlp_train.py build them; imported when a frame runs).
KERNELS = ("mlp_upscale.cl", "mlp_train.cl")
# What it does with the contract's parameters ("mlp-nofeature" reads no depth_hr, so none
# of the depth convention; neither reads motion).
CONVENTIONS = conventions(
    depth_inverted=(CONVERTS, "depth_hr is turned to reversed-Z (1 - d) before the feature pass"),
    hdr=(CANNOT, "its network was trained on PQ-encoded HDR colour; no LDR path"))
SPECS = {
    "mlp": MethodSpec(
        "mlp", "shader MLP",
        "per-pixel 50-50-50-25 MLP on the 5x5 beauty and 5x5 output-res depth "
        "neighbourhoods (Spencer 2022)",
        functools.partial(MlpUpscaler, feature=True), inputs=("color", "jitter"),
        gbuffers=("depth_hr",), scales=(2.0, 3.0), precisions=("fp32", "fp16"),
        temporal=False, doc="docs/methods/mlp.md", twin="clss.methods.mlp.oracle:twin",
        shipped=tuple((float(s), tf.shipped_name(True, s)) for s in tf.SCALES),
        kernels=KERNELS, fast_paths=fastpath.__name__, cli="clss.methods.mlp.cli_online",
        conventions=CONVENTIONS),
    "mlp-nofeature": MethodSpec(
        "mlp-nofeature", "shader MLP, no feature pass",
        "the shader MLP with its feature inputs zeroed (the seed's ablation); needs no "
        "G-buffer", functools.partial(MlpUpscaler, feature=False), inputs=("color",),
        scales=(2.0, 3.0), precisions=("fp32", "fp16"), temporal=False,
        doc="docs/methods/mlp.md", twin="clss.methods.mlp.oracle:twin",
        shipped=tuple((float(s), tf.shipped_name(False, s)) for s in tf.SCALES),
        kernels=KERNELS, fast_paths=fastpath.__name__, cli="clss.methods.mlp.cli_online",
        conventions=CONVENTIONS),
}
