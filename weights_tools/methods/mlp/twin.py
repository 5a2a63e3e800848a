"""The torch twin of the shader MLP upscaler's frame step (clss/methods/mlp/): the same
geometry, transform and network as clss/methods/mlp/mlp_upscale.cl and the ONNX twin, from the
constants and functions of clss.methods.mlp.transform (ramp, ramp_inv, widths, scales),
so that training optimises exactly what the engine runs. tests/test_method_mlp.py holds it
to the OpenCL step.

    net = MlpNet(scale=2)                    # parameters fc1/fc2/fc3 = the safetensors keys
    out_pq = net(color_pq, depth_hr)         # [N,3,h,w] PQ, [N,1,H,W] -> [N,3,H,W] PQ
    net = MlpNet(scale=2, jitter=True)       # + fcj: the jitter input (transform.JITTER_KEY)
    out_pq = net(color_pq, depth_hr, jitter) # jitter [N, 2], render pixels
    net.tensors()                            # {name: numpy} for transform.save_weights
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from clss.methods.mlp import transform as tf
from clss.pipeline.contract import PQ_NITS, pq_decode, pq_encode


class MlpNet(nn.Module):
    def __init__(self, scale=2, feature=True, tensors=None, jitter=False):
        """jitter: add the jitter input (zero-initialised where `tensors` lack it, so that
        the network starts as the one it was loaded from); on by itself where they have it."""
        super().__init__()
        self.s, self.b = tf.check_scale(scale), tf.block(scale)
        self.feature = bool(feature)
        self.fc1 = nn.Linear(tf.WIDTHS[0], tf.WIDTHS[1])
        self.fc2 = nn.Linear(tf.WIDTHS[1], tf.WIDTHS[2])
        self.fc3 = nn.Linear(tf.WIDTHS[2], tf.WIDTHS[3])
        self.fcj = None
        if jitter or (tensors is not None and tf.has_jitter(tensors)):
            self.fcj = nn.Linear(2, tf.WIDTHS[1], bias=False)
            nn.init.zeros_(self.fcj.weight)
        self.load_tensors(tf.init_weights() if tensors is None else tensors)

    def load_tensors(self, tensors):
        t = tf.check_weights(tensors)
        with torch.no_grad():
            if self.fcj is not None and tf.has_jitter(t):
                self.fcj.weight.copy_(torch.from_numpy(t[tf.JITTER_KEY]))
            for name in tf.LAYER_NAMES:
                getattr(self, name).weight.copy_(torch.from_numpy(t[f"{name}.weight"]))
                getattr(self, name).bias.copy_(torch.from_numpy(t[f"{name}.bias"]))

    def tensors(self) -> dict:
        return {k: v.detach().cpu().numpy().astype(np.float32).copy()
                for k, v in self.state_dict().items()}

    # -- the frame step --------------------------------------------------------------------
    def inputs(self, color_pq, feat):
        """The transformed inputs [N, 3, h, w, 50] and the beauty means [N, 3, h, w, 1]."""
        n, c, h, w = color_pq.shape
        taps = F.unfold(F.pad(color_pq.reshape(n * c, 1, h, w), (2, 2, 2, 2), mode="replicate"),
                        tf.TAPS)                                   # [n*3, 25, h*w]
        taps = taps.reshape(n, c, tf.TAPS ** 2, h, w).permute(0, 1, 3, 4, 2)
        m = taps.mean(-1, keepdim=True)
        xb = tf.ramp(taps - m)
        if self.feature and feat is not None:
            p = 4 - self.s
            ft = F.unfold(F.pad(feat, (1, p, 1, p), mode="replicate"), tf.TAPS, stride=self.s)
            ft = ft.reshape(n, 1, tf.TAPS ** 2, h, w).permute(0, 1, 3, 4, 2)
            xf = tf.ramp(ft - ft.mean(-1, keepdim=True)).expand(n, c, h, w, tf.TAPS ** 2)
        else:
            xf = torch.zeros_like(xb)
        return torch.cat([xb, xf], -1), m

    def blocks(self, color_pq, feat, jitter=None):
        """[N, 3, h, w, B*B]: each render pixel's output block, PQ domain (jitter [N, 2]:
        each frame's, for the jitter input)."""
        x, m = self.inputs(color_pq, feat)
        y = self.fc1(x)
        if self.fcj is not None:
            j = torch.zeros(x.shape[0], 2, dtype=x.dtype) if jitter is None else jitter
            y = y + self.fcj(j.to(x.dtype))[:, None, None, None, :]
        y = F.leaky_relu(y, tf.LEAKY_ALPHA)
        y = F.leaky_relu(self.fc2(y), tf.LEAKY_ALPHA)
        y = self.fc3(y)[..., :self.b * self.b]
        return m + tf.ramp_inv(y)

    def fold(self, blk):
        """[N, 3, h, w, B*B] -> [N, 3, H, W]: the mean of the blocks covering each pixel."""
        n, c, h, w, bb = blk.shape
        s, b = self.s, self.b
        H, W = s * h, s * w
        cols = blk.reshape(n * c, h * w, bb).transpose(1, 2)
        sums = F.fold(cols, (H + 2, W + 2), b, stride=s)[..., 1:H + 1, 1:W + 1]
        ones = torch.ones(1, bb, h * w, dtype=blk.dtype)
        counts = F.fold(ones, (H + 2, W + 2), b, stride=s)[..., 1:H + 1, 1:W + 1]
        return (sums / counts).reshape(n, c, H, W)

    def forward(self, color_pq, feat=None, jitter=None):
        return self.fold(self.blocks(color_pq, feat, jitter))


def upscale(net: MlpNet, color, depth_hr=None, jitter=(0.0, 0.0), nits=PQ_NITS) -> np.ndarray:
    """One frame as the engine's step: color [h, w, 3] linear (+ depth_hr [H, W], the
    frame's jitter) -> [H, W, 3] linear."""
    x = torch.from_numpy(pq_encode(color, nits).transpose(2, 0, 1)[None].copy())
    f = None
    if net.feature:
        f = torch.from_numpy(np.asarray(depth_hr, np.float32)[None, None].copy())
    with torch.no_grad():
        j = torch.tensor(np.asarray(jitter, np.float32).reshape(1, 2))
        y = net(x, f, j)[0].clamp(0, 1).numpy().transpose(1, 2, 0)
    return pq_decode(y, nits)
