"""NSRR's bench room: its two networks (features, reconstruct) and every conv layer in them
through clss.Model / clss.ops.conv against onnxruntime on the same graphs, and its frame step
as a bench case, clss.Upscaler(method="nsrr")'s device path against onnxruntime on the same
step's whole-frame ONNX graph (clss/methods/nsrr/oracle.py), at 540p -> 1080p (2x) and
270p -> 1080p (4x). The suite finds it by the room's name (bench/methods/__init__.py).

The networks and the frame steps run the shipped weights' configuration (depth rejection; at 4x the rules' base), as a user gets them (before 2026-11-29 afternoon: the untrained default configuration, whose output stage is lighter: docs/benchmarks.md).

    python -m bench.methods.nsrr [fp32|fp16]
"""
from __future__ import annotations

import numpy as np

from clss.device import storage_dtype

from ..cases import BenchCase
from ..netcases import (BENCH_JITTER, FULL_ONLY_NETWORKS, frame_bench_case, frame_runner, frame_setup,
                        median_ms, network_cases, synthetic_frame)

# The host-wait bench (bench/hostwait.py) rows this method.
HOST_WAITS = ("nsrr",)
FULL_ONLY = FULL_ONLY_NETWORKS
# render size and scale per tier (named by the output, bench/cases.py TIERS): the issue's
# 1080p outputs, and a tiny smoke shape
NSRR_TIERS = {"1080p": (((540, 960), 2.0), ((270, 480), 4.0)), "540p": (((270, 480), 2.0), ((135, 240), 4.0)),
              "tiny": (((16, 32), 2.0), ((16, 32), 4.0))}


def nsrr_frame_case(render_size, scale: float, tier: str, weights=None) -> BenchCase:
    from clss.methods.nsrr import networks as nets
    from clss.methods.nsrr.oracle import build_graph, frame_feeds
    from clss.methods.nsrr.upscaler import load_weights
    from clss.pipeline.contract import output_size
    h, w = render_size
    H, W = output_size(h, w, scale)
    cfg, wts, _ = load_weights(weights, scale)
    flops = 2.0 * nets.macs_per_pixel(cfg, scale)["total"] * H * W

    def build(dev, prec, params):
        from clss import Upscaler
        up = Upscaler(method="nsrr", scale=scale, device=dev, precision=prec, weights=(cfg, wts),
                      profile=True)
        run, (color, depth, motion) = frame_runner(dev, up, (h, w), (H, W))
        jitter = np.array(BENCH_JITTER, np.float32)
        twin = build_graph((h, w), scale, cfg, wts)
        n = cfg["n_prev"]
        x = {"color": color.transpose(2, 0, 1)[None].copy(), "depth": depth[None, None].copy(),
             "motion": motion.transpose(2, 0, 1)[None].copy(), "jitter": jitter}
        # the first timed frame is a reset (frame_runner), as this feed
        feeds = frame_feeds(cfg, x, np.zeros((1, nets.FEAT * n, H, W), np.float32), True)
        st = storage_dtype(prec).itemsize
        io = color.nbytes + depth.nbytes + motion.nbytes + H * W * 3 * 4
        # the history read and written, the stack written and read
        hist = nets.FEAT * n * H * W
        stack = nets.FEAT * (n + 1) * H * W
        return frame_setup(run, twin, feeds, prec, io + (2 * hist + 2 * stack) * st,
                           io + (2 * hist + 2 * stack) * 4, note=f"widths {cfg['name']}", up=up)
    return frame_bench_case("nsrr", scale, tier, flops, build, (h, w), (H, W))


def networks(tier: str, weights=None) -> list:
    """(net, variant, model) of the two networks, built as each frame step of the tier
    builds them (clss/methods/nsrr/frame.py): features at the render size, reconstruct at
    the output size padded to a multiple of 4."""
    from clss.methods.nsrr import networks as nets
    from clss.methods.nsrr.frame import pad4
    from clss.methods.nsrr.upscaler import load_weights
    from clss.pipeline.contract import output_size
    out = []
    for (h, w), scale in NSRR_TIERS.get(tier, ()):
        cfg, wts, _ = load_weights(weights, scale)
        H, W = output_size(h, w, scale)
        out += [("features", f"x{scale:g}", nets.build_features(cfg, wts, h, w)),
                ("reconstruct", f"x{scale:g}", nets.build_reconstruct(cfg, wts, pad4(H), pad4(W)))]
    return out


def cases(tier: str) -> list:
    """The room's bench cases at one shape tier (none at a tier it has no shape for): the
    networks and their layers, then the frame steps."""
    return (network_cases("nsrr", tier, networks(tier))
            + [nsrr_frame_case(rs, s, tier) for rs, s in NSRR_TIERS.get(tier, ())])


def measure(render_size, scale, prec="fp32", frames=3, weights=None, ort_threads=2, ort=True):
    """Warm wall ms of the NSRR frame step (median of `frames` after one warm-up), its
    per-stage event times (the paper's Table 2 breakdown) and onnxruntime's wall ms on
    the whole-frame graph, same machine, same run."""
    from clss import Upscaler
    from clss.device import get_device
    from clss.pipeline.contract import output_size
    dev = get_device()
    h, w = render_size
    H, W = output_size(h, w, scale)
    color, depth, motion = synthetic_frame(h, w)
    up = Upscaler(method="nsrr", scale=scale, device=dev, precision=prec, weights=weights,
                  profile=True)
    d = [dev.to_device(a, "fp32") for a in (color, depth, motion)]
    out = dev.empty((H, W, 3), dtype=np.float32)
    up.step_device(*d, BENCH_JITTER, reset=True, out=out)
    up.reset_timings()
    ms = median_ms(lambda: up.step_device(*d, BENCH_JITTER, out=out), frames)
    res = {"shape": f"{h}x{w}->{H}x{W}", "precision": prec, "ms": ms,
           "stages_ms": up.stage_ms(), "widths": up.cfg["name"]}
    if ort:
        from clss.methods.nsrr.oracle import OracleNsrr
        o = OracleNsrr((h, w), scale, weights=(up.cfg, up.weights), threads=ort_threads)
        depth_c = depth
        o.step(color, depth_c, motion, BENCH_JITTER, reset=True)
        res["ort_ms"] = median_ms(lambda: o.step(color, depth_c, motion, BENCH_JITTER), frames)
        res["speedup"] = res["ort_ms"] / res["ms"]
    return res


if __name__ == "__main__":
    import json
    import sys
    prec = sys.argv[1] if len(sys.argv) > 1 else "fp32"
    for rs, s in NSRR_TIERS["1080p"][::-1]:
        print(json.dumps(measure(rs, s, prec), indent=None), flush=True)
