"""Conformance cases of NSS's frame kernels (clss/methods/nss/nss.cl, launched by
clss/methods/nss/frame.py): each kernel against its ONNX twin from the method's oracle
(clss/methods/nss/oracle.py: inputs_graph, depth_graph, pre_graph, post_graph, the same
nodes as the whole-frame twin). The depth reconstruction has two paths with one twin: the
portable nss_depth_gather and the atomic one (kernels/scatter.cl's fill_u32 + scatter_depth,
as frame.py launches them). They run with the scatter family's cases (the atomic path is
its scatter_depth; clss/verify/cases/scatter.py appends them), so `clss verify` checks them."""
from __future__ import annotations

import numpy as np

from ...methods.nss import networks as nets
from ...methods.nss import oracle
from ...methods.nss.frame import KERNEL, SCATTER, kernel_defines
from ...ops.base import rng
from ...tolerance import Tolerance
from ..case import Case

# The float32 planes (colour, depth, motion, history, derivative state) stay float32 in
# every precision, as frame.py keeps them; only the network's tensors (tp, kpn, x) are T.
_F32 = ("color", "depth", "motion", "recon", "hist", "deriv", "keep")
_TAPS = ("taps", "tent", "kq", "centre", "valid")

# nss_post: the 4x4 / 6x6 weighted moments and the Karis inverse (1 / (1 - max), up to
# 1 / (1 - TM_MAX)) amplify the float32 summation order's rounding; fp16: x and kpn / tp
# are half (the twin gets the same half-rounded kpn / tp; x is rounded on the store).
_TOL_POST = {"fp32": Tolerance(1e-4, 1e-4), "fp16": Tolerance(2e-3, 2e-3),
             "fp16-native": Tolerance(1e-2, 1e-2)}
# the depth paths compute in float32 whatever the precision: equal to the twin in every
# precision (not Case.exact, whose reference is rounded to half in half modes)
_TOL_DEPTH = {p: Tolerance(0.0, 0.0) for p in ("fp32", "fp16", "fp16-native")}
_TOL_PRE = {"fp32": Tolerance(1e-5, 1e-4), "fp16": Tolerance(2e-3, 2e-3),
            "fp16-native": Tolerance(1e-2, 1e-2)}


def _cfg(quality="mid"):
    return nets.make_config(2, quality)


def _motion(g, h, w, reach):
    """A smooth field (constant + small noise): the gather equals the scatter wherever the
    motion varies by less than GATHER_RADIUS around a contributor."""
    base = g.uniform(-reach, reach, (1, 2, 1, 1))
    return (base + g.uniform(-0.4, 0.4, (1, 2, h, w))).astype(np.float32)


def inputs_case(h, w, depth_inverted=True, motion_scale=(1.0, 1.0), exposure=1.0) -> Case:
    g = rng("nss.inputs", h, w, depth_inverted, motion_scale, exposure)
    color = g.uniform(0, 8, (h, w, 3)).astype(np.float32)
    depth = g.uniform(0.05, 1.0, (h, w)).astype(np.float32)
    motion = g.uniform(-3, 3, (h, w, 2)).astype(np.float32)
    color[0, 0, 1], depth[-1, -1], motion[0, -1, 0] = np.nan, np.inf, -np.inf
    color[-1, 0, 2] = 7.0e4                                     # clamped to COLOR_MAX

    def run(dev, prec, inputs):
        k = dev.kernel(KERNEL, "nss_inputs", prec, **kernel_defines(_cfg()))
        arr = {n: dev.to_device(inputs[n], "fp32") for n in ("color", "depth", "motion")}
        col, dz, mv = (dev.empty(s, dtype=np.float32) for s in ((3, h, w), (h, w), (2, h, w)))
        dev.launch(k, (w, h), [arr["color"].data, arr["depth"].data, arr["motion"].data,
                               col.data, dz.data, mv.data, np.int32(w), np.int32(h),
                               np.int32(bool(depth_inverted)), np.float32(motion_scale[0]),
                               np.float32(motion_scale[1]), np.float32(1.0 / exposure)])
        return [dev.to_host(a) for a in (col, dz, mv)]

    variant = (f"{h}x{w}" + ("" if depth_inverted else " forward-Z")
               + ("" if exposure == 1.0 else f" exposure {exposure:g}")
               + ("" if tuple(motion_scale) == (1.0, 1.0) else " motion x{:g},{:g}".format(*motion_scale)))
    return Case("nss_inputs", variant, {"color": color, "depth": depth, "motion": motion},
                oracle.inputs_graph((h, w), depth_inverted, motion_scale, exposure), run,
                no_round=("color", "depth", "motion"))


