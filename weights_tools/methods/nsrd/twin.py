"""The torch twin of the NSRD frame step (clss/methods/nsrd/): the same network under the
same weight names, the same demodulation, depth-test mask, accumulative warps, sub-pixel
output and re-modulation, differentiable and batched. tests/test_nsrd_torch.py holds it
to the OpenCL step over frames with a reset; weights_tools/methods/nsrd/recipe.py
trains it.

Tensors are NCHW float32: colour linear (/ exposure), depth reversed-Z, motion in render
pixels (previous = p + motion), G-buffers as the contract's. The state between frames is
a dict: "state" [N,8,h,w] (render-res history: lighting PQ, mask, warped lighting of the
frame before, depth), "hist" [N,3,H,W] (the previous output's lighting, PQ), "h", "c"
[N,hid,hp,wp] (ConvLSTM); None = a fresh sequence.

With config "out_base": "rules" (networks.OUT_BASES) the step takes the clss-rules output
of the frame as data (`rules=`, [N,3,H,W] PQ colour, clss-rules' history channels 0-2 at
this step's nits: the rules have no learned parameters; the recipe precomputes them with
the OpenCL clss-rules step, weights_tools/rules_base.py), feeds it to the network beside the
previous output and returns rules + clamp(mix, 0, 1) (nsrd - rules), linear.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from clss.methods.nsrd import networks as nets
from clss.pipeline.contract import PQ_NITS

from weights_tools.trainloop import pq_decode, pq_encode  # noqa: F401 (also this module's API)


class NsrdNet(nn.Module):
    """The network of networks.build_network; `state_dict()` keys are the weight names."""

    def __init__(self, cfg, weights: dict | None = None):
        super().__init__()
        self.cfg = dict(cfg)
        self.convs = nn.ModuleDict()
        for name, (co, ci, k) in nets.layer_shapes(cfg).items():
            self.convs[name.replace(".", "_")] = nn.Conv2d(ci, co, k, padding=k // 2,
                                                           stride=2 if name == "dn" else 1)
        w = weights if weights is not None else nets.init_weights(cfg)
        self.load_state_dict({k: torch.from_numpy(np.asarray(v, np.float32)) for k, v in w.items()})

    # the weight names have dots (ga.f.weight); ModuleDict keys cannot
    def state_dict(self, *a, **kw):
        sd = super().state_dict(*a, **kw)
        return type(sd)((_rname(k), v) for k, v in sd.items())

    def load_state_dict(self, sd, strict=True):
        return super().load_state_dict({_tname(k): v for k, v in sd.items()}, strict=strict)

    def numpy_weights(self) -> dict:
        return {k: v.detach().cpu().numpy().astype(np.float32) for k, v in self.state_dict().items()}

    def c(self, name, x):
        return self.convs[name.replace(".", "_")](x)

    def rcab(self, x, name):
        r = self.c(f"{name}.1", F.leaky_relu(self.c(f"{name}.0", x), nets.ALPHA))
        a = r.mean((2, 3), keepdim=True)
        a = torch.sigmoid(self.c(f"{name}.a1", F.relu(self.c(f"{name}.a0", a))))
        return x + r * a

    def forward(self, cur, warp, prev, h, c):
        x = torch.cat([cur, warp], 1)
        gated = F.leaky_relu(self.c("ga.f", x), nets.ALPHA) * torch.sigmoid(self.c("ga.g", x))
        xt = torch.cat([gated, F.leaky_relu(self.c("pf", prev), nets.ALPHA),
                        F.leaky_relu(self.c("cf", cur), nets.ALPHA), h], 1)
        i, f, o, g = torch.chunk(self.c("lstm", xt), 4, 1)
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
        h = torch.sigmoid(o) * torch.tanh(c)
        d = self.rcab(F.leaky_relu(self.c("dn", h), nets.ALPHA), "r1")
        u = self.rcab(F.pixel_shuffle(self.c("up", d), 2) + h, "r0")
        mix = self.c("mix", u) if nets.rules_base(self.cfg) else None
        return self.c("out", u), h, c, mix


def _tname(k):
    """weight name (ga.f.weight, r1.a0.bias) -> module key (convs.ga_f.weight)."""
    layer, p = k.rsplit(".", 1)
    return f"convs.{layer.replace('.', '_')}.{p}"


def _rname(k):
    layer, p = k[len("convs."):].rsplit(".", 1)
    return f"{layer.replace('_', '.')}.{p}"


def warp(x, m):
    """Backward warp of x [N,C,H,W] by pixel motion m [N,2,H,W]: bilinear, zeros outside
    (GridSample align_corners=0), as the kernels' tap weights."""
    N, _, H, W = x.shape
    xs = torch.arange(W, dtype=x.dtype, device=x.device).view(1, 1, W) + m[:, 0]
    ys = torch.arange(H, dtype=x.dtype, device=x.device).view(1, H, 1) + m[:, 1]
    grid = torch.stack([(2 * xs + 1) / W - 1, (2 * ys + 1) / H - 1], -1)
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=False)


