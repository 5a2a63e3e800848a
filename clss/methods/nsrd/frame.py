"""The NSRD frame step on an OpenCL device: buffers, launches, the network.

Per frame (render h x w, padded hp x wp = even; output H x W = h s x w s):

    prepare   colour / material -> lighting (PQ); the state warped; the depth-test mask;
              cur [10,hp,wp], warp [8,hp,wp]; the next state [8,h,w]   (nsrd.cl)
    prev      the previous output's lighting warped at H x W, unshuffled to [3s^2,hp,wp]
    network   cur, warp, prev, h, c -> y [3s^2,hp,wp], h', c'        (clss.Model)
    finish    y shuffled to H x W + the current lighting (bilinear, or the guided base: networks.BASES), clipped (the next history),
              times the output-resolution material, then (nsrd_decode, 8 pixels a
              work-item: float8 PQ decode) the decoded lighting -> out [H,W,3]

With config "out_base": "rules" (networks.OUT_BASES) also:

    rules     clss-rules' frame step on the same inputs (the rule-mode kernels of
              clss/methods/clss, asked of the method registry; its own history, reset
              where this step resets); nsrd_rules_in unshuffles its PQ colour into prev's
              second 3s^2 channels before the network
    mix       after finish: out = rules + clamp(mix, 0, 1) (out - rules)       (nsrd.cl)

Everything carried between frames stays on the device: the render-resolution state
(double-buffered), the previous output's lighting (read by `prev` before `finish`
overwrites it: the queue is in order) and the ConvLSTM's h and c (double-buffered; zeroed
on a reset). Nothing is allocated per frame, so a long run holds memory flat.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyopencl as cl

from ... import selfcheck
from ...device import Device
from ...ops.conv import builtin_free
from ...pipeline.contract import PQ_NITS, PQ_PEAK_NITS
from ...pipeline.method import input_buffers, summed_event_ms
from ...tolerance import DEFAULT_TOL, EXACT
from .. import rules_frame_step, run_rules_step
from . import networks as nets

KERNEL = Path(__file__).with_name("nsrd.cl")   # the frame kernels, beside this file

STAGES = ("prepare", "rules", "prev", "network", "finish")


def guide_defines() -> dict:
    """The guided base's constants (networks.GUIDE_*) as nsrd.cl's -D options."""
    return {"NSRD_GUIDE_INV_SIG2": f"{1.0 / nets.GUIDE_SIGMA ** 2!r}f",
            "NSRD_GUIDE_FLOOR": f"{nets.GUIDE_FLOOR!r}f"}


class NsrdFrameStep:
    """Device buffers and launches of one frame step at a fixed render size."""

    def __init__(self, dev: Device, prec: str, render_size, cfg, weights, *, nits=PQ_NITS,
                 profile=False):
        self.dev, self.prec, self.cfg = dev, prec, cfg
        self.s = s = int(cfg["scale"])
        self.h, self.w = (int(v) for v in render_size)
        self.H, self.W = self.h * s, self.w * s
        self.hp, self.wp = nets.pad2(self.h), nets.pad2(self.w)
        self.nits, self.profile = float(nits), bool(profile)
        h, w, H, W, hp, wp = self.h, self.w, self.H, self.W, self.hp, self.wp
        f32, e = np.float32, dev.empty
        hid = cfg["hid"]
        (self.in_color, self.in_depth, self.in_motion, self.in_albedo, self.in_normal,
         self.in_albedo_hr) = input_buffers(
            dev, ("color", "depth", "motion", "albedo", "normal", "albedo_hr"), (h, w), (H, W))
        self.states = [e((nets.STATE, h, w), dtype=f32) for _ in range(2)]
        self.cur_i = 0                  # states[cur_i] was written last
        self.hist = e((3, H, W), dtype=f32)
        self.mv = e((2, h, w), dtype=f32)
        self.cur = e((1, nets.CUR, hp, wp), prec)
        self.warp = e((1, nets.WARP, hp, wp), prec)
        self.prev = e((1, nets.prev_channels(cfg), hp, wp), prec)
        # the ConvLSTM state: the network reads hc[0] and writes hc[1], copied back on the
        # device after it (fixed buffers keep the network's recorded launch plan; feeding
        # alternating buffers re-recorded it every frame, ~30 ms of host time)
        self.hc = [(e((1, hid, hp, wp), prec), e((1, hid, hp, wp), prec)) for _ in range(2)]
        self.warp_state = bool(cfg.get("warp_state", False))
        # with warp_state, prepare warps hc[0] into hcw, which the network reads
        self.hcw = ((e((1, hid, hp, wp), prec), e((1, hid, hp, wp), prec)) if self.warp_state
                    else self.hc[0])
        self.y = e((1, nets.out_channels(cfg), hp, wp), prec)
        self.out = e((H, W, 3), dtype=f32)
        # the rules' base: clss-rules' step at this step's nits (the caller's exposure
        # reaches both), its PQ colour in rules.state, its output in rules.out
        self.rules = self.mix = None
        if nets.rules_base(cfg):
            self.rules = rules_frame_step(dev, prec, (h, w), float(s), self.nits, self.profile)
            self.mix = e((1, s * s, hp, wp), prec)
        # zeroed once: the padding of prev is never written, and no kernel reads
        # uninitialised memory (tests/test_oclgrind_methods.py)
        for a in (*self.states, self.hist, self.prev, *self.hc[0], *self.hc[1]):
            dev.zero(a)
        from ...model import Model
        self.network = Model(nets.build_network(cfg, weights, hp, wp), device=dev, precision=prec)
        self.encode8 = selfcheck.enabled(dev, prec, ENCODE8)
        # CLSS_CLANG_VECTORS: the float8 kernels' private vector stores as clang vector accesses
        # on PoCL (common.h: its vstore8/vload8 are out-of-line calls there)
        defs = {**selfcheck.defines(dev, prec, INLINE_MATH), **selfcheck.defines(dev, prec, ENCODE8),
                "CLSS_CLANG_VECTORS": builtin_free(dev)}
        if self.encode8 and nets.guided(cfg):
            defs.update(selfcheck.defines(dev, prec, GUIDED8))
        defs.update(guide_defines())
        k = {n: dev.kernel(KERNEL, n, prec, NSRD_SCALE=s, **defs)
             for n in ("nsrd_encode", "nsrd_alpha", "nsrd_prepare", "nsrd_prepare8", "nsrd_warp_state8",
                       "nsrd_prev", "nsrd_prev8", "nsrd_finish", "nsrd_finish8", "nsrd_decode")
             + (("nsrd_rules_in", "nsrd_rules_mix") if self.rules is not None else ())}
        self.learned = bool(nets.learned_remod(cfg))
        na = s * s * hp * wp
        self.alpha = e((na if self.learned else 1,), dtype=f32)      # nsrd_alpha's output
        i32, f = np.int32, np.float32
        demod, eps = i32(bool(cfg["demod"])), f(nets.DEMOD_EPS)
        self.L = {
            "encode": dev.prepare(k["nsrd_encode"], (-(-w // 8), h), [
                self.in_color.data, self.in_albedo.data, self.cur.data, self.states[0].data,
                i32(w), i32(h), i32(wp), i32(hp), f(1), f(self.nits / PQ_PEAK_NITS), demod, eps]),
            "prepare": dev.prepare(k["nsrd_prepare8"] if self.encode8 else k["nsrd_prepare"],
                                   (-(-wp // 8), hp) if self.encode8 else (wp, hp), [
                self.in_color.data, self.in_depth.data, self.in_motion.data,
                self.in_albedo.data, self.in_normal.data, self.states[1].data,
                self.states[0].data, self.cur.data, self.warp.data, self.mv.data,
                i32(w), i32(h), i32(wp), i32(hp), i32(1), f(1), f(1), f(1),
                f(self.nits / PQ_PEAK_NITS), f(1), demod, i32(bool(cfg["mask"])), eps,
                f(nets.DEPTH_TOL), f(nets.DEPTH_FLOOR), self.hc[0][0].data, self.hc[0][1].data,
                self.hcw[0].data, self.hcw[1].data, i32(hid), i32(self.warp_state)]),
            "prev": dev.prepare(k["nsrd_prev8"] if self.encode8 else k["nsrd_prev"],
                                (-(-W // 8), H) if self.encode8 else (W, H), [
                self.hist.data, self.mv.data, self.prev.data, i32(h), i32(w), i32(H), i32(W),
                i32(hp), i32(wp), i32(s), f(1)]),
            # with encode8, nsrd_finish8 decodes the lighting into out too (no nsrd_decode)
            "finish": dev.prepare(k["nsrd_finish8"] if self.encode8 else k["nsrd_finish"],
                                  (-(-W // 8), H) if self.encode8 else (W, H), [
                self.y.data, self.states[0].data, self.in_albedo_hr.data, self.hist.data,
                self.out.data, i32(h), i32(w), i32(H), i32(W), i32(hp), i32(wp), i32(s),
                f(0), f(0), demod, eps, i32(nets.learned_remod(cfg)), self.alpha.data,
                *((f(PQ_PEAK_NITS / self.nits),) if self.encode8 else ()),
                self.in_albedo.data, i32(nets.guided(cfg))]),
            "warp_state": dev.prepare(k["nsrd_warp_state8"], (-(-wp // 8), hp, hid), [
                self.mv.data, self.hc[0][0].data, self.hc[0][1].data, self.hcw[0].data, self.hcw[1].data,
                i32(w), i32(h), i32(wp), i32(hp), f(1)]),
            "alpha": dev.prepare(k["nsrd_alpha"], (-(-na // 8),), [
                self.y.data, self.alpha.data, i32(3 * na), i32(na)]),
            "decode": dev.prepare(k["nsrd_decode"], (-(-H * W // 8),), [
                self.hist.data, self.out.data, i32(H * W), f(PQ_PEAK_NITS / self.nits)]),
        }
        if self.rules is not None:
            self.L["rules_in"] = dev.prepare(k["nsrd_rules_in"], (W, H), [
                self.rules.state.data, self.prev.data, i32(H), i32(W), i32(hp), i32(wp), i32(s),
                i32(3 * s * s)])
            self.L["mix"] = dev.prepare(k["nsrd_rules_mix"], (W, H), [
                self.rules.out.data, self.mix.data, self.out.data, i32(H), i32(W), i32(hp),
                i32(wp), i32(s)])
        # only the launches this frame step runs: the float8 path's, or the per-pixel one's
        # (whose PQ decode the float8 finish folds in)
        for name in (("decode",) if self.encode8 else ("encode", "alpha", "warp_state")):
            del self.L[name]
        self.events: list[tuple[str, cl.Event]] = []

    @property
    def state(self):
        """The render-resolution state the next frame warps [8,h,w] (float32)."""
        return self.states[self.cur_i]

    @property
    def lstm(self):
        """(h, c) of the ConvLSTM after the last frame."""
        return self.hc[0]

    def run(self, color, depth, motion, albedo, normal, albedo_hr, jitter, reset, *,
            depth_inverted=True, motion_scale=(1.0, 1.0), exposure=1.0, out=None):
        """Enqueue one frame (device arrays in image layout, float32) with no host wait.
        Returns the output array (`out` or the internal one) and the last event."""
        L, i32, f = self.L, np.int32, np.float32
        out = self.out if out is None else out
        keep = f(0.0 if reset else 1.0)
        old, new = self.states[self.cur_i], self.states[1 - self.cur_i]
        p = L["prepare"]
        for idx, v in ((0, color.data), (1, depth.data), (2, motion.data), (3, albedo.data),
                       (4, normal.data), (5, old.data), (6, new.data),
                       (14, i32(bool(depth_inverted))), (15, f(motion_scale[0])),
                       (16, f(motion_scale[1])), (17, f(1.0 / exposure)), (19, keep)):
            p.bind(idx, v)
        L["prev"].bind(10, keep)
        fin = L["finish"]
        for idx, v in ((1, new.data), (2, albedo_hr.data), (4, out.data),
                       (12, f(float(jitter[0]))), (13, f(float(jitter[1])))):
            fin.bind(idx, v)
        if self.encode8:
            fin.bind(18, f(PQ_PEAK_NITS / self.nits * exposure))
        fin.bind(19 if self.encode8 else 18, albedo.data)    # the guided base's guide
        if self.encode8:
            enc = L["encode"]
            for idx, v in ((0, color.data), (1, albedo.data), (3, new.data), (8, f(1.0 / exposure))):
                enc.bind(idx, v)
        else:
            dec = L["decode"]
            dec.bind(1, out.data)
            dec.bind(3, f(PQ_PEAK_NITS / self.nits * exposure))
        (h_in, c_in), (h_out, c_out) = self.hc
        ev = []
        if self.rules is not None:
            ev += self._rules(color, depth, motion, jitter, reset, depth_inverted, motion_scale,
                              exposure)
        if reset:
            for a in (h_in, c_in):
                ev.append(("prepare", self.dev.zero(a)))
        if self.encode8:
            ev.append(("prepare", enc()))
        ev.append(("prepare", p()))
        if self.encode8 and self.warp_state:
            ws = L["warp_state"]
            ws.bind(9, keep)
            ev.append(("prepare", ws()))
        ev.append(("prev", L["prev"]()))
        outs = {"y": self.y, "h_out": h_out, "c_out": c_out}
        if self.rules is not None:
            ri = L["rules_in"]
            ri.bind(0, self.rules.state.data)     # its history is double-buffered
            ev.append(("prev", ri()))
            outs["mix"] = self.mix
        ne = [] if self.profile else None
        self.network.run_device({"cur": self.cur, "warp": self.warp, "prev": self.prev,
                                 "h": self.hcw[0], "c": self.hcw[1]}, out=outs, events=ne)
        ev += [("network", e) for e in ne or ()]
        q = self.dev.queue
        ev += [("network", cl.enqueue_copy(q, dst.data, src.data, byte_count=src.nbytes))
               for src, dst in ((h_out, h_in), (c_out, c_in))]
        if self.encode8 and self.learned:
            ev.append(("finish", L["alpha"]()))
        last = fin()
        ev.append(("finish", last))
        if not self.encode8:
            last = dec()
            ev.append(("finish", last))
        if self.rules is not None:
            mx = L["mix"]
            mx.bind(2, out.data)
            last = mx()
            ev.append(("finish", last))
        if self.profile:
            self.events.extend(ev)
        self.cur_i = 1 - self.cur_i
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
        arrays = [*(self.hcw if self.warp_state else ()), self.in_color, self.in_depth, self.in_motion, self.in_albedo, self.in_normal,
                  self.in_albedo_hr, *self.states, self.hist, self.mv, self.cur, self.warp,
                  self.prev, *self.hc[0], *self.hc[1], self.y, self.out, self.alpha]
        n = sum(a.nbytes for a in arrays)
        if self.rules is not None:
            n += self.mix.nbytes + self.rules.device_bytes()
        mem = self.network.memory()
        n += mem.get("weights_bytes", 0) + mem.get("intermediate_peak_bytes", 0)
        return int(n)


# The frame kernels without builtin calls in their per-pixel arithmetic (inline_math.h,
# -DCLSS_INLINE_MATH=1): on pip's PoCL 3.0 each floor, clamp, min or isfinite was an
# out-of-line call, which kept PoCL from vectorising the work-item loop. Self-checked
# against the builtins on two frames (the second warping the first's state), bit-exact.
INLINE_MATH = "nsrd.inline_math"


def _frames_check(dev: Device, prec: str, configs, name: str) -> list[np.ndarray]:
    """Two frames (the second warping the first's state) through each config, a NaN in the
    colour and the material and an infinity in the output-resolution material; the output,
    the state and the history of each. name seeds the inputs."""
    from ...ops.base import rng
    g = rng(name)
    outs = []
    for cfg in configs:
        scale = int(cfg["scale"])
        fs = NsrdFrameStep(dev, prec, (7, 13), cfg, nets.init_weights(cfg, 1))
        h, w, H, W = 7, 13, 7 * scale, 13 * scale
        for t, jitter in enumerate(((0.25, -0.25), (-0.25, 0.25))):
            arrays = [g.uniform(0, 4, (h, w, 3)), g.uniform(0.1, 0.9, (h, w)), g.uniform(-1.5, 1.5, (h, w, 2)),
                      g.uniform(0, 1, (h, w, 3)), g.uniform(-1, 1, (h, w, 3)), g.uniform(0, 1, (H, W, 3))]
            arrays[0][0, 0, 0] = np.nan
            arrays[3][2, 3, 0] = np.nan
            arrays[5][1, 2, 1] = np.inf
            ins = [dev.to_device(a.astype(np.float32)) for a in arrays]
            out, ev = fs.run(*ins, jitter, t == 0)
            ev.wait()
            outs += [dev.to_host(out), dev.to_host(fs.state), dev.to_host(fs.hist)]
    return outs


def _two_frames_check(dev: Device, prec: str) -> list[np.ndarray]:
    """The frame kernels' fast paths' check: _frames_check at 2x with the learned
    re-modulation and 3x with the blur."""
    return _frames_check(dev, prec, [nets.make_config(2, remod="learned"), nets.make_config(3, remod="blur")],
                         "nsrd inline math selfcheck")


# The lighting's PQ encode on float8 in a kernel of its own (nsrd_encode, -DNSRD_ENCODE8=1),
# not per pixel in nsrd_prepare, and the learned re-modulation's sigmoid likewise (nsrd_alpha),
# not per output pixel in nsrd_finish: PoCL calls its scalar exp, exp2 and log2 out of line.
# With it, the other frame kernels take 8 pixels a work-item on float8 too (nsrd_prepare8
# with nsrd_warp_state8, nsrd_prev8, and nsrd_finish8 with nsrd_decode folded in),
# bit-identical to the per-pixel ones (tests/test_method_nsrd.py). Checked
# against the per-pixel encode on the same two frames, within the frame step's tolerance
# (the float8 and scalar exp2 / log2 need not round alike).
ENCODE8 = "nsrd.encode8"


def _pocl(dev) -> bool:
    from ...ops.conv import builtin_free
    return bool(builtin_free(dev))


selfcheck.register(selfcheck.FastPath(
    INLINE_MATH, KERNEL, {"CLSS_INLINE_MATH": 1}, {"CLSS_INLINE_MATH": 0}, check=_two_frames_check,
    tolerance=lambda prec: EXACT if prec != "fp16-native" else DEFAULT_TOL[prec],
    what="floor, clamp, min, max and isfinite in the frame kernels as plain arithmetic / the builtins",
    applies=_pocl))

# The guided base on float8 lanes in nsrd_finish8 (-DNSRD_GUIDED8=1), its weights' exp on
# pq.h's plain-arithmetic exp2: lane by lane, the scalar guided_base made 16 out-of-line
# exp calls an output pixel (280 of the 325 ms of the shipped x2 weights' output stage at
# 1080p on pip's PoCL 3.0). Checked against the lane-by-lane form on the two frames of
# _guided_check, within the frame step's tolerance (the exp differs in its last bits).
GUIDED8 = "nsrd.guided8"


def _guided_check(dev: Device, prec: str) -> list[np.ndarray]:
    """_frames_check through the guided base (the shipped weights' form) with the learned
    re-modulation, at 2x and 3x."""
    return _frames_check(dev, prec, [nets.make_config(s, remod="learned", base="guided") for s in (2, 3)],
                         "nsrd guided8 selfcheck")


selfcheck.register(selfcheck.FastPath(
    ENCODE8, KERNEL, {"NSRD_ENCODE8": 1}, {"NSRD_ENCODE8": 0}, check=_two_frames_check,
    tolerance=DEFAULT_TOL.__getitem__,
    what="the lighting's PQ encode, the re-modulation's sigmoid and the other frame kernels on float8, "
         "8 pixels a work-item (nsrd_encode, nsrd_alpha, nsrd_prepare8, nsrd_warp_state8, nsrd_prev8, "
         "nsrd_finish8) / per pixel",
    applies=_pocl))

selfcheck.register(selfcheck.FastPath(
    GUIDED8, KERNEL, {"NSRD_GUIDED8": 1}, {"NSRD_GUIDED8": 0}, check=_guided_check,
    tolerance=DEFAULT_TOL.__getitem__,
    what="the guided base on float8 lanes in nsrd_finish8, its weights' exp on pq.h's plain-arithmetic "
         "exp2 / lane by lane with the library's exp",
    applies=_pocl))