def depth_case(h, w, path="gather", reach=1.5) -> Case:
    g = rng("nss.depth", h, w, path, reach)
    depth = g.uniform(0.05, 1.0, (1, 1, h, w)).astype(np.float32)
    motion = _motion(g, h, w, reach)

    def run(dev, prec, inputs):
        dz = dev.to_device(inputs["depth"], "fp32")
        mv = dev.to_device(inputs["motion"], "fp32")
        recon = dev.empty((h, w), dtype=np.uint32)
        i32, wmin = np.int32, np.float32(nets.SCATTER_WMIN)
        if path == "gather":
            k = dev.kernel(KERNEL, "nss_depth_gather", prec, **kernel_defines(_cfg()))
            dev.launch(k, (w, h), [dz.data, mv.data, recon.data, i32(w), i32(h), wmin])
        else:   # frame.py's atomic path: cleared to the far plane, then scattered (max)
            opts = {"DEPTH_MAX": 1}
            dev.launch(dev.kernel(SCATTER, "fill_u32", "fp32", **opts), (h * w,),
                       [recon.data, np.uint32(0), i32(h * w)])
            dev.launch(dev.kernel(SCATTER, "scatter_depth", "fp32", **opts), (w, h, 1),
                       [dz.data, mv.data, recon.data, i32(h), i32(w), i32(1), wmin])
        return [dev.to_host(recon).view(np.float32).reshape(1, 1, h, w)]

    return Case(f"nss_depth_{path}", f"{h}x{w} reach{reach:g}",
                {"depth": depth, "motion": motion}, oracle.depth_graph((h, w)), run,
                tol=dict(_TOL_DEPTH), no_round=("depth", "motion"))


def _state(g, h, w):
    H, W, hp, wp = 2 * h, 2 * w, nets.pad8(h), nets.pad8(w)
    return {"color": g.uniform(0, 4, (1, 3, h, w)).astype(np.float32),
            "motion": _motion(g, h, w, 1.5),
            "hist": g.uniform(0, 4, (1, 3, H, W)).astype(np.float32),
            "tp": g.uniform(0, 1, (1, nets.TEMPORAL, hp, wp)).astype(np.float32)}


def pre_case(h, w, keep=1.0) -> Case:
    g = rng("nss.pre", h, w, keep)
    hp, wp = nets.pad8(h), nets.pad8(w)
    x = _state(g, h, w)
    x["depth"] = g.uniform(0.05, 1.0, (1, 1, h, w)).astype(np.float32)
    # the reconstructed depth: the current one, nearer in places (disocclusions), far in others
    recon = x["depth"] * g.choice(np.float32([1.0, 1.0, 1.3, 0.97]), (1, 1, h, w))
    recon[g.random((1, 1, h, w)) < 0.1] = 0.0
    x["recon"] = recon.astype(np.float32)
    x["deriv"] = np.concatenate([g.uniform(0, 1, (1, 1, h, w)), g.uniform(0, 1, (1, 1, h, w))],
                                axis=1).astype(np.float32)
    x["keep"] = np.array([keep], np.float32)

    def run(dev, prec, inputs):
        k = dev.kernel(KERNEL, "nss_pre", prec, **kernel_defines(_cfg()))
        f32 = lambda n: dev.to_device(inputs[n][0], "fp32")  # noqa: E731
        col, dz, mv, hist, deriv = (f32(n) for n in ("color", "depth", "motion", "hist", "deriv"))
        recon = dev.to_device(np.ascontiguousarray(inputs["recon"][0, 0]).view(np.uint32))
        tp = dev.to_device(inputs["tp"], prec)
        deriv_new = dev.empty((2, h, w), dtype=np.float32)
        xo = dev.empty((1, nets.IN, hp, wp), prec)
        dev.launch(k, (wp, hp), [col.data, dz.data, mv.data, recon.data, hist.data, tp.data,
                                 deriv.data, deriv_new.data, xo.data, np.int32(w), np.int32(h),
                                 np.int32(wp), np.int32(hp), np.float32(keep)])
        return [dev.to_host(xo), dev.to_host(deriv_new)[None]]

    return Case("nss_pre", f"{h}x{w}" + (" reset" if not keep else ""), x,
                oracle.pre_graph((h, w)), run, tol=dict(_TOL_PRE), no_round=_F32)


