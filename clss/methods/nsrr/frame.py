"""The NSRR frame step on an OpenCL device: buffers, launches, the two networks.

Per frame (render h x w, output H x W, padded Hp x Wp = multiples of 4; N history slots):

    prepare       colour, depth, motion -> rgbd [4,h,w] (PQ, reversed-Z), mv [2,h,w]
    features      rgbd -> feat [12,h,w]                     (clss.Model; once per frame)
    reproject     feat, mv, hist -> stack [12(N+1),Hp,Wp]   zero-upsampling with the jitter,
                                                            motion upsampled bilinearly,
                                                            the history warped one step
    rules         colour, depth, motion -> base [3,Hp,Wp]   with config "base": "rules" only:
                                                            clss-rules' frame step (the rule-
                                                            mode kernels of clss/methods/clss,
                                                            its own history), its PQ output
                                                            copied into the padded base
    reconstruct   stack -> y [3,Hp,Wp]                      (clss.Model: reweighting + U-Net;
                                                            + base, the jittered colour
                                                            bilinear or the rules' output,
                                                            with the residual)
    finish        y -> out [H,W,3] linear

The stack is double-buffered: its first 12N channels are the next frame's history, so
the next reproject reads them where they are (a copy of them cost as much as the warp).

Everything is enqueued on the device's in-order queue with no host wait between the
stages; the caller waits once, on the output. The networks run through recorded
clss.Model launch plans into buffers allocated here once.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyopencl as cl

from ... import selfcheck
from ...device import Device
from ...ops.conv import builtin_free, vector_width
from ...pipeline.contract import PQ_NITS, PQ_PEAK_NITS, output_size
from ...pipeline.method import input_buffers, summed_event_ms
from ...tolerance import DEFAULT_TOL, EXACT
from .. import rules_frame_step, run_rules_step
from .networks import FEAT, build_features, build_reconstruct, reject_tau, rules_base

KERNEL = Path(__file__).with_name("nsrr.cl")   # the frame kernels, beside this file

STAGES = ("prepare", "rules", "features", "reproject", "reconstruct", "finish")
RESET_FILLS = ("zero", "duplicate")


def pad4(n: int) -> int:
    return -(-int(n) // 4) * 4


def zu_axis(scale: float, jit: float):
    """(integer scale or 0, integer sample offset in the block) of one axis, as
    kernels/zero_upsample.cl (and nsrr.cl) place a jittered sample."""
    if float(scale).is_integer():
        s = int(scale)
        return s, min(int(math.floor((0.5 + jit) * s)), s - 1)
    return 0, 0


class NsrrFrameStep:
    """Device buffers and launches of one frame step at a fixed render size."""

    def __init__(self, dev: Device, prec: str, render_size, scale, cfg, weights, *,
                 history=None, reset_fill="zero", nits=PQ_NITS, profile=False):
        if reset_fill not in RESET_FILLS:
            raise ValueError(f"reset_fill: expected {' or '.join(RESET_FILLS)}, got {reset_fill!r}")
        self.dev, self.prec, self.cfg = dev, prec, cfg
        self.h, self.w = (int(s) for s in render_size)
        self.H, self.W = output_size(self.h, self.w, scale)
        self.Hp, self.Wp = pad4(self.H), pad4(self.W)
        self.sy, self.sx = self.H / self.h, self.W / self.w
        self.nprev = int(cfg["n_prev"])
        self.history = self.nprev if history is None else int(history)
        if not 0 <= self.history <= self.nprev:
            raise ValueError(f"history: expected 0..{self.nprev} previous frames, got {history!r}")
        self.reset_fill = reset_fill
        self.nits = float(nits)
        self.profile = bool(profile)
        h, w, Hp, Wp = self.h, self.w, self.Hp, self.Wp
        f32 = np.float32
        e = dev.empty
        self.in_color, self.in_depth, self.in_motion = input_buffers(
            dev, ("color", "depth", "motion"), (h, w))
        self.rgbd = e((1, 4, h, w), prec)
        self.mv = e((2, h, w), dtype=f32)
        # the render depth in float32, this frame's and the previous one's (the depth
        # rejection's; deps[1 - cur] is written this frame, as the stacks)
        self.deps = [e((h, w), dtype=f32) for _ in range(2)]
        self.tau = reject_tau(cfg)
        self.feat = e((1, FEAT, h, w), prec)
        self.stacks = [e((1, FEAT * (self.nprev + 1), Hp, Wp), prec) for _ in range(2)]
        self.cur = 0            # stacks[cur] was written last: its first 12N channels are the history
        self.y = e((1, 3, Hp, Wp), prec)
        self.residual = bool(cfg.get("residual", False))
        self.base = e((1, 3, Hp, Wp), prec)
        self.out = e((self.H, self.W, 3), dtype=f32)
        # "base": "rules": clss-rules' frame step on the same inputs (its history is its own,
        # kept and reset as the rules keep it); its PQ colour (history channels 0-2) is
        # copied into rbase, whose padding stays 0, and fed to the U-Net as its base
        self.rules = self.rbase = None
        if rules_base(cfg):
            self.rules = rules_frame_step(dev, prec, (h, w), scale, self.nits, self.profile)
            self.rbase = e((1, 3, Hp, Wp), prec)
            dev.zero(self.rbase)
        # zeroed once: no kernel reads uninitialised memory (tests/test_oclgrind_methods.py)
        for a in (*self.stacks, *self.deps):
            dev.zero(a)
        from ...model import Model
        self.features = Model(build_features(cfg, weights, h, w), device=dev, precision=prec)
        self.reconstruct = Model(build_reconstruct(cfg, weights, Hp, Wp), device=dev, precision=prec)
        # float8 loads and stores as clang vector accesses on PoCL (builtin calls are out of
        # line there: common.h, CLSS_CLANG_VECTORS)
        cv = builtin_free(dev)
        k = {n: dev.kernel(KERNEL, n, prec, CLSS_CLANG_VECTORS=cv) for n in ("nsrr_prepare", "nsrr_finish")}
        rd = {**selfcheck.defines(dev, prec, REPROJECT_VECTORS), "CLSS_CLANG_VECTORS": cv}
        rd.setdefault("G", reproject_group(dev))
        i32, f = np.int32, np.float32
        self.L = {
            "prepare": dev.prepare(k["nsrr_prepare"], (w, h), [
                self.in_color.data, self.in_depth.data, self.in_motion.data, self.rgbd.data,
                self.mv.data, i32(w), i32(h), i32(1), f(1), f(1), f(1),
                f(self.nits / PQ_PEAK_NITS), self.deps[0].data])}
        k["nsrr_reproject"] = dev.kernel(KERNEL, "nsrr_reproject", prec, **rd)
        self.xy = None          # the warp's sample positions (the fast path's nsrr_warp_coords)
        if int(rd["VEC"]) == 1:
            grid, coords = (Wp, Hp), self.mv
        else:
            # runs of 8 pixels, in plane groups; the warp's sample positions computed once
            w8 = -(-Wp // 8) * 8
            # xs, ys, and the depth rejection's decisions when it is on
            self.xy = e((3 if self.tau >= 0 else 2, self.H, w8), dtype=f32)
            dev.zero(self.xy)
            grid = (-(-Wp // (8 * int(rd["RUNS"]))), Hp, 1 + FEAT * self.nprev // int(rd["G"]))
            coords = self.xy
            self.L["coords"] = dev.prepare(dev.kernel(KERNEL, "nsrr_warp_coords", prec, **rd), (w8 // 8, self.H), [
                self.mv.data, self.xy.data, i32(h), i32(w), i32(self.H), i32(self.W), i32(Wp),
                f(self.sy), f(self.sx), self.deps[0].data, self.deps[1].data, f(0), f(0),
                f(self.tau)])
        self.L.update({
            "reproject": dev.prepare(k["nsrr_reproject"], grid, [
                self.feat.data, coords.data, self.stacks[1].data, self.stacks[0].data, self.base.data,
                i32(h), i32(w), i32(self.H), i32(self.W), i32(Hp), i32(Wp), i32(self.nprev),
                i32(self.history), i32(0), i32(0), i32(0), i32(0), f(self.sy), f(self.sx),
                f(0), f(0), i32(1), self.deps[0].data, self.deps[1].data, f(self.tau)]),
            "finish": dev.prepare(k["nsrr_finish"], (-(-self.W // 8), self.H), [
                self.y.data, self.out.data, i32(self.H), i32(self.W), i32(Wp), i32(Hp),
                f(PQ_PEAK_NITS / self.nits)]),
        })
        self.events: list[tuple[str, cl.Event]] = []
        self.accepted = False

    def run(self, color, depth, motion, jitter, reset, *, depth_inverted=True,
            motion_scale=(1.0, 1.0), exposure=1.0, out=None):
        """Enqueue one frame (device arrays in image layout, float32) with no host wait.
        Returns the output array (`out` or the internal one) and the last event."""
        L, i32, f = self.L, np.int32, np.float32
        out = self.out if out is None else out
        p = L["prepare"]
        for idx, v in ((0, color.data), (1, depth.data), (2, motion.data),
                       (7, i32(bool(depth_inverted))), (8, f(motion_scale[0])),
                       (9, f(motion_scale[1])), (10, f(1.0 / exposure))):
            p.bind(idx, v)
        jx, jy = float(jitter[0]), float(jitter[1])
        (siy, oy), (six, ox) = zu_axis(self.sy, jy), zu_axis(self.sx, jx)
        mode = 0 if not reset else (1 if self.reset_fill == "zero" else 2)
        r = L["reproject"]
        for idx, v in ((13, i32(siy)), (14, i32(six)), (15, i32(oy)), (16, i32(ox)),
                       (19, f(jy)), (20, f(jx)), (21, i32(mode))):
            r.bind(idx, v)
        prev, stack = self.stacks[self.cur], self.stacks[1 - self.cur]
        r.bind(2, prev.data)
        r.bind(3, stack.data)
        dcur, dprev = self.deps[1 - self.cur].data, self.deps[self.cur].data
        p.bind(12, dcur)
        r.bind(22, dcur)
        r.bind(23, dprev)
        if "coords" in L:
            c = L["coords"]
            for idx, v in ((9, dcur), (10, dprev), (11, f(jy)), (12, f(jx))):
                c.bind(idx, v)
        fin = L["finish"]
        fin.bind(1, out.data)
        fin.bind(6, f(PQ_PEAK_NITS / self.nits * exposure))
        ev = [("prepare", p())]
        if self.rules is not None:
            ev += self._rules(color, depth, motion, (jx, jy), reset, depth_inverted,
                              motion_scale, exposure)
        fe = [] if self.profile else None
        self.features.run_device({"rgbd": self.rgbd}, out={"feat": self.feat}, events=fe)
        ev += [("features", e) for e in fe or ()]
        if "coords" in L:
            ev.append(("reproject", L["coords"]()))
        ev.append(("reproject", r()))
        re = [] if self.profile else None
        # (one launch plan per stack buffer: clss.Model keeps both and replays them)
        base = self.base if self.rules is None else self.rbase
        feeds = {"stack": stack, "base": base} if self.residual else {"stack": stack}
        self.reconstruct.run_device(feeds, out={"y": self.y}, events=re)
        ev += [("reconstruct", e) for e in re or ()]
        last = fin()
        ev.append(("finish", last))
        if self.profile:
            self.events.extend(ev)
        self.cur = 1 - self.cur
        self.accepted = True
        return out, last

    def _rules(self, color, depth, motion, jitter, reset, depth_inverted, motion_scale, exposure):
        """clss-rules' frame step on this frame (clss.methods.run_rules_step), then its PQ
        colour copied into rbase; the profiled events."""
        rs = self.rules
        ev = run_rules_step(rs, color, depth, motion, jitter, reset,
                            depth_inverted=depth_inverted, motion_scale=motion_scale,
                            exposure=exposure, profile=self.profile)
        b, H, W = self.rbase.dtype.itemsize, self.H, self.W
        copy = cl.enqueue_copy(self.dev.queue, self.rbase.data, rs.state.data,
                               src_origin=(0, 0, 0), dst_origin=(0, 0, 0), region=(W * b, H, 3),
                               src_pitches=(W * b, H * W * b),
                               dst_pitches=(self.Wp * b, self.Hp * self.Wp * b))
        return ev + [("rules", copy)] if self.profile else []

    @property
    def hist(self):
        """The history the next frame warps: [12N, Hp, Wp] (a view of the last stack)."""
        return self.stacks[self.cur].reshape(-1, self.Hp, self.Wp)[:FEAT * self.nprev]

    def stage_ms(self) -> dict:
        return summed_event_ms(self.events, STAGES)

    def device_bytes(self) -> int:
        arrays = [self.in_color, self.in_depth, self.in_motion, self.rgbd, self.mv, *self.deps, self.feat,
                  *self.stacks, self.y, self.base, self.out] + ([self.xy] if self.xy is not None else [])
        n = sum(a.nbytes for a in arrays)
        if self.rules is not None:
            n += self.rbase.nbytes + self.rules.device_bytes()
        for m in (self.features, self.reconstruct):
            mem = m.memory()
            n += mem.get("weights_bytes", 0) + mem.get("intermediate_peak_bytes", 0)
        return int(n)


# The reprojection on runs of 8 output pixels of a row, in plane groups (nsrr.cl, VEC = 8):
# a CPU layout (planes written as float8, a few store streams per work-item), self-checked
# against VEC = 1 on four frames: two of noisy motion (the taps gathered lane by lane),
# one of a uniform pan (the taps as window loads) and one of a pan off the frame's edge,
# each warping the previous one's history (bit-exact: the same operations lane by lane).
REPROJECT_VECTORS = "nsrr.reproject_vectors"
# the fast variant's -D options: 8-pixel runs, RUNS of them per work-item (1 was fastest),
# floor, clamp and min without builtin calls (kernels/inline_math.h, bit-exact); the history
# planes in groups of reproject_group(dev)
REPROJECT_FAST = {"VEC": 8, "RUNS": 1, "CLSS_INLINE_MATH": 1}


def reproject_group(dev: Device) -> int:
    """History planes per work-item of the fast reprojection (G, a divisor of 12): 6 on
    16-wide CPUs (AVX-512: fastest on a Cascade Lake, 3, 4 and 12 the same or slower), 4 on
    8-wide ones (AVX2: on a Zen 3, 1080p fp32, x2 151 ms against G 6's 189, x4 183 against
    243; 2, 3 and 12 slower)."""
    return 6 if vector_width(dev) >= 16 else 4


def reproject_motions(g, shape):
    """Motions that reach both of the fast reprojection's branches: noisy (gathers), a
    uniform sub-pixel pan (window loads), and a pan that leaves the frame (edge taps)."""
    return [g.uniform(-1.5, 1.5, shape), g.uniform(-1.5, 1.5, shape),
            np.broadcast_to(np.float32([0.3, -0.2]), shape), np.broadcast_to(np.float32([-2.6, 1.4]), shape)]


def _reproject_check(dev: Device, prec: str) -> list[np.ndarray]:
    from ...ops.base import rng
    from .networks import init_weights, make_config
    g = rng("nsrr reproject selfcheck")
    cfg = make_config("fast", reject="depth")       # (the rejection's lanes too)
    fs = NsrrFrameStep(dev, prec, (7, 13), 2.0, cfg, init_weights(cfg, 1))
    outs = []
    for t, mv in enumerate(reproject_motions(g, (7, 13, 2))):
        arrays = [g.uniform(0, 4, (7, 13, 3)), g.uniform(0.1, 0.9, (7, 13)), mv]
        color, depth, motion = (dev.to_device(np.ascontiguousarray(a, np.float32)) for a in arrays)
        out, ev = fs.run(color, depth, motion, ((0.25, -0.25), (-0.25, 0.25))[t % 2], t == 0)
        ev.wait()
        outs += [dev.to_host(out), dev.to_host(fs.stacks[fs.cur])]    # run() flipped cur
    return outs


selfcheck.register(selfcheck.FastPath(
    REPROJECT_VECTORS, KERNEL, REPROJECT_FAST, {"VEC": 1}, check=_reproject_check,
    tolerance=lambda prec: EXACT if prec != "fp16-native" else DEFAULT_TOL[prec],
    what="runs of 8 output pixels of a row per work-item, the planes in groups (a few store "
         "streams each), the warp's sample positions computed once (nsrr_warp_coords), the taps "
         "as window loads where a run's taps are contiguous",
    applies=lambda dev: dev.is_cpu, measured=True))
