"""Training patches of the shader MLP upscaler, accepted by gradient: written once for the
offline recipe (weights_tools/methods/mlp/recipe.py) and the online training on the device
(online.py), numpy only.

A patch is PATCH x PATCH render pixels of loss with MARGIN render pixels around them (2 for
the 5x5 taps, 1 for the blocks that overlap the loss region), so that a crop computes
exactly what the whole frame computes there. A candidate (a random frame and place) is
accepted with probability min(1, max(P_MIN, g / g_ref)), g the mean gradient magnitude of
its reference (PQ, the mean of the channels; |d/dx| + |d/dy|) over the loss region and
g_ref the ACCEPT_QUANTILE quantile of g over PROBES candidates (the seed: "the larger the
gradient, the more likely the patch is to be accepted"); rejected ones are drawn again.
"""
from __future__ import annotations

import numpy as np

PATCH = 16            # render pixels of loss per patch side
MARGIN = 3            # render pixels around it: 2 for the 5x5 taps, 1 for the overlap
ACCEPT_QUANTILE = 0.75
P_MIN = 0.1
PROBES = 2000


def crop_size() -> int:
    return PATCH + 2 * MARGIN


def gradient_integral(ref_pq) -> np.ndarray:
    """The integral image of the reference's gradient magnitude: ref_pq [..., H, W, 3]
    (PQ) -> [..., H+1, W+1] float64."""
    lum = np.asarray(ref_pq, np.float32).mean(-1)
    g = np.zeros_like(lum)
    g[..., :, 1:] += np.abs(lum[..., :, 1:] - lum[..., :, :-1])
    g[..., 1:, :] += np.abs(lum[..., 1:, :] - lum[..., :-1, :])
    c = g.astype(np.float64).cumsum(-2).cumsum(-1)
    pad = [(0, 0)] * (c.ndim - 2) + [(1, 0), (1, 0)]
    return np.pad(c, pad)


def patch_gradient(integ, i0, j0, s) -> float:
    """Mean gradient magnitude over the loss region of the patch at render (i0, j0)
    (integ: one frame's gradient_integral)."""
    y0, x0 = s * (i0 + MARGIN), s * (j0 + MARGIN)
    y1, x1 = y0 + s * PATCH, x0 + s * PATCH
    return float(integ[y1, x1] - integ[y0, x1] - integ[y1, x0] + integ[y0, x0]) / (s * PATCH) ** 2


def accept_probability(g, g_ref) -> float:
    return min(1.0, max(P_MIN, g / g_ref))


class Sampler:
    """Accepted patches over sequences. sizes[k]: render (h, w) of sequence k;
    frames[k]: its (first, end) frame range; integ(k, t): frame t's gradient_integral."""

    def __init__(self, sizes, frames, integ, scale, seed=0, rng=None):
        self.sizes, self.frames, self.integ, self.s = sizes, frames, integ, int(scale)
        self.g = rng if rng is not None else np.random.default_rng(seed)
        if any(min(hw) < crop_size() for hw in sizes):
            raise ValueError(f"frames smaller than {crop_size()} render pixels "
                             f"(a training patch and its margin)")
        probe = [patch_gradient(self.integ(k, t), i0, j0, self.s)
                 for k, t, i0, j0 in (self.candidate() for _ in range(PROBES))]
        self.g_ref = max(float(np.quantile(probe, ACCEPT_QUANTILE)), 1e-6)
        self.tried = self.accepted = 0

    def candidate(self):
        """(sequence, frame, i0, j0): the crop's top-left render pixel."""
        k = int(self.g.integers(len(self.sizes)))
        lo, hi = self.frames[k]
        t = int(self.g.integers(lo, hi))
        h, w = self.sizes[k]
        size = crop_size()
        return k, t, int(self.g.integers(0, h - size + 1)), int(self.g.integers(0, w - size + 1))

    def draw(self):
        """One accepted candidate."""
        while True:
            k, t, i0, j0 = self.candidate()
            self.tried += 1
            p = accept_probability(patch_gradient(self.integ(k, t), i0, j0, self.s), self.g_ref)
            if self.g.random() < p:
                self.accepted += 1
                return k, t, i0, j0