def material(albedo, demod=True):
    if not demod:
        return torch.ones_like(albedo)
    return torch.where(albedo >= nets.DEMOD_EPS, albedo, torch.ones_like(albedo))


def material_hr(albedo_hr, demod=True):
    """The output-resolution material: albedo_hr filtered (networks.MATERIAL_FILTER,
    separable, edge-clamped), then the eps rule."""
    k = torch.tensor(nets.MATERIAL_FILTER, dtype=albedo_hr.dtype, device=albedo_hr.device)
    k2 = (k[:, None] * k[None, :]).view(1, 1, 3, 3).repeat(3, 1, 1, 1)
    a = F.conv2d(F.pad(albedo_hr, (1, 1, 1, 1), mode="replicate"), k2, groups=3)
    return material(a, demod)


def guided_base(L, albedo, albedo_hr, jitters, demod=True):
    """The guided base (networks.BASES): each output pixel's lighting as the tent- and
    material-weighted mean of the 4 x 4 render samples around it (networks.guide_taps)."""
    N, C, h, w = L.shape
    H, W = albedo_hr.shape[2:]
    taps = [nets.guide_taps((h, w), (H, W), j) for j in jitters]
    idx = torch.from_numpy(np.stack([t[0] for t in taps])).to(L.device).view(N, 1, -1)
    tent = torch.from_numpy(np.stack([t[1] for t in taps])).to(L).unsqueeze(1)
    K = tent.shape[2]

    def gather(x):              # [N,C,h,w] -> [N,C,K,H,W]
        return torch.gather(x.flatten(2), 2, idx.expand(-1, x.shape[1], -1)).view(
            N, x.shape[1], K, H, W)
    d2 = ((gather(material(albedo, demod)) - material(albedo_hr, demod).unsqueeze(2)) ** 2
          ).sum(1, keepdim=True)
    wt = tent * (torch.exp(-d2 * (1.0 / nets.GUIDE_SIGMA ** 2)) + nets.GUIDE_FLOOR)
    return (wt * gather(L)).sum(2) / wt.sum(2)


def depth_mask(d, dw):
    rel = (dw - d).abs() / (nets.DEPTH_TOL * torch.maximum(d, dw) + nets.DEPTH_FLOOR)
    return (2.0 - rel).clamp(0.0, 1.0)


