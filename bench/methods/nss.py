"""NSS's bench room: its network and every conv layer in it through clss.Model /
clss.ops.conv against onnxruntime on the same graphs, and its frame step as a bench case,
clss.Upscaler(method="nss")'s device path against onnxruntime on the same step's
whole-frame ONNX graph (clss/methods/nss/oracle.py), at 540p -> 1080p (2x) and tiny.
The suite finds the room by its name (bench/methods/__init__.py).

    python -m bench.methods.nss [fp32|fp16] [1080p|tiny]
"""
from __future__ import annotations

import numpy as np

from clss.device import storage_dtype

from ..cases import BenchCase
from ..netcases import (BENCH_JITTER, FULL_ONLY_NETWORKS, frame_bench_case, frame_runner, frame_setup,
                        median_ms, network_cases, synthetic_frame)

# The host-wait bench (bench/hostwait.py) rows this method (its frame step enqueues
# inputs, depth, pre, the network and post with no host wait; the seeded init where the
# package has no weights).
HOST_WAITS = ("nss",)
FULL_ONLY = FULL_ONLY_NETWORKS
NSS_TIERS = {"1080p": ((540, 960),), "540p": ((270, 480),), "tiny": ((16, 32),)}


def _weights(weights):
    from clss.methods.nss.upscaler import load_weights
    cfg, wts, _ = load_weights(weights, 2.0, allow_untrained=True)
    return cfg, wts


def nss_frame_case(render_size, tier: str, weights=None) -> BenchCase:
    from clss.methods.nss import networks as nets
    from clss.methods.nss.oracle import build_graph, frame_feeds, zero_state
    h, w = render_size
    H, W = 2 * h, 2 * w
    cfg, wts = _weights(weights)
    flops = 2.0 * nets.macs_per_pixel(cfg) * nets.pad8(h) * nets.pad8(w)

    def build(dev, prec, params):
        from clss import Upscaler
        up = Upscaler(method="nss", scale=2, device=dev, precision=prec, weights=(cfg, wts),
                      profile=True)
        run, (color, depth, motion) = frame_runner(dev, up, (h, w), (H, W))
        jitter = np.array(BENCH_JITTER, np.float32)
        twin = build_graph((h, w), cfg, wts)
        x = {"color": color.transpose(2, 0, 1)[None].copy(), "depth": depth[None, None].copy(),
             "motion": motion.transpose(2, 0, 1)[None].copy(), "jitter": jitter}
        feeds = frame_feeds(cfg, x, zero_state(cfg, (h, w)), True)
        st = storage_dtype(prec).itemsize
        io = color.nbytes + depth.nbytes + motion.nbytes + H * W * 3 * 4
        hist = (2 * 3 * H * W + 2 * 2 * h * w) * 4
        net_io = (nets.IN + 2 * nets.TEMPORAL) * nets.pad8(h) * nets.pad8(w)
        return frame_setup(run, twin, feeds, prec, io + hist + net_io * st,
                           io + hist + net_io * 4, note=f"quality {cfg['quality']}", up=up)
    return frame_bench_case("nss", 2.0, tier, flops, build, (h, w), (H, W))


def networks(tier: str, weights=None) -> list:
    """(net, variant, model) of the network at each render size of the tier, padded to
    multiples of 8 as the frame step builds it (clss/methods/nss/frame.py)."""
    from clss.methods.nss import networks as nets
    cfg, wts = _weights(weights)
    return [("net", "x2", nets.build_network(cfg, wts, nets.pad8(h), nets.pad8(w)))
            for h, w in NSS_TIERS.get(tier, ())]


def cases(tier: str) -> list:
    """The room's bench cases at one shape tier: the network and its layers, then the
    frame step."""
    return (network_cases("nss", tier, networks(tier))
            + [nss_frame_case(rs, tier) for rs in NSS_TIERS.get(tier, ())])


def measure(render_size, prec="fp32", frames=3, weights=None, ort_threads=2, ort=True):
    """Warm wall ms of the NSS frame step (median of `frames` after one warm-up), its
    per-stage event times, and onnxruntime's wall ms on the whole-frame graph, same
    machine, same run."""
    from clss import Upscaler
    from clss.device import get_device
    dev = get_device()
    h, w = render_size
    color, depth, motion = synthetic_frame(h, w)
    d = [dev.to_device(a, "fp32") for a in (color, depth, motion)]
    up = Upscaler(method="nss", scale=2, device=dev, precision=prec, weights=weights,
                  allow_untrained=True, profile=True)
    out = dev.empty((2 * h, 2 * w, 3), dtype=np.float32)
    up.step_device(*d, BENCH_JITTER, reset=True, out=out)
    up.reset_timings()
    ms = median_ms(lambda: up.step_device(*d, BENCH_JITTER, out=out), frames)
    res = {"shape": f"{h}x{w}->{2 * h}x{2 * w}", "precision": prec, "ms": ms,
           "stages_ms": up.stage_ms(), "trained": up.trained}
    if ort:
        from clss.methods.nss.oracle import OracleNss
        o = OracleNss((h, w), 2.0, weights=(up.cfg, up.weights), threads=ort_threads)
        o.step(color, depth, motion, BENCH_JITTER, reset=True)
        res["ort_ms"] = median_ms(lambda: o.step(color, depth, motion, BENCH_JITTER), frames)
        res["speedup"] = res["ort_ms"] / res["ms"]
    return res


if __name__ == "__main__":
    import json
    import sys
    prec = sys.argv[1] if len(sys.argv) > 1 else "fp32"
    tier = sys.argv[2] if len(sys.argv) > 2 else "1080p"
    for rs in NSS_TIERS[tier]:
        print(json.dumps(measure(rs, prec), indent=None), flush=True)
