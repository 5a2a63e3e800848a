"""The shader MLP's bench room: its frame step as a bench case, clss.Upscaler(method="mlp")'s
device path (clss/methods/mlp/mlp_upscale.cl: the PQ pass and the fused GEMM + fold kernel, or
the reference pair where the fast path is disabled)
against onnxruntime on the same step's whole-frame ONNX graph (clss/methods/mlp/oracle.py),
at 540p -> 1080p (2x) and 360p -> 1080p (3x), with trained-like (random, non-zero) weights.
The suite finds the room by its name (bench/methods/__init__.py). `measure()` also times one
online training step (clss/methods/mlp/mlp_train.cl) beside the frame step.

    python -m bench.methods.mlp [fp32|fp16] [HxW]
"""
from __future__ import annotations

import numpy as np

from ..cases import BenchCase, Setup
from ..netcases import NET_TOL, frame_bench_case, median_ms, synthetic_frame

# the host-wait bench's row (bench/hostwait.py): wall time against the network kernels'
# event time (the input conversions are not timed)
HOST_WAITS = ("mlp",)

# (render size, scale) per tier, the tier named by the output (bench/cases.py TIERS)
MLP_TIERS = {"1080p": (((540, 960), 2), ((360, 640), 3)), "540p": (((270, 480), 2), ((180, 320), 3)),
             "tiny": (((16, 32), 2), ((16, 32), 3))}


def bench_weights(seed=0) -> dict:
    """Trained-like weights: the seeded init with a non-zero output layer (the zero one
    would make the inverse ramp's input exactly 0), and the jitter input the shipped
    generalists have (transform.JITTER_KEY: fc1's bias per frame)."""
    from clss.methods.mlp import transform as tf
    g = np.random.default_rng(seed)
    t = tf.init_weights(seed)
    t["fc3.weight"] = (g.standard_normal((25, 50)) * 0.1).astype(np.float32)
    t[tf.JITTER_KEY] = (g.standard_normal((50, 2)) * 0.1).astype(np.float32)
    return t


JITTER = (0.25, -0.125)     # the bench frame's jitter


def macs_per_render_pixel(scale) -> int:
    from clss.methods.mlp import transform as tf
    b = tf.block(scale)
    w = tf.WIDTHS
    # three channels; the feature half of layer 1 once per pixel (shared)
    return 3 * (w[0] // 2 * w[1] + w[1] * w[2] + w[2] * b * b) + w[0] // 2 * w[1]


def _depth_hr(h, w, s):
    g = np.random.default_rng(h * 7 + w)
    return g.uniform(0.05, 1.0, (s * h, s * w)).astype(np.float32)


def synthetic_gbuffers(h, w, scale) -> dict:
    """The host-wait bench's G-buffer: the output-resolution depth the MLP reads."""
    return {"depth_hr": _depth_hr(h, w, int(scale))}


def mlp_frame_case(render_size, scale: int, tier: str) -> BenchCase:
    from clss.methods.mlp.oracle import build_graph
    h, w = render_size
    H, W = scale * h, scale * w
    wts = bench_weights()
    flops = 2.0 * macs_per_render_pixel(scale) * h * w

    def build(dev, prec, params):
        from clss import Upscaler
        up = Upscaler(method="mlp", scale=scale, device=dev, precision=prec, weights=wts)
        color, _, _ = synthetic_frame(h, w)
        dhr = _depth_hr(h, w, scale)
        # float32 in and out, as every method's step_device (fp16: converted on the device)
        c_d, f_d = dev.to_device(color), dev.to_device(dhr)
        out = dev.empty((H, W, 3))
        up.step_device(c_d, depth_hr=f_d, jitter=JITTER, out=out)   # builds outside the timed runs

        def run():
            up.step_device(c_d, depth_hr=f_d, jitter=JITTER, out=out)
            return [out]
        twin = build_graph((h, w), scale, {k: (v.astype(np.float16).astype(np.float32)
                                              if prec != "fp32" else v) for k, v in wts.items()})
        st = 2 if prec != "fp32" else 4
        io = (color.size + dhr.size + H * W * 3) * st
        blocks = 3 * (scale + 2) ** 2 * h * w
        # the fused step moves the frame and the PQ planes once; the blocks go through
        # memory only on the reference pair (and onnxruntime)
        return Setup(run, twin, {"color": color, "depth_hr": dhr,
                                 "jitter": np.asarray(JITTER, np.float32)}, NET_TOL[prec],
                     io + 2 * 3 * h * w * 4,
                     io * 4 // st + 2 * blocks * 4, out_index=0)
    return frame_bench_case("mlp", scale, tier, flops, build, (h, w), (H, W))


def cases(tier: str) -> list:
    """The room's bench cases at one shape tier (none at a tier it has no shape for)."""
    return [mlp_frame_case(rs, s, tier) for rs, s in MLP_TIERS.get(tier, ())]


def measure(render_size=(540, 960), scale=2, prec="fp32", frames=3, ort=True, online=True,
            batch=32):
    """Warm wall ms of the frame step (median of `frames` after one warm-up), onnxruntime's
    on the whole-frame graph (default session: all cores), and one online training step
    (`batch` patches; its host part: cutting the patches) per frame, same process."""
    from clss import Upscaler
    from clss.device import get_device
    from clss.methods.mlp import mlp_upscale as ops
    dev = get_device()
    h, w = render_size
    H, W = scale * h, scale * w
    wts = bench_weights()
    color, _, _ = synthetic_frame(h, w)
    dhr = _depth_hr(h, w, scale)
    up = Upscaler(method="mlp", scale=scale, device=dev, precision=prec, weights=wts,
                  online=online, online_batch=batch)
    c_d, f_d = dev.to_device(color), dev.to_device(dhr)
    out = dev.empty((H, W, 3))
    from clss import selfcheck
    fast = int(selfcheck.defines(dev, prec, ops.FAST)["VEC"])
    def frame():
        up.step_device(c_d, depth_hr=f_d, jitter=JITTER, out=out)
        dev.queue.finish()
    frame()
    ms = median_ms(frame, frames)
    res = {"shape": f"{h}x{w}->{H}x{W}", "precision": prec, "vec": fast, "ms": ms,
           "gmacs": macs_per_render_pixel(scale) * h * w / ms / 1e6}
    if online:
        g = np.random.default_rng(1)
        ref = (g.random((H, W, 3)) ** 2 * 4).astype(np.float32)
        def train():
            up.train_step(color, ref, depth_hr=dhr, jitter=JITTER)
            dev.queue.finish()
        train()                                           # builds
        res["online_step_ms"] = median_ms(train, frames)
        res["online_batch"] = batch
        res["online_over_frame"] = res["online_step_ms"] / res["ms"]
    if ort:
        from clss.methods.mlp.oracle import OracleMlp
        o = OracleMlp((h, w), scale, weights=wts, precision=prec)
        o.step(color, jitter=JITTER, depth_hr=dhr)
        res["ort_ms"] = median_ms(lambda: o.step(color, jitter=JITTER, depth_hr=dhr), frames)
        res["speedup"] = res["ort_ms"] / res["ms"]
    return res


if __name__ == "__main__":
    import json
    import sys
    prec = sys.argv[1] if len(sys.argv) > 1 else "fp32"
    rs = tuple(int(v) for v in sys.argv[2].split("x")) if len(sys.argv) > 2 else (540, 960)
    print(json.dumps(measure(rs, 2, prec)), flush=True)
