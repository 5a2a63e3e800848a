"""The whole-frame ONNX twin of the bicubic baseline: PQ encode, one Resize node (cubic,
a = -0.75, half-pixel centres, clamped edges), clip to [0, 1], PQ decode; run by
onnxruntime. tests/test_methods.py holds the OpenCL upscaler to it."""
from __future__ import annotations

import numpy as np
import onnx

from ...pipeline.contract import PQ_NITS, output_size, validate_frame
from ...pipeline.twin import GraphBuilder, make_model, pq_decode, pq_encode, value_info

OPSET = 19


def build_graph(render_size, scale, nits=PQ_NITS) -> onnx.ModelProto:
    """color [1,3,h,w] linear -> output [1,3,H,W] linear."""
    h, w = render_size
    H, W = output_size(h, w, scale)
    g = GraphBuilder(OPSET)
    x = pq_encode(g, "color", nits)
    sizes = g.const(np.array([1, 3, H, W], np.int64), np.int64, "sizes")
    y = g.op("Resize", x, "", "", sizes, mode="cubic", cubic_coeff_a=-0.75,
             coordinate_transformation_mode="half_pixel")
    pq_decode(g, g.clip(y, 0.0, 1.0), nits, name="output")
    return make_model(g.nodes, g.inits, "bicubic_frame", [value_info("color", (1, 3, h, w))],
                      [value_info("output", (1, 3, H, W))], __name__, OPSET)


class OracleBicubic:
    """Frame-by-frame runner of the twin with the contract's `step`."""

    def __init__(self, render_size, scale=2.0, **unused):
        import onnxruntime as ort
        self.render_size, self.scale = tuple(render_size), float(scale)
        self.model = build_graph(self.render_size, self.scale)
        self.session = ort.InferenceSession(self.model.SerializeToString(),
                                            providers=["CPUExecutionProvider"])

    def step(self, color, depth=None, motion=None, jitter=(0.0, 0.0), reset=False, **unused):
        h, w = self.render_size
        f = validate_frame(color, np.zeros((h, w), np.float32), np.zeros((h, w, 2), np.float32),
                           (0.0, 0.0), render_size=self.render_size)
        x = np.ascontiguousarray(f["color"].transpose(2, 0, 1)[None])
        (y,) = self.session.run(["output"], {"color": x})
        return np.ascontiguousarray(y[0].transpose(1, 2, 0))
