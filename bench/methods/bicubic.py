"""The bicubic baseline's bench room: its frame step (PQ encode, the cubic resize, PQ decode:
clss/methods/bicubic/) against onnxruntime on the same step's whole-frame ONNX graph
(clss/methods/bicubic/oracle.py), at each tier's CLSS frame step (540p -> 1080p and
1080p -> 2160p, 2x). The suite finds the room by its name (bench/methods/__init__.py). The
floor under every learned method's figures: its frame step is one resize and two
elementwise passes, so it measures launch and memory costs."""
from __future__ import annotations

from clss.device import storage_dtype

from ..cases import TIERS, BenchCase, _resize_flops
from ..netcases import frame_bench_case, frame_runner, frame_setup

# CLSS's frame step of each tier: the floor under the learned methods at the same output
BICUBIC_TIERS = {tier: (step,) for tier, step in TIERS.items()}


def bicubic_frame_case(render_size, scale: float, tier: str) -> BenchCase:
    from clss.methods.bicubic.oracle import build_graph
    from clss.pipeline.contract import output_size
    h, w = render_size
    H, W = output_size(h, w, scale)
    flops = _resize_flops("cubic", 3 * H * W)

    def build(dev, prec, params):
        from clss import Upscaler
        up = Upscaler(method="bicubic", scale=scale, device=dev, precision=prec)
        run, (color, _, _) = frame_runner(dev, up, (h, w), (H, W))
        st = storage_dtype(prec).itemsize
        io = color.nbytes + H * W * 3 * 4
        # the PQ planes written and read at both resolutions
        planes = 2 * 3 * (h * w + H * W)
        return frame_setup(run, build_graph((h, w), scale),
                           {"color": color.transpose(2, 0, 1)[None].copy()}, prec,
                           io + planes * st, io + planes * 4)
    return frame_bench_case("bicubic", scale, tier, flops, build, (h, w), (H, W))


def cases(tier: str) -> list:
    """The room's bench cases at one shape tier (none at a tier it has no shape for)."""
    return [bicubic_frame_case(rs, s, tier) for rs, s in BICUBIC_TIERS.get(tier, ())]
