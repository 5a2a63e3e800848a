"""The torch twin of the NSRR frame step (clss/methods/nsrr/): the same networks under the
same weight names (fe.*, rw.*, un.*), the same zero-upsampling, motion upsampling,
accumulative warp and reset fills, differentiable, batched. tests/test_nsrr_torch.py
holds it to the OpenCL step over frames with a reset; weights_tools/methods/nsrr/recipe.py
trains it and writes the .safetensors file the OpenCL step loads.

Tensors are NCHW float32 in the step's internal domain: rgbd = PQ colour + reversed-Z
depth, motion in render pixels, the history [N, 12*n_prev, H, W].

With config "base": "rules" (networks.BASES) the residual's base is the clss-rules
method's PQ output for the frame. The rules have no learned parameters, so the twin takes
it as data (`rules=`, [N, 3, H, W]): `rules_outputs` (weights_tools/rules_base.py) runs the
shipped clss-rules frame step (OpenCL) over a sequence, and the recipe caches that beside
the data.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from clss.methods.nsrr import networks as nets
from clss.methods.nsrr.frame import pad4
from clss.methods.nsrr.oracle import depth_taps, zu_index
from clss.pipeline.twin import base_grid
from clss.pipeline.contract import PQ_NITS, output_size

from weights_tools.rules_base import rules_outputs  # noqa: F401 (also this module's API)
from weights_tools.trainloop import pq_decode, pq_encode  # noqa: F401 (also this module's API)

FEAT = nets.FEAT


def _convs(shapes, names):
    return nn.ModuleList(nn.Conv2d(shapes[n][1], shapes[n][0], 3, padding=1) for n in names)


class NsrrNet(nn.Module):
    """The three networks; `state_dict()` keys are the .safetensors names."""

    def __init__(self, cfg, weights: dict | None = None):
        super().__init__()
        self.cfg = dict(cfg)
        self.n_prev = int(cfg["n_prev"])
        op, alpha = nets.act_of(cfg)
        self.act = (lambda x: F.leaky_relu(x, alpha)) if op == "LeakyRelu" else F.relu
        s = nets.layer_shapes(cfg)
        self.fe = _convs(s, [f"fe.{i}" for i in range(3)])
        self.rw = _convs(s, [f"rw.{i}" for i in range(3)])
        self.un = _convs(s, [f"un.{i}" for i in range(10)])
        w = weights if weights is not None else nets.init_weights(cfg)
        self.load_state_dict({k: torch.from_numpy(np.asarray(v, np.float32)) for k, v in w.items()})

    def numpy_weights(self) -> dict:
        return {k: v.detach().cpu().numpy().astype(np.float32) for k, v in self.state_dict().items()}

    # -- the networks -----------------------------------------------------------------
    def features(self, rgbd):
        y = rgbd
        for c in self.fe:
            y = self.act(c(y))
        return torch.cat([rgbd, y], 1)

    def reconstruct(self, stack, base=None):
        """stack [N, 12(n+1), Hp, Wp] (padded to 4) -> PQ colour [N, 3, Hp, Wp]; base
        [N, 3, Hp, Wp]: the rules' base, an input too with "base": "rules"."""
        n = self.n_prev
        rgbd = torch.cat([stack[:, FEAT * k:FEAT * k + 4] for k in range(n + 1)], 1)
        act = self.act
        r = act(self.rw[0](rgbd))
        r = act(self.rw[1](r))
        r = (torch.tanh(self.rw[2](r)) + 1.0) * (nets.WEIGHT_SCALE / 2)
        parts = [stack[:, FEAT * k:FEAT * (k + 1)] * r[:, k - 1:k] for k in range(1, n + 1)]
        x = torch.cat([stack[:, :FEAT]] + parts + ([base] if nets.rules_base(self.cfg) else []), 1)
        u = self.un

        def two(x, a, b):
            return act(u[b](act(u[a](x))))
        e1 = two(x, 0, 1)
        e2 = two(F.max_pool2d(e1, 2), 2, 3)
        b = two(F.max_pool2d(e2, 2), 4, 5)
        d2 = two(torch.cat([F.interpolate(b, scale_factor=2, mode="nearest"), e2], 1), 6, 7)
        d1 = act(u[8](torch.cat([F.interpolate(d2, scale_factor=2, mode="nearest"), e1], 1)))
        return u[9](d1)


