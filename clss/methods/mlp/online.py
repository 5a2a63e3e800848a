"""Online training of the shader MLP upscaler on the OpenCL device, while it upscales (the
seed's own system; docs/methods/mlp.md, "Online training").

Contract: a frame that carries a full-resolution `reference` (the renderer affords one now
and then) is a training frame. Per training frame the engine draws `batch` patches of that
frame accepted by gradient (clss.methods.mlp.patches, the offline recipe's rule), and runs
`steps` optimiser steps of forward, backward and Adam on the device
(mlp_train.cl), in place on the packed weights the frame step reads; then the frame
is upscaled with the updated weights. Loss: the offline recipe's (L1 in PQ on the folded
output over each patch's loss region). Adam: torch's defaults (betas 0.9, 0.999, eps 1e-8),
learning rate `lr`, no decay (a stream has no end to decay towards).

Training runs in fp32 whatever the frame step's precision: in fp16 storage mode the frame
step reads a half-rounded copy of the weights, refreshed after each step.

A network with the jitter input (transform.JITTER_KEY) trains with each frame's jitter
term in fc1's bias (a copy of the weights that the forward and backward read); Adam then
updates the bias itself. The jitter weights are not trained online: the stream's jitter
is a short cycle of the same few offsets, which the bias already learns per frame.
"""
from __future__ import annotations

import numpy as np

from ...pipeline.contract import pq_encode
from . import patches as pt
from . import transform as tf

DEFAULT_LR = 1e-3
DEFAULT_BATCH = 32
DEFAULT_STEPS = 1


def scratch_weights(seed=0) -> dict:
    """The from-scratch start: the seeded init with a small random output layer (a zero
    output layer gets no gradient through the ramp's inverse at 0; the offline recipe
    starts the same way)."""
    g = np.random.default_rng(seed)
    t = tf.init_weights(seed)
    t["fc3.weight"] = (g.standard_normal((25, 50)) * 0.01).astype(np.float32)
    return t


