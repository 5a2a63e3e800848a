"""The shader MLP upscaler's online training kernels (mlp_train.cl, beside this file):
forward with the activations kept, the L1 loss's residual on the folded output, backward,
the weight gradients per layer and torch's Adam update, fp32, on the packed weights the
frame step reads (mlp_upscale.py). Buffers and batch layout: TrainBuffers; the driver:
online.py."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ...device import Device
from .mlp_upscale import WEIGHT_COUNT

KERNEL = Path(__file__).with_name("mlp_train.cl")
WG = 64


def _round_up(n, m):
    return -(-int(n) // m) * m


class TrainBuffers:
    """The device buffers of one batch of `patches` patches (fp32, feature-major)."""

    def __init__(self, dev: Device, patches: int, scale: int, block: int, patch: int, margin: int):
        self.P, self.s, self.b = int(patches), int(scale), int(block)
        self.patch, self.margin = int(patch), int(margin)
        c = patch + 2 * margin
        r = patch + 2
        L = scale * patch
        self.N = self.P * 3 * r * r
        self.loss_count = self.P * 3 * L * L
        N, bb = self.N, block * block
        e = lambda *shape: dev.empty(shape, "fp32")   # noqa: E731
        self.col, self.feat, self.ref = e(self.P, 3, c, c), e(self.P, scale * c, scale * c), \
            e(self.P, 3, L, L)
        self.X, self.H1, self.H2 = e(50, N), e(50, N), e(50, N)
        self.Y, self.BLK, self.diff = e(bb, N), e(bb, N), e(self.P, 3, L, L)
        self.D1, self.D2, self.D3 = e(50, N), e(50, N), e(bb, N)
        self.G = e(WEIGHT_COUNT)

    def nbytes(self) -> int:
        return sum(int(getattr(self, k).nbytes) for k in
                   ("col", "feat", "ref", "X", "H1", "H2", "Y", "BLK", "diff", "D1", "D2",
                    "D3", "G"))


def defines(base: dict, patch: int, margin: int) -> dict:
    d = {k: v for k, v in base.items() if not k.startswith("PQ_")}
    d.update(PATCH=int(patch), MARGIN=int(margin))
    return d


def forward_backward(dev: Device, tb: TrainBuffers, weights, defs: dict):
    """forward, loss residual (tb.diff), backward and the weight gradients (tb.G)."""
    N = np.int32(tb.N)
    k = lambda name: dev.kernel(KERNEL, name, "fp32", **defs)  # noqa: E731
    dev.launch(k("mlp_train_forward"), (_round_up(tb.N, WG),),
               (tb.col.data, tb.feat.data, weights.data, tb.X.data, tb.H1.data, tb.H2.data,
                tb.Y.data, tb.BLK.data, N), local_size=(WG,))
    dev.launch(k("mlp_train_loss"), (_round_up(tb.loss_count, WG),),
               (tb.BLK.data, tb.ref.data, tb.diff.data, N), local_size=(WG,))
    dev.launch(k("mlp_train_backward"), (_round_up(tb.N, WG),),
               (weights.data, tb.H1.data, tb.H2.data, tb.Y.data, tb.diff.data, tb.D1.data,
                tb.D2.data, tb.D3.data, N, np.float32(1.0 / tb.loss_count)), local_size=(WG,))
    bb = tb.b * tb.b
    off = 0
    for D, IN, ci, co, used in ((tb.D1, tb.X, 50, 50, 50), (tb.D2, tb.H1, 50, 50, 50),
                                (tb.D3, tb.H2, 50, 25, bb)):
        # D3 holds only the block's bb rows: rows >= bb are never read (co_used)
        dev.launch(k("mlp_train_wgrad"), (ci + 1, co),
                   (D.data, IN.data, tb.G.data, N, np.int32(ci), np.int32(co),
                    np.int32(used), np.int32(off)))
        off += co * ci + co
    return tb.G


def adam(dev: Device, weights, grad, m, v, step: int, lr: float, betas=(0.9, 0.999),
         eps=1e-8):
    """One torch.optim.Adam step (step counts from 1) in place on `weights`."""
    b1, b2 = betas
    bc1 = 1.0 - b1 ** step
    bc2 = 1.0 - b2 ** step
    kern = dev.kernel(KERNEL, "mlp_train_adam", "fp32")
    dev.launch(kern, (_round_up(WEIGHT_COUNT, WG),),
               (weights.data, grad.data, m.data, v.data, np.int32(WEIGHT_COUNT),
                np.float32(lr), np.float32(b1), np.float32(b2), np.float32(eps),
                np.float32(bc1), np.float32(np.sqrt(bc2))), local_size=(WG,))
