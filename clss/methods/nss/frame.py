"""The NSS frame step on an OpenCL device: buffers, launches, the network.

Per frame (render h x w, padded hp x wp = multiples of 8; output H x W = 2h x 2w):

    inputs    the caller's frame -> colour [3,h,w] (/ exposure), depth (reversed-Z),
              motion [2,h,w]                                                 (nss.cl)
    depth     the depth reprojected to the previous frame: kernels/scatter.cl's
              scatter_depth (atomic max into a uint buffer cleared to the far plane), or
              nss_depth_gather (portable, no atomics; depth_scatter="gather")
    pre       disocclusion, warped history and feedback, luma derivative, tonemap ->
              x [12,hp,wp]; the next derivative state                         (nss.cl)
    network   x -> kpn [K*K,hp/4,wp/4], tp [4,hp,wp]                       (clss.Model)
    post      kernel-prediction filter, Catmull-Rom history, clamp, accumulate -> out
              [H,W,3] and the next history                                    (nss.cl)

With config "base": "rules" (networks.BASES) also:

    rules     clss-rules' frame step on the same inputs (the rule-mode kernels of
              clss/methods/clss, asked of the method registry; its own history, reset
              where this step resets) -> its output [H,W,3]; nss_rules_in adds it to x
              (3 channels) before the network
    mix       after post: out = rules + clamp(mix, 0, 1) (out - rules); the next history
              is that output                                                   (nss.cl)

Everything carried between frames stays on the device: the output history (double-
buffered: post reads the old one around each pixel), the derivative state (double-
buffered) and the temporal parameters (the network's tp output: pre reads last frame's
before the network overwrites it; the queue is in order). Nothing is allocated per frame.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyopencl as cl

from ...device import Device
from ...pipeline.contract import PQ_NITS
from ...pipeline.method import input_buffers, summed_event_ms
from .. import rules_frame_step, run_rules_step
from . import networks as nets

KERNEL = Path(__file__).with_name("nss.cl")   # the frame kernels, beside this file
SCATTER = "scatter"                            # kernels/scatter.cl (scatter_depth, fill_u32)
DEPTH_PATHS = ("atomic", "gather")

STAGES = ("inputs", "rules", "depth", "pre", "network", "post")


def kernel_defines(cfg) -> dict:
    """networks.py's constants for nss.cl (-D)."""
    return {"KPN": int(cfg["kpn"]), "COLOR_MAX": float(nets.COLOR_MAX),
            "DEPTH_TOL": float(nets.DEPTH_TOL), "DEPTH_FLOOR": float(nets.DEPTH_FLOOR),
            "GATHER_R": nets.GATHER_RADIUS, "D_MIN": float(nets.D_MIN),
            "D_MAX": float(nets.D_MAX), "D_ALPHA": float(nets.D_ALPHA),
            "LUMA_R": float(nets.LUMA[0]), "LUMA_G": float(nets.LUMA[1]),
            "LUMA_B": float(nets.LUMA[2]), "KPN_EPS": float(nets.KPN_EPS),
            "CLAMP_EPS": float(nets.CLAMP_EPS), "TM_MAX": float(nets.TM_MAX),
            "ALPHA_LO": float(nets.ALPHA_RANGE[0]), "ALPHA_HI": float(nets.ALPHA_RANGE[1]),
            "GAMMA_SCALE": float(nets.GAMMA_SCALE)}