class OnlineTrainer:
    """Adam on the device over the packed weights buffer `weights` (fp32, WEIGHT_COUNT),
    updated in place."""

    def __init__(self, dev, scale, feature, weights, *, lr=DEFAULT_LR, batch=DEFAULT_BATCH,
                 steps=DEFAULT_STEPS, seed=0, nits=None, jitter_weight=None):
        from .mlp_upscale import WEIGHT_COUNT
        from ...pipeline.contract import PQ_NITS
        self.dev, self.s, self.feature = dev, tf.check_scale(scale), bool(feature)
        self.lr, self.batch, self.steps = float(lr), int(batch), int(steps)
        if self.batch < 1 or self.steps < 1:
            raise ValueError("online training: batch and steps must be at least 1")
        self.nits = PQ_NITS if nits is None else nits
        self.weights = weights
        self.jitter_weight = jitter_weight      # [50, 2] of a jitter-input network, or None
        self.jittered = None                    # the weights with a frame's jitter term
        self.m = dev.to_device(np.zeros(WEIGHT_COUNT, np.float32))
        self.v = dev.to_device(np.zeros(WEIGHT_COUNT, np.float32))
        self.t = 0
        self.rng = np.random.default_rng(seed)
        self.defines = None
        self.tb = None
        self.history = []          # (frame index, mean L1 of the frame's steps)
        self.accepted = self.tried = 0

    def _buffers(self, defines):
        from .mlp_train import TrainBuffers, defines as train_defines
        if self.tb is None:
            self.tb = TrainBuffers(self.dev, self.batch, self.s, self.s + 2, pt.PATCH, pt.MARGIN)
            self.defines = train_defines(defines, pt.PATCH, pt.MARGIN)
        return self.tb

    def prepare(self, color, depth_hr, reference, exposure=1.0):
        """One training frame on the host: PQ colour and reference, and its patch rule."""
        c = pq_encode(np.asarray(color, np.float32) / exposure, self.nits)
        r = pq_encode(np.asarray(reference, np.float32) / exposure, self.nits)
        if r.shape != (self.s * c.shape[0], self.s * c.shape[1], 3):
            raise ValueError(f"reference: expected [{self.s * c.shape[0]}, "
                             f"{self.s * c.shape[1]}, 3] at scale {self.s}, got {r.shape}")
        integ = pt.gradient_integral(r)
        rule = pt.Sampler([c.shape[:2]], [(0, 1)], lambda k, t: integ, self.s, rng=self.rng)
        d = None if not self.feature else np.asarray(depth_hr, np.float32)
        return c, d, r, rule

    def cut(self, frame):
        """A batch of `batch` patches of a prepared frame accepted by gradient, on the host:
        (col [P,3,C,C], feat [P,sC,sC], ref [P,3,L,L]), PQ (depth as it is)."""
        c, d, r, rule = frame
        s, P, size, L = self.s, self.batch, pt.crop_size(), self.s * pt.PATCH
        col = np.empty((P, 3, size, size), np.float32)
        feat = np.zeros((P, s * size, s * size), np.float32)
        ref = np.empty((P, 3, L, L), np.float32)
        t0, a0 = rule.tried, rule.accepted
        for p in range(P):
            _, _, i0, j0 = rule.draw()
            col[p] = c[i0:i0 + size, j0:j0 + size].transpose(2, 0, 1)
            if d is not None:
                feat[p] = d[s * i0:s * (i0 + size), s * j0:s * (j0 + size)]
            y0, x0 = s * (i0 + pt.MARGIN), s * (j0 + pt.MARGIN)
            ref[p] = r[y0:y0 + L, x0:x0 + L].transpose(2, 0, 1)
        self.tried += rule.tried - t0
        self.accepted += rule.accepted - a0
        return col, feat, ref

    def load(self, col, feat, ref, defines):
        tb = self._buffers(defines)
        tb.col.set(np.ascontiguousarray(col, np.float32))
        tb.feat.set(np.ascontiguousarray(feat, np.float32))
        tb.ref.set(np.ascontiguousarray(ref, np.float32))
        return tb

    def _forward_weights(self, jitter):
        """The weights the forward and backward read: the master, or with the jitter
        input a copy whose fc1 bias holds the frame's jitter term."""
        if self.jitter_weight is None:
            return self.weights
        import pyopencl as cl
        if self.jittered is None:
            self.jittered = self.weights.copy()
        else:
            cl.enqueue_copy(self.dev.queue, self.jittered.data, self.weights.data)
        off, n = tf.bias_offset(), tf.WIDTHS[1]
        b = self.weights[off:off + n].get()
        self.jittered[off:off + n].set(tf.jitter_bias(
            {"fc1.bias": b, tf.JITTER_KEY: self.jitter_weight}, jitter))
        return self.jittered

    def gradients(self, defines, jitter=(0.0, 0.0)):
        """Forward, loss and backward on the loaded batch: (gradient buffer, L1 loss)."""
        from .mlp_train import forward_backward
        tb = self._buffers(defines)
        g = forward_backward(self.dev, tb, self._forward_weights(jitter), self.defines)
        loss = float(np.abs(tb.diff.get()).mean())
        return g, loss

    def step(self, defines, jitter=(0.0, 0.0)):
        """One optimiser step on the loaded batch; returns its loss (before the step)."""
        from .mlp_train import adam
        g, loss = self.gradients(defines, jitter)
        self.t += 1
        adam(self.dev, self.weights, g, self.m, self.v, self.t, self.lr)
        return loss

    def train_frame(self, color, depth_hr, reference, defines, exposure=1.0, frame=None,
                    jitter=(0.0, 0.0)):
        """`steps` steps, each on a fresh batch of this frame's patches; the mean loss."""
        losses = []
        prepared = self.prepare(color, depth_hr, reference, exposure)
        for _ in range(self.steps):
            self.load(*self.cut(prepared), defines)
            losses.append(self.step(defines, jitter))
        loss = float(np.mean(losses))
        self.history.append((frame, loss))
        return loss

    def tensors(self) -> dict:
        """The current weights as the safetensors dict."""
        flat = self.weights.get()
        out, off = {}, 0
        for k, name in enumerate(tf.LAYER_NAMES):
            ci, co = tf.WIDTHS[k], tf.WIDTHS[k + 1]
            out[f"{name}.weight"] = flat[off:off + co * ci].reshape(co, ci).copy()
            out[f"{name}.bias"] = flat[off + co * ci:off + co * ci + co].copy()
            off += co * ci + co
        return out
