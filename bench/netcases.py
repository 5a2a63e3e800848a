"""What the methods' bench rooms (bench/methods/) share: a whole network through clss.Model
against onnxruntime on the same graph (`model_case`), a method's networks and every conv
layer in them as cases (`network_cases`), the synthetic render-resolution frame, a frame
step's device path as a timed runner, and the whole-network tolerances."""
from __future__ import annotations

import numpy as np
import onnx

from clss.device import storage_dtype
from clss.ops.base import rng
from clss.tolerance import Tolerance

from .cases import (BenchCase, Setup, _nbytes, _rounded, fixed_inputs, layer_case, layer_flops, layer_key,
                    layer_label, network_layers, smooth_motion)

# Whole networks and frames chain dozens of roundings and an in-graph bilinear and
# sigmoid; the check is a sanity check here (the op and pipeline tests are the strict ones).
NET_TOL = {"fp32": Tolerance(1e-4, 1e-3), "fp16": Tolerance(2e-2, 2e-2), "fp16-native": Tolerance(5e-2, 5e-2)}

# A room's FULL_ONLY (bench/methods/__init__.py) where its networks are the paper-sized ones:
# dozens of cases of seconds each would make the default level take the better part of an hour.
FULL_ONLY_NETWORKS = ("its networks, their conv layers and its frame steps take minutes at full-HD "
                      "output on a CPU")


def model_case(name, model: onnx.ModelProto, input_shapes: dict, tier: str, flops: float,
               quick: bool = False) -> BenchCase:
    def build(dev, prec, params):
        from clss.model import Model
        m = Model(model, device=dev, precision=prec, input_shapes=input_shapes)
        host = seeded_feeds(name, input_shapes, prec)
        d_in = m.upload(host)
        out_shapes = list(m.output_shapes.values())
        st = storage_dtype(prec)
        # Compulsory traffic of a whole network: inputs, weights, outputs once.
        weights = sum(_nbytes(t.dims, np.float32) for t in model.graph.initializer)
        eng = sum(float(a.nbytes) for a in d_in.values()) + weights * st.itemsize / 4 + \
            sum(_nbytes(s, st) for s in out_shapes)
        ort = sum(float(v.nbytes) for v in host.values()) + weights + sum(_nbytes(s, np.float32) for s in out_shapes)
        twin = fixed_inputs(model, input_shapes)

        # the outputs go into buffers allocated once, as a frame step hands its networks
        # (clss/methods/*/frame.py): fresh ones per run charged a small network the pages'
        # first touch (NSRR's 4x feature extractor: 17.9 ms a run against 11.7 ms of its
        # steps' wall time in `clss bench --layers`, which writes into fixed buffers too)
        outs = m.run_device(d_in)

        def run():
            return list(m.run_device(d_in, out=outs).values())

        def release():
            d_in.clear()
            outs.clear()
        return Setup(run, twin, host, NET_TOL[prec], eng, ort, release=release,
                     note=f"{len(m.graph.nodes)} steps after fusion")
    shape = ", ".join(f"{k}: {'x'.join(map(str, s))}" for k, s in input_shapes.items())
    return BenchCase(name, "network", "network", tier, float(flops), build, quick=quick, shape=shape,
                     network=(model, dict(input_shapes)))


def seeded_feeds(name: str, input_shapes: dict, prec: str) -> dict:
    """A whole network's inputs: seeded |N(0, 1)|, rounded to the storage precision."""
    return {k: _rounded(np.abs(rng("bench net", name, k).standard_normal(s, dtype=np.float32)), prec)
            for k, s in input_shapes.items()}