class NssFrameStep:
    """Device buffers and launches of one frame step at a fixed render size."""

    def __init__(self, dev: Device, prec: str, render_size, cfg, weights, *,
                 depth_scatter="atomic", profile=False):
        if depth_scatter not in DEPTH_PATHS:
            raise ValueError(f"depth_scatter: expected one of {', '.join(DEPTH_PATHS)}, "
                             f"got {depth_scatter!r}")
        self.dev, self.prec, self.cfg = dev, prec, cfg
        self.depth_scatter, self.profile = depth_scatter, bool(profile)
        self.h, self.w = (int(v) for v in render_size)
        self.H, self.W = 2 * self.h, 2 * self.w
        self.hp, self.wp = nets.pad8(self.h), nets.pad8(self.w)
        h, w, H, W, hp, wp = self.h, self.w, self.H, self.W, self.hp, self.wp
        K = int(cfg["kpn"])
        f32, e = np.float32, dev.empty
        self.in_color, self.in_depth, self.in_motion = input_buffers(
            dev, ("color", "depth", "motion"), (h, w), (H, W))
        self.col = e((3, h, w), dtype=f32)
        self.dz = e((1, 1, h, w), dtype=f32)
        self.mv = e((1, 2, h, w), dtype=f32)
        self.recon = e((1, 1, h, w), dtype=np.uint32)
        self.hists = [e((3, H, W), dtype=f32) for _ in range(2)]
        self.derivs = [e((2, h, w), dtype=f32) for _ in range(2)]
        self.cur_i = 0                  # hists[cur_i], derivs[cur_i] were written last
        self.x = e((1, nets.in_channels(cfg), hp, wp), prec)
        self.kpn = e((1, K * K, hp // 4, wp // 4), prec)
        self.tp = e((1, nets.TEMPORAL, hp, wp), prec)
        self.out = e((H, W, 3), dtype=f32)
        # the rules' base: clss-rules' step at the nits of the units NSS runs in (linear 1.0
        # = PQ_NITS; the caller's nits reach both as NSS's exposure), its output in rules.out
        self.rules = self.mix = None
        if nets.rules_base(cfg):
            self.rules = rules_frame_step(dev, prec, (h, w), 2.0, PQ_NITS, self.profile)
            self.mix = e((1, 1, hp, wp), prec)
        # zeroed once: no kernel reads uninitialised memory (a reset multiplies by 0)
        for a in (*self.hists, *self.derivs, self.tp):
            dev.zero(a)
        from ...model import Model
        self.network = Model(nets.build_network(cfg, weights, hp, wp), device=dev, precision=prec)
        defs = kernel_defines(cfg)
        names = ("nss_inputs", "nss_depth_gather", "nss_pre", "nss_post")
        k = {n: dev.kernel(KERNEL, n, prec, **defs)
             for n in names + (("nss_rules_in", "nss_rules_mix") if self.rules is not None else ())}
        i32, f = np.int32, np.float32
        L = self.L = {
            "inputs": dev.prepare(k["nss_inputs"], (w, h), [
                self.in_color.data, self.in_depth.data, self.in_motion.data, self.col.data,
                self.dz.data, self.mv.data, i32(w), i32(h), i32(1), f(1), f(1), f(1)]),
            "pre": dev.prepare(k["nss_pre"], (wp, hp), [
                self.col.data, self.dz.data, self.mv.data, self.recon.data, self.hists[0].data,
                self.tp.data, self.derivs[0].data, self.derivs[1].data, self.x.data, i32(w),
                i32(h), i32(wp), i32(hp), f(1)]),
            "post": dev.prepare(k["nss_post"], (W, H), [
                self.col.data, self.mv.data, self.kpn.data, self.tp.data, self.hists[0].data,
                self.hists[1].data, self.out.data, i32(w), i32(h), i32(wp), i32(hp), f(0),
                f(0), f(1), f(1)]),
        }
        if self.rules is not None:
            L["rules_in"] = dev.prepare(k["nss_rules_in"], (wp, hp), [
                self.rules.out.data, self.x.data, i32(w), i32(h), i32(wp), i32(hp),
                i32(nets.IN), f(1)])
            L["mix"] = dev.prepare(k["nss_rules_mix"], (W, H), [
                self.rules.out.data, self.mix.data, self.out.data, self.hists[1].data, i32(w),
                i32(h), i32(wp), f(1)])
        if depth_scatter == "atomic":
            # scatter.cl reads float32 planes whatever the network's precision
            opts = {"DEPTH_MAX": 1}
            L["clear"] = dev.prepare(dev.kernel(SCATTER, "fill_u32", "fp32", **opts), (h * w,),
                                     [self.recon.data, np.uint32(0), i32(h * w)])
            L["depth"] = dev.prepare(dev.kernel(SCATTER, "scatter_depth", "fp32", **opts),
                                     (w, h, 1), [self.dz.data, self.mv.data, self.recon.data,
                                                 i32(h), i32(w), i32(1), f(nets.SCATTER_WMIN)])
        else:
            L["depth"] = dev.prepare(k["nss_depth_gather"], (w, h), [
                self.dz.data, self.mv.data, self.recon.data, i32(w), i32(h), f(nets.SCATTER_WMIN)])
        self.events: list[tuple[str, cl.Event]] = []

    @property
    def hist(self):
        """The last output (linear / exposure) [3,H,W] float32: the next frame's history."""
        return self.hists[self.cur_i]

    @property
    def deriv(self):
        """The derivative state (derivative, luma) [2,h,w] after the last frame."""
        return self.derivs[self.cur_i]

    def run(self, color, depth, motion, jitter, reset, *, depth_inverted=True,
            motion_scale=(1.0, 1.0), exposure=1.0, out=None):
        """Enqueue one frame (device arrays in image layout, float32) with no host wait.
        Returns the output array (`out` or the internal one) and the last event."""
        L, i32, f = self.L, np.int32, np.float32
        out = self.out if out is None else out
        keep = f(0.0 if reset else 1.0)
        old, new = self.cur_i, 1 - self.cur_i
        inp = L["inputs"]
        for idx, v in ((0, color.data), (1, depth.data), (2, motion.data),
                       (8, i32(bool(depth_inverted))), (9, f(motion_scale[0])),
                       (10, f(motion_scale[1])), (11, f(1.0 / exposure))):
            inp.bind(idx, v)
        pre = L["pre"]
        for idx, v in ((4, self.hists[old].data), (6, self.derivs[old].data),
                       (7, self.derivs[new].data), (13, keep)):
            pre.bind(idx, v)
        post = L["post"]
        for idx, v in ((4, self.hists[old].data), (5, self.hists[new].data), (6, out.data),
                       (11, f(float(jitter[0]))), (12, f(float(jitter[1]))), (13, keep),
                       (14, f(exposure))):
            post.bind(idx, v)
        ev = [("inputs", inp())]
        if self.rules is not None:
            ev += self._rules(color, depth, motion, jitter, reset, depth_inverted, motion_scale,
                              exposure)
        if "clear" in L:
            ev.append(("depth", L["clear"]()))
        ev.append(("depth", L["depth"]()))
        ev.append(("pre", pre()))
        outs = {"kpn": self.kpn, "tp": self.tp}
        if self.rules is not None:
            ri = L["rules_in"]
            ri.bind(7, f(1.0 / exposure))
            ev.append(("pre", ri()))
            outs["mix"] = self.mix
        ne = [] if self.profile else None
        self.network.run_device({"x": self.x}, out=outs, events=ne)
        ev += [("network", e) for e in ne or ()]
        last = post()
        ev.append(("post", last))
        if self.rules is not None:
            mx = L["mix"]
            for idx, v in ((2, out.data), (3, self.hists[new].data), (7, f(1.0 / exposure))):
                mx.bind(idx, v)
            last = mx()
            ev.append(("post", last))
        if self.profile:
            self.events.extend(ev)
        self.cur_i = new
        return out, last

    def _rules(self, color, depth, motion, jitter, reset, depth_inverted, motion_scale, exposure):
        """clss-rules' frame step on this frame (clss.methods.run_rules_step); the profiled
        events."""
        return run_rules_step(self.rules, color, depth, motion, jitter, reset,
                              depth_inverted=depth_inverted, motion_scale=motion_scale,
                              exposure=exposure, profile=self.profile)

    def stage_ms(self) -> dict:
        return summed_event_ms(self.events, STAGES)

    def device_bytes(self) -> int:
        arrays = [self.in_color, self.in_depth, self.in_motion, self.col, self.dz, self.mv,
                  self.recon, *self.hists, *self.derivs, self.x, self.kpn, self.tp, self.out]
        n = sum(a.nbytes for a in arrays)
        if self.rules is not None:
            n += self.mix.nbytes + self.rules.device_bytes()
        mem = self.network.memory()
        n += mem.get("weights_bytes", 0) + mem.get("intermediate_peak_bytes", 0)
        return int(n)