def post_case(h, w, quality="mid", jitter=(0.25, -0.125), keep=1.0) -> Case:
    g = rng("nss.post", h, w, quality, jitter, keep)
    cfg = _cfg(quality)
    K = int(cfg["kpn"])
    hp, wp = nets.pad8(h), nets.pad8(w)
    x = _state(g, h, w)
    x["kpn"] = g.uniform(0, 1, (1, K * K, hp // 4, wp // 4)).astype(np.float32)
    x["kpn"][0, 0, 0, 0] = 0.0                                     # below KPN_EPS
    x["keep"] = np.array([keep], np.float32)
    x.update(oracle.tap_feeds(cfg, (h, w), jitter))
    H, W = 2 * h, 2 * w

    def run(dev, prec, inputs):
        k = dev.kernel(KERNEL, "nss_post", prec, **kernel_defines(cfg))
        col, mv, hist = (dev.to_device(inputs[n][0], "fp32") for n in ("color", "motion", "hist"))
        kpn, tp = dev.to_device(inputs["kpn"], prec), dev.to_device(inputs["tp"], prec)
        hist_new = dev.empty((3, H, W), dtype=np.float32)
        out = dev.empty((H, W, 3), dtype=np.float32)
        f = np.float32
        dev.launch(k, (W, H), [col.data, mv.data, kpn.data, tp.data, hist.data, hist_new.data,
                               out.data, np.int32(w), np.int32(h), np.int32(wp), np.int32(hp),
                               f(jitter[0]), f(jitter[1]), f(keep), f(1.0)])
        hn = dev.to_host(hist_new)
        o = dev.to_host(out)
        if not np.array_equal(o.transpose(2, 0, 1), hn):
            raise AssertionError("nss_post: out (exposure 1) differs from hist_new")
        return [hn[None]]

    return Case("nss_post", f"{h}x{w} {quality} (K={K}) jitter {jitter[0]:g},{jitter[1]:g}"
                + (" reset" if not keep else ""), x, oracle.post_graph((h, w), K), run,
                tol=dict(_TOL_POST), no_round=_F32 + _TAPS)


def cases(level: str = "quick") -> list[Case]:
    out = [inputs_case(5, 7), depth_case(5, 7, "gather"), depth_case(5, 7, "atomic"),
           pre_case(5, 7), post_case(5, 7)]
    if level == "tiny":
        return out
    out += [inputs_case(13, 17, False, (0.5, -2.0), 2.0), depth_case(13, 17, "gather", 3.0),
            depth_case(13, 17, "atomic", 3.0), pre_case(13, 17), pre_case(9, 11, keep=0.0),
            post_case(13, 17, "mid", (-0.375, 0.4375)), post_case(9, 11, "high"),
            post_case(9, 11, "mid", (0.0, 0.0), keep=0.0)]
    if level == "quick":
        return out
    return out + [inputs_case(1, 1), depth_case(1, 1, "gather"), depth_case(1, 1, "atomic"),
                  depth_case(31, 27, "gather", 12.0), depth_case(31, 27, "atomic", 12.0),
                  pre_case(1, 1), pre_case(31, 27), post_case(1, 1, "high"),
                  post_case(31, 27, "high", (0.49, -0.49))]
