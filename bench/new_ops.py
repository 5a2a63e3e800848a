"""The ops of issue 49 (reductions, normalisations, modern activations, run-time matrix
products, Clip with tensor bounds) at the sizes a model sees at 540x960 input, each as a
one-node (or few-node) ONNX graph through clss.Model and onnxruntime in the same process:
medians of --repeat runs after a warm-up, fp32, both peers on the same feeds; clss writes
into preallocated outputs (run_device(out=...), as a frame step runs its networks),
onnxruntime into its arena.

    python -m bench.new_ops [--repeat 5] [--only NAME] [--json FILE]

Prints a Markdown table: the shape, clss ms, onnxruntime ms, the ratio (onnxruntime /
clss: above 1 is clss faster) and the max error against onnxruntime (relative to the
output's range)."""
from __future__ import annotations

import argparse
import json
import time

import numpy as np
from onnx import TensorProto, helper, numpy_helper

from clss.cli.model import _median_ms as median_ms

H, W = 540, 960


def _model(nodes, inputs: dict, outputs, inits: dict | None = None, opset: int = 18):
    vi = [helper.make_tensor_value_info(k, TensorProto.FLOAT, v.shape) for k, v in inputs.items()]
    vo = [helper.make_tensor_value_info(o, TensorProto.FLOAT, None) for o in outputs]
    g = helper.make_graph(nodes, "op", vi, vo, [numpy_helper.from_array(v, k) for k, v in (inits or {}).items()])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", opset)])
    m.ir_version = 9
    return m


def _node(op, ins, **attrs):
    return helper.make_node(op, ins, ["y"], **attrs)


