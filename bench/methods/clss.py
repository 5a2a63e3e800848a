"""CLSS's bench room: the two networks (classifier, composition) through clss.Model against
onnxruntime on the same graphs, and the whole frame step (net and rule modes) against
onnxruntime on the step's ONNX graph (clss/methods/clss/oracle.py). The suite finds it by
the room's name (bench/methods/__init__.py). The host-wait bench times the three methods
whose frame step is CLSS's FrameStep, with the host's enqueue time of one frame
(`enqueue_frame`)."""
from __future__ import annotations

import numpy as np

from clss.device import storage_dtype
from clss.methods.clss.networks import CLASSIFIER_CHANNELS, COMPOSITION_CHANNELS, pad16
from clss.pipeline.contract import output_size

from ..cases import TIERS, BenchCase, Setup
from ..netcases import BENCH_JITTER, NET_TOL, frame_runner, model_case, stage_timer

# The methods of this room that the host-wait bench (bench/hostwait.py) rows.
HOST_WAITS = ("clss", "clss-rules", "jbicubic")


def enqueue_frame(up, color, depth, motion, jitter, out):
    """Enqueue one history-carrying frame on `up`'s FrameStep without waiting for it;
    returns the event to wait for (the host-wait bench times the enqueue alone). Then the
    frame is accepted as the upscaler's step would."""
    fs = up._fs
    ev = fs.run(color, depth, motion, None, jitter, False, out=out)
    return ev, fs.accept


def network_cases(tier):
    """The two CLSS networks through clss.Model."""
    from clss.methods.clss.networks import build_classifier, build_composition, count_flops
    (h, w), scale = TIERS[tier]
    H, W = output_size(h, w, scale)
    Hp, Wp = pad16(H), pad16(W)
    cls = build_classifier(height=Hp, width=Wp)
    comp = build_composition(height=H, width=W)
    return [model_case("network classifier", cls, {"x": (1, CLASSIFIER_CHANNELS, Hp, Wp)}, tier,
                       count_flops(cls, Hp, Wp), quick=False),
            model_case("network composition", comp, {"x": (1, COMPOSITION_CHANNELS, H, W)}, tier,
                       count_flops(comp, H, W), quick=False)]


def cases(tier: str) -> list:
    """The room's bench cases at one shape tier: the networks, then the frame step in net
    and rule modes."""
    (h, w), scale = TIERS[tier]
    return network_cases(tier) + [frame_case(mode, (h, w), scale, tier) for mode in ("net", "rule")]


def frame_case(mode: str, render_size, scale: float, tier: str) -> BenchCase:
    from clss.methods.clss.oracle import build_frame_graph
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
                      classifier=cls, composition=comp, profile=True)
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
                     note=(f"classifier on {up.classifier_backend_name}" if mode == "net" else ""),
                     stages=stage_timer(up))
    # Not in --quick: at 540p a net-mode frame costs seconds on a 2-core CPU.
    return BenchCase(f"frame step {mode}", "frame", "frame", tier, flops, build,
                     shape=f"{h}x{w}->{H}x{W}", precisions=("fp32", "fp16"))