def network_cases(method: str, tier: str, nets) -> list[BenchCase]:
    """A method's networks at one tier: "network <method> <net>" for each whole network
    through clss.Model (`model_case`), then "layer <method> <net>.<layer> <geometry>" for
    each Conv / ConvTranspose node in them against onnxruntime on the same single node
    (bench/cases.py network_layers, layer_case).

    nets: (net, variant, model[, input_shapes]) at the shapes a frame step of the method
    runs each (input_shapes fix the graph inputs' symbolic dims; without them the graph's
    inputs must be static; variant tells the same net at two frame steps apart, e.g.
    "x4"). A workload is benched once: a network whose graph is
    an earlier one's at the same shapes, a layer with an earlier one's op, kernel,
    stride, channels, input size and fused epilogue. A name that two different workloads
    would share gets the variant appended."""
    import hashlib
    networks, layers = {}, {}        # key -> (base name, variant, payload)
    for net, variant, model, *given in nets:
        shapes = given[0] if given else static_input_shapes(model)
        key = (net, hashlib.sha1(fixed_inputs(model, shapes).SerializeToString()).hexdigest())
        if key in networks:
            continue
        ls = network_layers(model, shapes)
        networks[key] = (f"network {method} {net}", variant, (model, shapes, sum(map(layer_flops, ls))))
        for L in ls:
            layers.setdefault(layer_key(L), (f"layer {method} {net}.{layer_label(L)}", variant, L))
    return ([model_case(name, m, shapes, tier, flops) for name, (m, shapes, flops) in _named(networks)]
            + [layer_case(L, tier, name) for name, L in _named(layers)])


def static_input_shapes(model: onnx.ModelProto) -> dict:
    """{input: shape} of a graph whose inputs have static dims."""
    init = {t.name for t in model.graph.initializer}
    out = {}
    for i in model.graph.input:
        if i.name in init:
            continue
        dims = i.type.tensor_type.shape.dim
        if not all(d.HasField("dim_value") for d in dims):
            raise ValueError(f"{model.graph.name}: input {i.name} has a symbolic dim; build the network "
                             "at the frame step's shape")
        out[i.name] = tuple(int(d.dim_value) for d in dims)
    return out


def _named(items: dict) -> list:
    """(name, payload) of each (base name, variant, payload): the base name, with the
    variant appended where several different workloads share it."""
    count: dict[str, int] = {}
    for base, _, _ in items.values():
        count[base] = count.get(base, 0) + 1
    return [(base if count[base] == 1 else f"{base} {variant}", payload)
            for base, variant, payload in items.values()]


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


def frame_setup(run, twin, feeds, prec, eng_bytes, ort_bytes, note="", up=None) -> Setup:
    """The Setup of a frame step whose output is the caller's H x W x 3 image and whose twin
    writes [1,3,H,W] as its first output (checked at the whole-network tolerance); `up`: its
    Upscaler, for the stage times (`stage_timer`)."""
    return Setup(run, twin, feeds, NET_TOL[prec], eng_bytes, ort_bytes,
                 post=lambda outs: [outs[0].transpose(2, 0, 1)[None]], out_index=0, note=note,
                 stages=stage_timer(up))


def stage_timer(up):
    """A Setup's `stages` for an Upscaler built with profile=True (an event list per frame:
    no host wait) whose frame step times its stages (STAGES); None for another."""
    if up is None or not (up.profile and up.STAGES):
        return None

    def stages():
        st = up.stage_ms()
        up.reset_timings()
        return st
    return stages


def frame_bench_case(method: str, scale: float, tier: str, flops: float, build, render_size,
                     output_hw) -> BenchCase:
    """A method's frame step as a bench case, "frame step <method> x<scale>", in fp32 and fp16
    (half storage)."""
    (h, w), (H, W) = render_size, output_hw
    return BenchCase(f"frame step {method} x{scale:g}", "frame", "frame", tier, flops, build,
                     shape=f"{h}x{w}->{H}x{W}", precisions=("fp32", "fp16"))


def median_ms(fn, frames: int) -> float:
    """The median wall milliseconds of `frames` calls of fn (warm it first)."""
    import time
    ts = []
    for _ in range(frames):
        t = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t) * 1e3)
    return float(np.median(ts))