def cases():
    """(name, shape text, model, feeds)."""
    g = np.random.default_rng(0)
    x32 = g.standard_normal((1, 32, H, W)).astype(np.float32)
    i64 = lambda *v: np.array(v, np.int64)   # noqa: E731
    c32 = {"s": g.standard_normal(32).astype(np.float32), "b": g.standard_normal(32).astype(np.float32)}
    tokens = g.standard_normal((1, H * W // 4, 64)).astype(np.float32)     # a 2x-patched Swin stage
    scores = g.standard_normal((H * W // 256, 2, 64, 64)).astype(np.float32)   # 8x8 windows at 1/2 res, 2 heads
    out = [
        ("ReduceMean spatial (channel attention)", "1x32x540x960 axes 2,3",
         _model([_node("ReduceMean", ["x", "a"], keepdims=1)], {"x": x32}, ["y"], {"a": i64(2, 3)}), {"x": x32}),
        ("ReduceMean channels (spatial attention)", "1x32x540x960 axis 1",
         _model([_node("ReduceMean", ["x", "a"], keepdims=1)], {"x": x32}, ["y"], {"a": i64(1)}), {"x": x32}),
        ("ReduceMax channels", "1x32x540x960 axis 1",
         _model([_node("ReduceMax", ["x", "a"], keepdims=1)], {"x": x32}, ["y"], {"a": i64(1)}), {"x": x32}),
        ("ReduceSum last axis", "1x129600x64 axis -1",
         _model([_node("ReduceSum", ["x", "a"], keepdims=1)], {"x": tokens}, ["y"], {"a": i64(-1)}), {"x": tokens}),
        ("Softmax last axis (window attention)", "4050x2x64x64",
         _model([_node("Softmax", ["x"], axis=-1)], {"x": scores}, ["y"]), {"x": scores}),
        ("LogSoftmax channels", "1x32x540x960 axis 1",
         _model([_node("LogSoftmax", ["x"], axis=1)], {"x": x32}, ["y"]), {"x": x32}),
        ("LayerNormalization", "1x129600x64 axis -1",
         _model([_node("LayerNormalization", ["x", "s", "b"], axis=-1)], {"x": tokens}, ["y"],
                {"s": g.standard_normal(64).astype(np.float32), "b": g.standard_normal(64).astype(np.float32)}),
         {"x": tokens}),
        ("InstanceNormalization", "1x32x540x960",
         _model([_node("InstanceNormalization", ["x", "s", "b"])], {"x": x32}, ["y"], c32), {"x": x32}),
        ("GroupNormalization 8 groups", "1x32x540x960",
         _model([_node("GroupNormalization", ["x", "s", "b"], num_groups=8)], {"x": x32}, ["y"], c32, opset=21),
         {"x": x32}),
        ("Clip, tensor bounds", "1x32x540x960",
         _model([_node("Clip", ["x", "lo", "hi"])], {"x": x32, "lo": np.array(-0.5, np.float32),
                                                     "hi": np.array(0.5, np.float32)}, ["y"]),
         {"x": x32, "lo": np.array(-0.5, np.float32), "hi": np.array(0.5, np.float32)}),
        ("Pow by 2", "1x32x540x960",
         _model([_node("Pow", ["x", "p"])], {"x": x32}, ["y"], {"p": np.array(2.0, np.float32)}), {"x": x32}),
        ("Attention Q K^T (MatMul)", "8100x2x64x16 @ 8100x2x16x64",
         _model([_node("MatMul", ["q", "k"])], {"q": scores[..., :16].copy(), "k": scores[..., :16, :].copy()}, ["y"]),
         {"q": scores[..., :16].copy(), "k": scores[..., :16, :].copy()}),
        ("Gemm, run-time B", "4096x256 @ 256x512",
         _model([_node("Gemm", ["a", "b"], transB=1)], {"a": tokens.reshape(-1, 256)[:4096].copy(),
                                                        "b": g.standard_normal((512, 256)).astype(np.float32)}, ["y"]),
         {"a": tokens.reshape(-1, 256)[:4096].copy(), "b": g.standard_normal((512, 256)).astype(np.float32)}),
    ]
    for op, attrs, opset in (("HardSwish", {}, 18), ("HardSigmoid", {}, 18), ("Gelu", {}, 20), ("Erf", {}, 18),
                             ("Mish", {}, 18), ("Softplus", {}, 18), ("Sigmoid", {}, 18)):
        out.append((op, "1x32x540x960", _model([_node(op, ["x"], **attrs)], {"x": x32}, ["y"], opset=opset),
                    {"x": x32}))
    return out


def _median_ms(fn, repeat):
    fn()    # warm-up: builds, first touches
    return median_ms(fn, repeat)


def main(argv=None) -> int:
    import clss
    from clss.verify.twin import session
    p = argparse.ArgumentParser(prog="python -m bench.new_ops", description=__doc__.split("\n\n")[0])
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--only", help="cases whose name contains this")
    p.add_argument("--json", help="also write the rows as JSON")
    a = p.parse_args(argv)
    rows = []
    print("| op | shape | clss ms | onnxruntime ms | ort / clss | max err / range |")
    print("|---|---|---|---|---|---|")
    for name, shape, model, feeds in cases():
        if a.only and a.only.lower() not in name.lower():
            continue
        m = clss.Model(model)
        dfeeds = m.upload(feeds)
        # into preallocated outputs, as a frame step runs its networks (a fresh output per
        # call is an allocation and its first-touch page faults: tens of ms at this size)
        douts = {k: m.device.empty(s, m.precision) for k, s in m.output_shapes.items()}

        def run_ours():
            m.run_device(dfeeds, out=douts)
            m.device.queue.finish()
        ours = _median_ms(run_ours, a.repeat)
        s = session(model)
        ort = _median_ms(lambda: s.run(None, feeds), a.repeat)
        ref = s.run(None, feeds)[0]
        got = m.run(feeds)["y"]
        err = float(np.max(np.abs(got - ref)) / max(float(np.max(np.abs(ref))), 1e-30))
        rows.append(dict(op=name, shape=shape, clss_ms=ours, ort_ms=ort, ratio=ort / ours, err=err))
        print(f"| {name} | {shape} | {ours:.1f} | {ort:.1f} | {ort / ours:.2f}x | {err:.1e} |", flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=2)
    return 0


if __name__ == "__main__":
    from clss.exiting import leave   # past pip's PoCL 3.0 teardown abort
    leave(main())