def zero_upsample(feat, H, W, jitters):
    """feat [N,C,h,w], jitters [(jx, jy)] per item -> [N,C,H,W], each sample where its
    jitter puts it (as clss/methods/nsrr/nsrr.cl; index maps from the oracle's zu_index)."""
    N, C, h, w = feat.shape
    out = []
    for i in range(N):
        jx, jy = (float(v) for v in jitters[i])
        ix = torch.from_numpy(zu_index(w, W / w, jx, W)).to(feat.device)
        iy = torch.from_numpy(zu_index(h, H / h, jy, H)).to(feat.device)
        f = F.pad(feat[i:i + 1], (0, 1, 0, 1))          # a zero column and row at index w, h
        out.append(f.index_select(3, ix).index_select(2, iy))
    return torch.cat(out, 0)


def upsample_motion(motion, H, W):
    """[N,2,h,w] render pixels -> [N,2,H,W] output pixels (bilinear, half-pixel, clamped)."""
    h, w = motion.shape[2:]
    m = F.interpolate(motion, size=(H, W), mode="bilinear", align_corners=False)
    return m * torch.tensor([W / w, H / h], dtype=m.dtype, device=m.device).view(1, 2, 1, 1)


def warp(x, m):
    """Backward warp of x [N,C,H,W] by output-pixel motion m [N,2,H,W]: bilinear, zeros
    outside (GridSample, align_corners=0)."""
    N, _, H, W = x.shape
    xs = torch.arange(W, dtype=x.dtype, device=x.device).view(1, 1, W) + m[:, 0]
    ys = torch.arange(H, dtype=x.dtype, device=x.device).view(1, H, 1) + m[:, 1]
    grid = torch.stack([(2 * xs + 1) / W - 1, (2 * ys + 1) / H - 1], -1)
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=False)


def depth_keep(depth, pdepth, m, jitters, tau):
    """[N,1,H,W] 1 where the history is kept, 0 where the depth rejection empties it
    (networks.REJECTS): depth, pdepth [N,1,h,w] the current and previous reversed-Z depth,
    m [N,2,H,W] the output-pixel motion (upsample_motion), tau networks.REJECT_TAU. The
    current range is the 2x2 render samples around each output pixel centre (jitter-aware,
    as the base), the previous one the 2x2 around where the pixel was (xs + 0.5) / sx - 0.5,
    clamped; the ranges may not lie apart by more than tau x the larger depth (nsrr.cl)."""
    N, _, h, w = depth.shape
    H, W = m.shape[2:]
    sx, sy = W / w, H / h
    flat, pflat = depth.reshape(N, h * w), pdepth.reshape(N, h * w)
    out = []
    for i in range(N):
        jx, jy = (float(v) for v in jitters[i])
        bx0, bx1 = (torch.from_numpy(a) for a in depth_taps(w, sx, jx, W))
        by0, by1 = (torch.from_numpy(a) for a in depth_taps(h, sy, jy, H))
        taps = [flat[i][(r.view(H, 1) * w + c.view(1, W)).reshape(-1)].view(H, W)
                for r in (by0, by1) for c in (bx0, bx1)]
        cmin = torch.minimum(torch.minimum(taps[0], taps[1]), torch.minimum(taps[2], taps[3]))
        cmax = torch.maximum(torch.maximum(taps[0], taps[1]), torch.maximum(taps[2], taps[3]))
        xs = torch.arange(W, dtype=m.dtype, device=m.device).view(1, W) + m[i, 0]
        ys = torch.arange(H, dtype=m.dtype, device=m.device).view(H, 1) + m[i, 1]
        u = ((xs + 0.5) / sx - 0.5).clamp(0, w - 1)
        v = ((ys + 0.5) / sy - 0.5).clamp(0, h - 1)
        u0, v0 = u.floor().long(), v.floor().long()
        u1, v1 = (u0 + 1).clamp(max=w - 1), (v0 + 1).clamp(max=h - 1)
        pt = [pflat[i][r * w + c] for r in (v0, v1) for c in (u0, u1)]
        pmin = torch.minimum(torch.minimum(pt[0], pt[1]), torch.minimum(pt[2], pt[3]))
        pmax = torch.maximum(torch.maximum(pt[0], pt[1]), torch.maximum(pt[2], pt[3]))
        gap = torch.maximum(cmin, pmin) - torch.minimum(cmax, pmax)
        out.append((gap <= torch.maximum(cmax, pmax) * tau).to(m.dtype))
    return torch.stack(out)[:, None]


