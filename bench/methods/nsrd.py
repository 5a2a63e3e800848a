"""NSRD's bench room: its network and every conv layer in it through clss.Model /
clss.ops.conv against onnxruntime on the same graphs, and its frame step as a bench case,
clss.Upscaler(method="nsrd")'s device path against onnxruntime on the same step's
whole-frame ONNX graph (clss/methods/nsrd/oracle.py), at 540p -> 1080p (2x) and
270p -> 1080p (4x). NSRD reads G-buffers: the synthetic frame gets a synthetic material
(render and output resolution) and normal (`synthetic_gbuffers`, which the host-wait bench
feeds it too). The suite finds the room by its name (bench/methods/__init__.py).

The networks and the frame steps run the shipped weights' configuration (guided base, learned re-modulation, warped state), as a user gets them (before 2026-11-29 afternoon: the untrained default configuration, whose output stage is lighter: docs/benchmarks.md).

    python -m bench.methods.nsrd [fp32|fp16] [1080p|tiny]
"""
from __future__ import annotations

import numpy as np

from clss.device import storage_dtype

from ..cases import BenchCase
from ..netcases import (BENCH_JITTER, FULL_ONLY_NETWORKS, frame_bench_case, frame_setup, median_ms,
                        network_cases, synthetic_frame)

# The host-wait bench (bench/hostwait.py) rows this method.
HOST_WAITS = ("nsrd",)
FULL_ONLY = FULL_ONLY_NETWORKS
NSRD_TIERS = {"1080p": (((540, 960), 2.0), ((270, 480), 4.0)), "540p": (((270, 480), 2.0), ((135, 240), 4.0)),
              "tiny": (((16, 32), 2.0), ((16, 32), 4.0))}


