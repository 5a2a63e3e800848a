"""Whole-network and whole-frame bench cases: clss.Model against onnxruntime on the
same network graph, and clss.Upscaler's device path against onnxruntime running
the frame-step ONNX graph (clss/methods/clss/oracle.py). Imported only once those
modules exist."""
from __future__ import annotations

import numpy as np
import onnx

from clss.device import storage_dtype
from clss.methods.clss.networks import pad16
from clss.ops.base import rng
from clss.tolerance import Tolerance

from .cases import BenchCase, Setup, _nbytes, _rounded, smooth_motion

# Whole networks and frames chain dozens of roundings and an in-graph bilinear and
# sigmoid; the check is a sanity check here (the op and pipeline tests are the strict ones).
NET_TOL = {"fp32": Tolerance(1e-4, 1e-3), "fp16": Tolerance(2e-2, 2e-2), "fp16-native": Tolerance(5e-2, 5e-2)}


def model_case(name, model: onnx.ModelProto, input_shapes: dict, tier: str, flops: float,
               quick: bool = False) -> BenchCase:
    def build(dev, prec, params):
        from clss.model import Model
        m = Model(model, device=dev, precision=prec, input_shapes=input_shapes)
        host = {k: _rounded(np.abs(rng("bench net", name, k).standard_normal(s, dtype=np.float32)), prec)
                for k, s in input_shapes.items()}
        d_in = m.upload(host)
        out_shapes = list(m.output_shapes.values())
        st = storage_dtype(prec)
        # Compulsory traffic of a whole network: inputs, weights, outputs once.
        weights = sum(_nbytes(t.dims, np.float32) for t in model.graph.initializer)
        eng = sum(float(a.nbytes) for a in d_in.values()) + weights * st.itemsize / 4 + \
            sum(_nbytes(s, st) for s in out_shapes)
        ort = sum(float(v.nbytes) for v in host.values()) + weights + sum(_nbytes(s, np.float32) for s in out_shapes)
        twin = _static(model, input_shapes)

        def run():
            return list(m.run_device(d_in).values())
        return Setup(run, twin, host, NET_TOL[prec], eng, ort, release=d_in.clear,
                     note=f"{len(m.graph.nodes)} steps after fusion")
    shape = ", ".join(f"{k}: {'x'.join(map(str, s))}" for k, s in input_shapes.items())
    return BenchCase(name, "network", "network", tier, float(flops), build, quick=quick, shape=shape)


def _static(model: onnx.ModelProto, input_shapes: dict) -> onnx.ModelProto:
    """The model with its symbolic input dims fixed, so onnxruntime plans for the shape."""
    m = onnx.ModelProto()
    m.CopyFrom(model)
    for vi in m.graph.input:
        if vi.name in input_shapes:
            for d, s in zip(vi.type.tensor_type.shape.dim, input_shapes[vi.name]):
                d.Clear()
                d.dim_value = int(s)
    return m


def synthetic_frame(h: int, w: int):
    """A render-resolution frame in the contract's image layout: HDR-ish colour,
    reversed-Z depth in (0, 1], smooth motion in render pixels."""
    g = rng("bench frame", h, w)
    color = g.uniform(0.0, 4.0, (h, w, 3)).astype(np.float32)
    depth = g.uniform(0.05, 1.0, (h, w)).astype(np.float32)
    motion = smooth_motion(("bench frame m", h, w), (1, 2, h, w), 2.0)[0].transpose(1, 2, 0).copy()
    return color, depth, motion


BENCH_JITTER = (0.25, -0.125)


def frame_runner(dev, up, render_size, output_hw):
    """(run, (color, depth, motion)): a frame step's `step_device` on the synthetic frame,
    for a BenchCase. The frame step (and its clss.Models) is built here, outside the
    bench's capture of the device (the Model's planning device copies the Device's
    attributes); the first timed frame is a reset (what the oracle computes from a zero
    history), the others carry the history, as a running game does."""
    color, depth, motion = synthetic_frame(*render_size)
    jitter = np.array(BENCH_JITTER, np.float32)
    d = [dev.to_device(a, "fp32") for a in (color, depth, motion)]
    out = dev.empty(tuple(output_hw) + (3,), dtype=np.float32)
    up.step_device(*d, jitter, reset=True, out=out)
    calls = [0]

    def run():
        up.step_device(*d, jitter, reset=calls[0] == 0, out=out)
        calls[0] += 1
        return [out]
    return run, (color, depth, motion)


def median_ms(fn, frames: int) -> float:
    """The median wall milliseconds of `frames` calls of fn (warm it first)."""
    import time
    ts = []
    for _ in range(frames):
        t = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t) * 1e3)
    return float(np.median(ts))


def frame_case(mode: str, render_size, scale: float, tier: str) -> BenchCase:
    from clss.methods.clss.oracle import build_frame_graph
    from clss.pipeline.contract import output_size
    from clss.methods.clss.networks import build_classifier, build_composition, frame_flops
    h, w = render_size
    H, W = output_size(h, w, scale)
    flops = 0.0
    if mode == "net":
        flops = float(sum(frame_flops(build_classifier(), build_composition(), H, W)))

    def build(dev, prec, params):
        from clss import Upscaler
        cls = build_classifier(height=pad16(H), width=pad16(W)) if mode == "net" else None
        comp = build_composition() if mode == "net" else None
        up = Upscaler(scale=scale, mode=mode, device=dev, precision=prec,
                      classifier=cls, composition=comp)
        run, (color, depth, motion) = frame_runner(dev, up, (h, w), (H, W))
        twin = build_frame_graph("rule" if mode == "rules" else mode, (h, w), scale, cls,
                                 comp)
        names = {i.name for i in twin.graph.input}
        feeds = {"color": color.transpose(2, 0, 1)[None].copy(), "depth": depth[None, None].copy(),
                 "motion": motion.transpose(2, 0, 1)[None].copy(),
                 "jitter": np.array(BENCH_JITTER, np.float32),
                 "reset": np.array([1.0], np.float32), "reactive": np.zeros((1, 1, h, w), np.float32),
                 "history": np.zeros((1, 16, H, W), np.float32),
                 "prev": np.zeros((1, 4, h, w), np.float32)}     # net mode's render-res state
        feeds = {k: v for k, v in feeds.items() if k in names}
        ort_out = [o.name for o in twin.graph.output]
        # Compulsory traffic per frame: the render-res inputs, the history (net: and prev)
        # read and written, the output written.
        st = storage_dtype(prec).itemsize
        io = color.nbytes + depth.nbytes + motion.nbytes + H * W * 3 * 4
        if mode == "net":       # and its render-res state prev read and written (float)
            io += 2 * 4 * h * w * 4
        eng = io + 2 * 16 * H * W * st
        ort = io + 2 * 16 * H * W * 4
        return Setup(run, twin, feeds, NET_TOL[prec], eng, ort,
                     post=lambda outs: [outs[0].transpose(2, 0, 1)[None]],
                     out_index=ort_out.index("output") if "output" in ort_out else 0,
                     note=(f"classifier on {up.classifier_backend_name}" if mode == "net" else ""))
    # Not in --quick: at 540p a net-mode frame costs seconds on a 2-core CPU.
    return BenchCase(f"frame step {mode}", "frame", "frame", tier, flops, build,
                     shape=f"{h}x{w}->{H}x{W}", precisions=("fp32", "fp16"))