def rgbd_of(color, depth, nits=PQ_NITS):
    """color [N,3,h,w] linear, depth [N,1,h,w] reversed-Z -> rgbd [N,4,h,w]."""
    return torch.cat([pq_encode(color, nits), depth], 1)


class TorchStep:
    """The frame step, batched: `step(rgbd, motion, jitters, reset)` -> (PQ output
    [N,3,H,W], next history). reset: a bool tensor [N] (per item)."""

    def __init__(self, net: NsrrNet, scale, reset_fill="zero", history=None):
        self.net, self.scale, self.reset_fill = net, float(scale), reset_fill
        self.n = net.n_prev
        self.history = self.n if history is None else int(history)

    def reproject(self, feat, motion, jitters, hist, reset, pdepth=None):
        """pdepth [N,1,h,w]: the previous frame's reversed-Z depth (the depth rejection's;
        None: no rejection, as on a reset)."""
        N, _, h, w = feat.shape
        H, W = output_size(h, w, self.scale)
        z = zero_upsample(feat, H, W, jitters)
        if hist is None:
            hist = z.new_zeros(N, FEAT * self.n, H, W)
        m = upsample_motion(motion, H, W)
        warped = warp(hist, m)
        tau = nets.reject_tau(self.net.cfg)
        if tau >= 0 and pdepth is not None:
            warped = warped * depth_keep(feat[:, 3:4], pdepth, m, jitters, tau)
        keep = (~reset).to(z.dtype).view(N, 1, 1, 1)
        prev = warped * keep
        if self.reset_fill == "duplicate":
            prev = prev + z.repeat(1, self.n, 1, 1) * (1 - keep)
        if self.history < self.n:
            mask = torch.zeros(1, FEAT * self.n, 1, 1, dtype=z.dtype, device=z.device)
            mask[:, :FEAT * self.history] = 1
            prev = prev * mask
        return torch.cat([z, prev], 1)

    def output(self, stack, base=None):
        H, W = stack.shape[2:]
        pad = (0, pad4(W) - W, 0, pad4(H) - H)
        fed = F.pad(base, pad) if base is not None and nets.rules_base(self.net.cfg) else None
        y = self.net.reconstruct(F.pad(stack, pad), fed)[:, :, :H, :W]
        return y + base if base is not None else y

    def base(self, rgbd, jitters, rules=None):
        """The residual base (None without it): PQ colour bilinear at the output pixel
        centres, each item's jitter applied, edge-clamped; with "base": "rules", `rules`
        (the clss-rules output, PQ [N,3,H,W], given as data)."""
        if not self.net.cfg.get("residual", False):
            return None
        if nets.rules_base(self.net.cfg):
            if rules is None:
                raise ValueError("NSRR with base 'rules': the step needs the rules' output (rules=)")
            return rules
        N, _, h, w = rgbd.shape
        H, W = output_size(h, w, self.scale)
        grids = [torch.from_numpy(base_grid((h, w), (H, W), j)) for j in jitters]
        return F.grid_sample(rgbd[:, :3], torch.cat(grids).to(rgbd), mode="bilinear",
                             padding_mode="border", align_corners=False)

    def step(self, rgbd, motion, jitters, hist, reset, pdepth=None, rules=None):
        """pdepth: the previous frame's rgbd[:, 3:4] (the depth rejection's); rules: the
        clss-rules output of this frame (PQ [N,3,H,W]; "base": "rules")."""
        stack = self.reproject(self.net.features(rgbd), motion, jitters, hist, reset, pdepth)
        return self.output(stack, self.base(rgbd, jitters, rules)), stack[:, :FEAT * self.n]