def synthetic_gbuffers(h: int, w: int, scale: float) -> dict:
    """albedo [h,w,3], normal [h,w,3] (unit), albedo_hr [H,W,3]: a seeded texture whose
    render-resolution samples are the output-resolution one's every s-th pixel."""
    s = int(scale)
    g = np.random.default_rng([21, h, w, s])
    ahr = g.uniform(0.0, 1.0, (h * s, w * s, 3)).astype(np.float32)
    n = g.normal(0, 1, (h, w, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return {"albedo": np.ascontiguousarray(ahr[::s, ::s]), "normal": n, "albedo_hr": ahr}


def _device_inputs(dev, h, w, scale):
    color, depth, motion = synthetic_frame(h, w)
    gb = synthetic_gbuffers(h, w, scale)
    d = [dev.to_device(a, "fp32") for a in (color, depth, motion)]
    dg = {k: dev.to_device(v, "fp32") for k, v in gb.items()}
    return (color, depth, motion), gb, d, dg


def nsrd_frame_case(render_size, scale: float, tier: str, weights=None) -> BenchCase:
    from clss.methods.nsrd import networks as nets
    from clss.methods.nsrd.oracle import build_graph, frame_feeds, zero_state
    from clss.methods.nsrd.upscaler import load_weights
    h, w = render_size
    s = int(scale)
    H, W = h * s, w * s
    cfg, wts, _ = load_weights(weights, scale)
    flops = 2.0 * nets.macs_per_pixel(cfg) * h * w

    def build(dev, prec, params):
        from clss import Upscaler
        up = Upscaler(method="nsrd", scale=scale, device=dev, precision=prec, weights=(cfg, wts),
                      profile=True)
        (color, depth, motion), gb, d, dg = _device_inputs(dev, h, w, scale)
        jitter = np.array(BENCH_JITTER, np.float32)
        out = dev.empty((H, W, 3), dtype=np.float32)
        up.step_device(*d, jitter, reset=True, out=out, **dg)
        calls = [0]

        def run():
            # the first timed frame is a reset (as the oracle's zero state), then history
            up.step_device(*d, jitter, reset=calls[0] == 0, out=out, **dg)
            calls[0] += 1
            return [out]
        twin = build_graph((h, w), cfg, wts)
        x = {"color": color.transpose(2, 0, 1)[None].copy(), "depth": depth[None, None].copy(),
             "motion": motion.transpose(2, 0, 1)[None].copy(), "jitter": jitter}
        feeds = frame_feeds(cfg, x, gb, zero_state(cfg, (h, w)), True)
        st = storage_dtype(prec).itemsize
        io = (color.nbytes + depth.nbytes + motion.nbytes + gb["albedo"].nbytes * 2
              + gb["albedo_hr"].nbytes + H * W * 3 * 4)
        # state and previous output read and written (float32), the network's inputs
        hist = (2 * nets.STATE * h * w + 2 * 3 * H * W) * 4
        net_io = (nets.CUR + nets.WARP + 2 * 3 * s * s + 4 * cfg["hid"]) * h * w
        return frame_setup(run, twin, feeds, prec, io + hist + net_io * st,
                           io + hist + net_io * 4, note=f"widths {cfg['name']}", up=up)
    return frame_bench_case("nsrd", scale, tier, flops, build, (h, w), (H, W))


def networks(tier: str, weights=None) -> list:
    """(net, variant, model) of the network, built as each frame step of the tier builds it
    (clss/methods/nsrd/frame.py): at the render size padded to even; one network per
    scale (its prev input and output are 3 s^2 channels)."""
    from clss.methods.nsrd import networks as nets
    from clss.methods.nsrd.upscaler import load_weights
    out = []
    for (h, w), scale in NSRD_TIERS.get(tier, ()):
        cfg, wts, _ = load_weights(weights, scale)
        out.append(("net", f"x{scale:g}", nets.build_network(cfg, wts, nets.pad2(h), nets.pad2(w))))
    return out


def cases(tier: str) -> list:
    """The room's bench cases at one shape tier (none at a tier it has no shape for): the
    network and its layers, then the frame steps."""
    return (network_cases("nsrd", tier, networks(tier))
            + [nsrd_frame_case(rs, s, tier) for rs, s in NSRD_TIERS.get(tier, ())])


def measure(render_size, scale, prec="fp32", frames=3, weights=None, ort_threads=2, ort=True):
    """Warm wall ms of the NSRD frame step (median of `frames` after one warm-up), its
    per-stage event times, and onnxruntime's wall ms on the whole-frame graph, same
    machine, same run."""
    from clss import Upscaler
    from clss.device import get_device
    dev = get_device()
    h, w = render_size
    s = int(scale)
    H, W = h * s, w * s
    (color, depth, motion), gb, d, dg = _device_inputs(dev, h, w, scale)
    up = Upscaler(method="nsrd", scale=scale, device=dev, precision=prec, weights=weights,
                  profile=True)
    out = dev.empty((H, W, 3), dtype=np.float32)
    up.step_device(*d, BENCH_JITTER, reset=True, out=out, **dg)
    up.reset_timings()
    ms = median_ms(lambda: up.step_device(*d, BENCH_JITTER, out=out, **dg), frames)
    res = {"shape": f"{h}x{w}->{H}x{W}", "precision": prec, "ms": ms,
           "stages_ms": up.stage_ms(), "widths": up.cfg["name"]}
    if ort:
        from clss.methods.nsrd.oracle import OracleNsrd
        o = OracleNsrd((h, w), scale, weights=(up.cfg, up.weights), threads=ort_threads)
        o.step(color, depth, motion, BENCH_JITTER, reset=True, **gb)
        res["ort_ms"] = median_ms(lambda: o.step(color, depth, motion, BENCH_JITTER, **gb), frames)
        res["speedup"] = res["ort_ms"] / res["ms"]
    return res


if __name__ == "__main__":
    import json
    import sys
    prec = sys.argv[1] if len(sys.argv) > 1 else "fp32"
    tier = sys.argv[2] if len(sys.argv) > 2 else "1080p"
    for rs, s in NSRD_TIERS[tier][::-1]:
        print(json.dumps(measure(rs, s, prec), indent=None), flush=True)