class TorchStep:
    """The frame step, batched. `step(...)` -> (output [N,3,H,W] linear, next state)."""

    def __init__(self, net: NsrdNet, nits=PQ_NITS):
        self.net, self.cfg, self.nits = net, net.cfg, float(nits)
        self.s = int(self.cfg["scale"])

    def prepare(self, color, depth, motion, albedo, normal, state, keep):
        """Render resolution: the network's cur and warp inputs and the next state."""
        L = pq_encode(color / material(albedo, self.cfg["demod"]), self.nits)
        if state is None:
            state = color.new_zeros(color.shape[0], nets.STATE, *color.shape[2:])
        smp = warp(state, motion)
        m = depth_mask(depth, smp[:, 7:8]) if self.cfg["mask"] else torch.ones_like(depth)
        m = m * keep
        w1, w2 = smp[:, 0:3] * keep, smp[:, 4:7] * keep
        v2 = m * smp[:, 3:4]
        cur = torch.cat([L, albedo, normal, depth], 1)
        return cur, torch.cat([w1, m, w2, v2], 1), torch.cat([L, m, w1, depth], 1)

    def prev(self, hist, motion, keep):
        """The previous output's lighting warped at output resolution by the bilinearly
        upsampled motion, pixel-unshuffled to render resolution."""
        N, _, h, w = motion.shape
        H, W = h * self.s, w * self.s
        if hist is None:
            return motion.new_zeros(N, 3 * self.s ** 2, h, w)
        m = F.interpolate(motion, size=(H, W), mode="bilinear", align_corners=False) * self.s
        return F.pixel_unshuffle(warp(hist, m) * keep, self.s)

    def finish(self, y, L, jitters, albedo_hr, lo=0.0, albedo=None):
        """y [N,3s^2,h,w] (cropped) -> (lighting PQ [N,3,H,W], output linear). `albedo`
        (render resolution): the guided base's guide."""
        N, _, h, w = L.shape
        H, W = h * self.s, w * self.s
        if nets.guided(self.cfg):
            base = guided_base(L, albedo, albedo_hr, jitters, self.cfg["demod"])
        else:
            grid = torch.cat([torch.from_numpy(nets.base_grid((h, w), (H, W), j)) for j in jitters])
            base = F.grid_sample(L, grid.to(L), mode="bilinear", padding_mode="border",
                                 align_corners=False)
        s2 = 3 * self.s ** 2
        lhr = (F.pixel_shuffle(y[:, :s2], self.s) + base).clamp(lo, 1.0)
        m = material_hr(albedo_hr, self.cfg["demod"])
        if nets.learned_remod(self.cfg):
            alpha = torch.sigmoid(F.pixel_shuffle(y[:, s2:], self.s))
            m = alpha * material(albedo_hr, True) + (1.0 - alpha) * m
        return lhr, pq_decode(lhr, self.nits) * m

    def step(self, color, depth, motion, albedo, normal, albedo_hr, jitters, st, reset,
             lo=0.0, rules=None):
        """reset: bool tensor [N]. st: the state dict or None. rules: the clss-rules PQ
        colour of this frame ([N,3,H,W]; "out_base": "rules" only). With the rules' base
        the returned state also holds "mix" [N,1,H,W], the clamped mix (the recipe's
        --mix-l1)."""
        N, _, h, w = color.shape
        st = st or {}
        keep = (~reset).to(color.dtype).view(N, 1, 1, 1)
        cur, wp, state = self.prepare(color, depth, motion, albedo, normal, st.get("state"), keep)
        prev = self.prev(st.get("hist"), motion, keep)
        rb = nets.rules_base(self.cfg)
        if rb:
            if rules is None:
                raise ValueError("NSRD with out_base 'rules': the step needs the rules' output (rules=)")
            prev = torch.cat([prev, F.pixel_unshuffle(rules, self.s)], 1)
        hp, wpd = nets.pad2(h), nets.pad2(w)
        pad = (0, wpd - w, 0, hp - h)
        hid = self.cfg["hid"]
        hs = st.get("h")
        if hs is None:
            hs = color.new_zeros(N, hid, hp, wpd)
            cs = hs
        elif self.cfg.get("warp_state", False):
            hs, cs = (F.pad(warp(v[:, :, :h, :w], motion) * keep, pad) for v in (hs, st["c"]))
        else:
            hs, cs = hs * keep, st["c"] * keep
        y, hs, cs, mix = self.net(F.pad(cur, pad), F.pad(wp, pad), F.pad(prev, pad), hs, cs)
        lhr, out = self.finish(y[:, :, :h, :w], state[:, 0:3], jitters, albedo_hr, lo, albedo)
        nst = {"state": state, "hist": lhr, "h": hs, "c": cs}
        if rb:
            m = F.pixel_shuffle(mix[:, :, :h, :w], self.s).clamp(0.0, 1.0)
            r = pq_decode(rules, self.nits)
            out = r + m * (out - r)
            nst["mix"] = m
        return out, nst
