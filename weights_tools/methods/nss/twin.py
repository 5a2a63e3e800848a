"""The torch twin of the NSS frame step (clss/methods/nss/): the same network under the
same weight names, the same depth reprojection and disocclusion, warps, luma derivative,
kernel-prediction filter, Catmull-Rom history, clamp and tonemapped accumulation,
differentiable (except the depth reprojection) and batched. tests/test_nss_torch.py
holds it to the OpenCL step; weights_tools/methods/nss/recipe.py trains it.

Tensors are NCHW float32: colour linear (/ exposure), depth reversed-Z, motion in render
pixels (previous = p + motion). The state between frames is a dict: "hist" [N,3,H,W]
(the previous output, linear), "deriv" [N,2,h,w], "tp" [N,4,hp,wp]; None = a fresh
sequence. The jitter-aware tap layout is the ONNX twin's (oracle.tap_feeds).

With config "base": "rules" (networks.BASES) the step takes the clss-rules output of the
frame as data (`rules=`, [N,3,H,W] linear / exposure: the rules have no learned
parameters; the recipe precomputes them with the OpenCL clss-rules step,
weights_tools/rules_base.py) and returns rules + clamp(mix, 0, 1) (nss - rules).
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from clss.methods.nss import networks as nets
from clss.methods.nss.oracle import tap_feeds
from clss.pipeline.twin import base_grid


class NssNet(nn.Module):
    """The network of networks.build_network; `state_dict()` keys are the weight names."""

    def __init__(self, cfg, weights: dict | None = None):
        super().__init__()
        self.cfg = dict(cfg)
        self.convs = nn.ModuleDict()
        for name, (co, ci, k) in nets.layer_shapes(cfg).items():
            self.convs[name] = nn.Conv2d(ci, co, k, padding=k // 2,
                                         stride=2 if name in nets.STRIDE2 else 1)
        w = weights if weights is not None else nets.init_weights(cfg)
        self.load_state_dict({k: torch.from_numpy(np.asarray(v, np.float32)) for k, v in w.items()})

    def state_dict(self, *a, **kw):
        sd = super().state_dict(*a, **kw)
        return type(sd)((k[len("convs."):], v) for k, v in sd.items())

    def load_state_dict(self, sd, strict=True):
        return super().load_state_dict({f"convs.{k}": v for k, v in sd.items()}, strict=strict)

    def numpy_weights(self) -> dict:
        return {k: v.detach().cpu().numpy().astype(np.float32) for k, v in self.state_dict().items()}

    def forward(self, x):
        c = lambda n, v: F.relu(self.convs[n](v))  # noqa: E731
        up = lambda v: F.interpolate(v, scale_factor=2, mode="nearest")  # noqa: E731
        a = c("e1", c("e0", x))
        b = c("e3", c("e2", a))
        y = c("e6", c("e5", c("e4", b)))
        y = c("d1", torch.cat([c("d0", up(y)), b], 1))
        kpn = torch.sigmoid(self.convs["kpn"](y))
        y = c("d3", torch.cat([c("d2", up(y)), a], 1))
        y = up(c("d4", y))
        mix = self.convs["mix"](y) if "mix" in self.convs else None
        return kpn, torch.sigmoid(self.convs["tp"](y)), mix


def _sample(x, xs, ys, padding="zeros"):
    """x [N,C,h,w] bilinear at index coordinates xs, ys [N,1,h',w'] (GridSample
    align_corners=0), as nss.cl's warp_taps (zeros) or its edge clamp (border)."""
    h, w = x.shape[2:]
    grid = torch.cat([(2 * xs + 1) / w - 1, (2 * ys + 1) / h - 1], 1).permute(0, 2, 3, 1)
    return F.grid_sample(x, grid, mode="bilinear", padding_mode=padding, align_corners=False)


def karis(x):
    return x / (1.0 + x.amax(1, keepdim=True))


def scatter_depth(d, xs, ys):
    """kernels/scatter.cl's scatter_depth: the max reversed-Z depth reaching each pixel of
    the previous frame (0 = far where none does). No gradient."""
    N, _, h, w = d.shape
    with torch.no_grad():
        bx, by = torch.floor(xs), torch.floor(ys)
        fx, fy = xs - bx, ys - by
        out = d.new_zeros(N, h * w + 1)
        for b in (0, 1):
            for a in (0, 1):
                tx, ty = bx + a, by + b
                wk = (fx if a else 1 - fx) * (fy if b else 1 - fy)
                ok = (wk > nets.SCATTER_WMIN) & (tx >= 0) & (tx < w) & (ty >= 0) & (ty < h)
                lin = ty.clamp(0, h - 1).long() * w + tx.clamp(0, w - 1).long()
                idx = torch.where(ok, lin, torch.full_like(lin, h * w)).view(N, -1)
                out = out.scatter_reduce(1, idx, d.reshape(N, -1), reduce="amax")
        return out[:, :h * w].view(N, 1, h, w)


