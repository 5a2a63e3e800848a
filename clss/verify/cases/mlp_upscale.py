"""Conformance cases of the shader MLP upscaler's kernels (clss/methods/mlp/mlp_upscale.cl,
launched by clss/methods/mlp/mlp_upscale.py): each kernel against its ONNX twin from the method's oracle
(clss/methods/mlp/oracle.py, the same nodes as the whole-frame twin). They run with the
mlp family's cases (clss/verify/cases/mlp.py appends them), so `clss verify` checks them."""
from __future__ import annotations

import numpy as np

from ...methods.mlp import fastpath  # noqa: F401 (the fast path blocks() looks up)
from ...methods.mlp import oracle, transform as tf
from ...methods.mlp.mlp_upscale import blocks, fold, frame, pack_weights
from ...ops.base import rng
from ...tolerance import Tolerance
from ..case import Case


def _weights(g):
    t = tf.init_weights(7)
    t["fc3.weight"] = (g.standard_normal((25, 50)) * 0.1).astype(np.float32)
    t["fc3.bias"] = (g.standard_normal(25) * 0.05).astype(np.float32)
    t["fc1.bias"] = (g.standard_normal(50) * 0.1).astype(np.float32)
    # exactly representable in half, so that one twin serves fp32 and the fp16 path
    # (which rounds its weights to half)
    return {k: v.astype(np.float16).astype(np.float32) for k, v in t.items()}


# fp16: half storage of the inputs and of the blocks (PQ values), float arithmetic;
# the twin gets the same half-rounded inputs.
_TOL = {"fp16": Tolerance(atol=2e-3, rtol=2e-3), "fp16-native": Tolerance(atol=2e-3, rtol=2e-3)}


def _network_case(name, h, w, scale, feature, graph, launch, post, tol) -> Case:
    """A case of the MLP on seeded weights, colour and feature: `launch(dev, prec, colour,
    feature, packed weights, defines)` against the twin `graph`; `post` maps its output
    to what is compared (blocks as they are, the frame PQ-encoded)."""
    g = rng(name.replace("mlp_upscale_", "mlp_upscale."), h, w, scale, feature)
    s = tf.check_scale(scale)
    t = _weights(g)
    color = (g.random((h, w, 3)) * 3.0).astype(np.float32)
    feat = g.random((s * h, s * w)).astype(np.float32)
    defines = tf.kernel_defines(s, feature)

    def run(dev, prec, inputs):
        c = dev.to_device(inputs["color"], prec)
        f = dev.to_device(inputs["feat"], prec)
        y = launch(dev, prec, c, f, pack_weights(dev, prec, tf.packed(t)), defines)
        out = [post(dev.to_host(y))]
        return out if feature else out + [inputs["feat"]]

    return Case(name, f"{h}x{w} x{s}" + ("" if feature else " no-feature"),
                {"color": color, "feat": feat}, graph((h, w), s, t, feature), run, tol=dict(tol))


def blocks_case(h, w, scale, feature=True) -> Case:
    return _network_case("mlp_upscale_blocks", h, w, scale, feature, oracle.blocks_graph, blocks,
                         lambda y: y, _TOL)


def fold_case(h, w, scale) -> Case:
    g = rng("mlp_upscale.fold", h, w, scale)
    s, b = tf.check_scale(scale), tf.block(scale)
    blk = g.uniform(0.05, 0.8, (3, b * b, h, w)).astype(np.float32)
    defines = tf.kernel_defines(s)

    def run(dev, prec, inputs):
        return [dev.to_host(fold(dev, prec, dev.to_device(inputs["blocks"], prec), defines))]

    return Case("mlp_upscale_fold", f"{h}x{w} x{s}", {"blocks": blk},
                oracle.fold_graph((h, w), s), run, tol=dict(_TOL))


# the whole frame in PQ code values, absolute: the method's test tolerances
_FRAME_TOL = {"fp32": Tolerance(atol=1e-4, rtol=0.0), "fp16": Tolerance(atol=2e-3, rtol=0.0),
              "fp16-native": Tolerance(atol=2e-3, rtol=0.0)}


def frame_case(h, w, scale, feature=True) -> Case:
    """The whole frame step (mlp_upscale.frame: the fused kernel where its fast path is
    enabled, else blocks + fold), compared PQ-encoded."""
    from ...pipeline.contract import pq_encode
    return _network_case("mlp_upscale_frame", h, w, scale, feature, oracle.frame_pq_graph, frame,
                         lambda y: pq_encode(np.asarray(y, np.float32)), _FRAME_TOL)


def cases(level: str = "quick") -> list[Case]:
    out = [blocks_case(5, 7, 2), fold_case(5, 7, 3)]
    if level == "tiny":
        # the frame case runs under oclgrind on its own (tests/test_oclgrind.py)
        return out
    out += [blocks_case(9, 11, 3), blocks_case(6, 9, 2, feature=False), fold_case(9, 11, 2),
            frame_case(5, 7, 3), frame_case(9, 37, 2), frame_case(6, 20, 3, feature=False)]
    if level == "quick":
        return out
    return out + [blocks_case(1, 1, 3), blocks_case(17, 23, 2), fold_case(1, 2, 2),
                  fold_case(13, 19, 3), frame_case(1, 1, 2), frame_case(40, 47, 3)]