def catmull_rom(f):
    f2, f3 = f * f, f * f * f
    return [-0.5 * f3 + f2 - 0.5 * f, 1.5 * f3 - 2.5 * f2 + 1.0,
            -1.5 * f3 + 2.0 * f2 + 0.5 * f, 0.5 * f3 - 0.5 * f2]


class TorchStep:
    """The frame step, batched. `step(...)` -> (output [N,3,H,W] linear, next state)."""

    def __init__(self, net: NssNet):
        self.net, self.cfg = net, net.cfg
        self._taps = {}

    def taps(self, render_size, jitters, device):
        feeds = [tap_feeds(self.cfg, render_size, j) for j in jitters]
        return {k: torch.from_numpy(np.stack([f[k] for f in feeds])).to(device)
                for k in feeds[0]}

    def step(self, color, depth, motion, jitters, st, reset, rules=None):
        """reset: bool tensor [N]. st: the state dict or None. rules: the clss-rules output
        of this frame ([N,3,H,W] linear / exposure; "base": "rules" only)."""
        N, _, h, w = color.shape
        H, W, hp, wp = 2 * h, 2 * w, nets.pad8(h), nets.pad8(w)
        K = int(self.cfg["kpn"])
        dev = color.device
        st = st or {}
        keep = (~reset).to(color.dtype).view(N, 1, 1, 1)
        hist = st.get("hist", color.new_zeros(N, 3, H, W))
        deriv = st.get("deriv", color.new_zeros(N, 2, h, w))
        tp_prev = st.get("tp", color.new_zeros(N, nets.TEMPORAL, hp, wp))
        col = color.clamp(0.0, nets.COLOR_MAX)
        mx, my = motion[:, 0:1], motion[:, 1:2]
        xs = torch.arange(w, dtype=color.dtype, device=dev).view(1, 1, 1, w) + mx
        ys = torch.arange(h, dtype=color.dtype, device=dev).view(1, 1, h, 1) + my
        recon = scatter_depth(depth, xs, ys)
        dr = _sample(recon, xs, ys)
        rel = (dr - depth).clamp_min(0.0) / (nets.DEPTH_TOL * torch.maximum(depth, dr) + nets.DEPTH_FLOOR)
        ins = ((xs >= -0.5) & (xs <= w - 0.5) & (ys >= -0.5) & (ys <= h - 0.5)).to(color.dtype)
        dis = 1.0 - (1.0 - (rel - 1.0).clamp(0.0, 1.0)) * ins * keep
        hx = (2 * torch.arange(w, dtype=color.dtype, device=dev) + 0.5).view(1, 1, 1, w) + 2.0 * mx
        hy = (2 * torch.arange(h, dtype=color.dtype, device=dev) + 0.5).view(1, 1, h, 1) + 2.0 * my
        hc = karis(_sample(hist, hx, hy) * keep)
        cc = karis(col)
        fb = _sample(tp_prev[:, :, :h, :w], xs, ys) * keep * (1.0 - dis)
        s = _sample(deriv, xs, ys) * keep
        dp, lp = s[:, 0:1], s[:, 1:2]
        luma = (cc * torch.tensor(nets.LUMA, dtype=color.dtype, device=dev).view(1, 3, 1, 1)).sum(1, keepdim=True)
        tt = (((luma - lp).abs() - nets.D_MIN) / (nets.D_MAX - nets.D_MIN)).clamp(0.0, 1.0)
        rate = nets.D_ALPHA * (1.0 - 0.9 * torch.clamp(dp / nets.D_MAX, max=1.0))
        der = (dp + rate * (tt * torch.sqrt(tt) - dp)) * (1.0 - dis)
        parts = [hc, cc, dis, fb, der]
        rb = nets.rules_base(self.cfg)
        if rb:
            if rules is None:
                raise ValueError("NSS with base 'rules': the step needs the rules' output (rules=)")
            parts.append(karis(F.avg_pool2d(rules, 2)))
        x = torch.cat(parts, 1)
        x = F.pad(x, (0, wp - w, 0, hp - h), mode="replicate")
        kpn, tp, mix = self.net(x)
        # the kernel-prediction filter
        t = self.taps((h, w), jitters, dev)
        cflat = col.reshape(N, 3, h * w)
        taps = torch.gather(cflat, 2, t["taps"].view(N, 1, -1).expand(N, 3, -1)).view(N, 3, K * K, H, W)
        kq = t["kq"].view(N, 1, -1).expand(N, K * K, -1)
        kw = torch.gather(kpn.reshape(N, K * K, -1), 2, kq).view(N, 1, K * K, H, W)
        kw = kw.clamp_min(nets.KPN_EPS) * t["tent"].view(N, 1, K * K, H, W)
        ws = kw.sum(2)
        m1 = (kw * taps).sum(2) / ws
        m2 = (kw * taps * taps).sum(2) / ws
        # temporal parameters at the output pixels
        g = torch.from_numpy(base_grid((h, w), (H, W), (0.0, 0.0))).to(dev).expand(N, -1, -1, -1)
        pr = F.grid_sample(tp[:, :, :h, :w], g, mode="bilinear", padding_mode="border",
                           align_corners=False)
        p0 = pr[:, 0:1]
        ta, tb = p0 * p0, (1.0 - p0) * (1.0 - p0)
        theta = ta / torch.clamp(ta + tb, min=1e-6)
        alpha = nets.ALPHA_RANGE[0] + (nets.ALPHA_RANGE[1] - nets.ALPHA_RANGE[0]) * pr[:, 1:2]
        gamma = nets.GAMMA_SCALE * pr[:, 2:3]
        # the previous output, Catmull-Rom
        mu = F.interpolate(motion, scale_factor=2, mode="nearest")
        Hx = torch.arange(W, dtype=color.dtype, device=dev).view(1, 1, 1, W) + 2.0 * mu[:, 0:1]
        Hy = torch.arange(H, dtype=color.dtype, device=dev).view(1, 1, H, 1) + 2.0 * mu[:, 1:2]
        ons = ((Hx >= -0.5) & (Hx <= W - 0.5) & (Hy >= -0.5) & (Hy <= H - 0.5)).to(color.dtype)
        fhx, fhy = torch.floor(Hx), torch.floor(Hy)
        wxs, wys = catmull_rom(Hx - fhx), catmull_rom(Hy - fhy)
        x0 = fhx.clamp(-4.0, W + 4.0).long()
        y0 = fhy.clamp(-4.0, H + 4.0).long()
        hflat = hist.reshape(N, 3, H * W)
        hv = 0.0
        for j in range(4):
            row = (y0 + j - 1).clamp(0, H - 1) * W
            r = 0.0
            for i in range(4):
                idx = (row + (x0 + i - 1).clamp(0, W - 1)).view(N, 1, -1).expand(N, 3, -1)
                r = r + wxs[i] * torch.gather(hflat, 2, idx).view(N, 3, H, W)
            hv = hv + wys[j] * r
        wh = hv.clamp(0.0, nets.COLOR_MAX)
        sg = torch.sqrt(torch.clamp((m2 - m1 * m1).abs(), min=nets.CLAMP_EPS)) * gamma
        hcl = m1 + (torch.minimum(torch.maximum(wh, m1 - sg), m1 + sg) - m1) * keep
        rect = hcl + (wh - hcl) * (theta * ons * keep)
        cen = torch.gather(cflat, 2, t["centre"].view(N, 1, -1).expand(N, 3, -1)).view(N, 3, H, W)
        rt, ct = karis(rect), karis(cen)
        ak = alpha * t["valid"].view(N, 1, H, W) * keep
        acc = (rt + (ct - rt) * ak).clamp(0.0, nets.TM_MAX)
        out = acc / (1.0 - acc.amax(1, keepdim=True))
        if rb:
            m = F.grid_sample(mix[:, :, :h, :w], g, mode="bilinear", padding_mode="border",
                              align_corners=False)
            m = m.clamp(0.0, 1.0)
            out = rules + m * (out - rules)
        # "filtered": the kernel filter's output (the model gym's out_filtered, a loss term)
        st = {"hist": out, "deriv": torch.cat([der, luma], 1), "tp": tp, "filtered": m1}
        if rb:
            st["mix"] = m           # [N,1,H,W] the clamped mix (the recipe's --mix-l1)
        return out, st
