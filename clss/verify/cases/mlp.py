"""Conformance cases of the fused per-pixel MLP (clss/ops/mlp.py, kernels/mlp.cl): ONNX twins
and seeded cases, `cases(level)` for `clss verify` and the tests."""
from __future__ import annotations

import numpy as np
import onnx
from onnx import helper

from ...ops.base import rng
from ...ops.conv import ACTIVATIONS
from ...ops.mlp import mlp
from ..case import Case, host_call
from ..twin import make_model

_ACT_OPS = {"relu": "Relu", "sigmoid": "Sigmoid", "tanh": "Tanh", "leaky_relu": "LeakyRelu"}


def twin(x: np.ndarray, layers, *, consts=False) -> "onnx.ModelProto":
    """Conv 1x1 -> activation per layer; weights and biases are graph inputs
    (w0, b0, w1, ...) so fp16 runs feed onnxruntime the same rounded values, or with
    `consts` initializers (a network's weights, as the bench runs them)."""
    nodes, inputs, cur = [], {"x": x}, "x"
    for i, (w, b, act) in enumerate(layers):
        name, alpha = (act, 0.01) if isinstance(act, str) else act
        inputs[f"w{i}"] = w.reshape(w.shape[0], w.shape[1], 1, 1)
        inputs[f"b{i}"] = b
        nodes.append(helper.make_node("Conv", [cur, f"w{i}", f"b{i}"], [f"c{i}"]))
        cur = f"c{i}"
        if name != "none":
            attrs = {"alpha": float(alpha)} if name == "leaky_relu" else {}
            nodes.append(helper.make_node(_ACT_OPS[name], [cur], [f"a{i}"], **attrs))
            cur = f"a{i}"
    nodes.append(helper.make_node("Identity", [cur], ["y0"]))
    if not consts:
        return make_model(nodes, inputs, ["y0"])
    return make_model(nodes, {"x": x}, ["y0"], initializers={k: v for k, v in inputs.items() if k != "x"})


def make_case(widths, acts, n=1, h=7, w=13, name="") -> Case:
    g = rng("mlp", tuple(widths), tuple(map(str, acts)), n, h, w)
    x = g.standard_normal((n, widths[0], h, w)).astype(np.float32)
    layers = []
    for i, act in enumerate(acts):
        wt = (g.standard_normal((widths[i + 1], widths[i])) / np.sqrt(widths[i])).astype(np.float32)
        layers.append((wt, g.standard_normal(widths[i + 1]).astype(np.float32) * 0.5, act))
    model = twin(x, layers)
    inputs = {"x": x}
    for i, (wt, b, _) in enumerate(layers):
        inputs[f"w{i}"] = wt.reshape(wt.shape[0], wt.shape[1], 1, 1)
        inputs[f"b{i}"] = b
    acts_ = list(acts)

    def run(dev, prec, x, **wb):
        ls = [(wb[f"w{i}"], wb[f"b{i}"], a) for i, a in enumerate(acts_)]
        return mlp(dev, prec, x, ls)

    short = {"none": "id", "relu": "relu", "leaky_relu": "lrelu", "sigmoid": "sig", "tanh": "tanh"}
    desc = "-".join(str(c) for c in widths) + " " + ",".join(
        short[a if isinstance(a, str) else a[0]] for a in acts) + f" {n}x{h}x{w}" + (f" {name}" if name else "")
    return Case("mlp", desc, inputs, model, host_call(run))


def cases(level: str = "quick") -> list[Case]:
    C = make_case
    composition = ((22, 32, 1), ("relu", "sigmoid"))           # CLSS composition network
    shader = ((50, 50, 50, 25), (("leaky_relu", 0.01),) * 3)   # shader MLP upscaler (seed 004)
    tiny = [
        C(*composition, h=5, w=9, name="clss-composition"),
        C((3, 5, 4), ("tanh", ("leaky_relu", 0.2)), n=2, h=3, w=7),
        C((2, 3, 2, 3, 2, 3, 2, 3, 2), ("relu", "none") * 3 + ("relu", "sigmoid"), h=3, w=5,
          name="8-layers"),
    ]
    if level == "tiny":
        return tiny
    quick = tiny + [C(*shader, h=7, w=13, name="shader-mlp")]
    if level == "quick":
        return quick
    full = quick + [
        # more than MAX_LAYERS: two kernels through a global intermediate. Not in
        # "tiny": oclgrind 21.10 flags the second kernel's reads as uninitialised
        # on a repeated run in one process although the first kernel (or a fill)
        # wrote every element and the values match onnxruntime.
        C((2,) * 10, ("relu", "none") * 4 + ("sigmoid",), h=3, w=5, name="chained"),
        C(*composition, h=31, w=27, name="clss-composition"),
        C(*composition, n=2, h=1, w=1),
        C(*composition, h=7, w=13),
        C((5, 3), ("none",), h=31, w=27),
        C((23, 17, 3), ("tanh", "relu"), h=7, w=13),
        C((17, 64, 64, 5), ("relu", ("leaky_relu", 0.1), "sigmoid"), n=2, h=9, w=11),
        C((3, 128, 3), ("relu", "none"), h=4, w=6, name="widest"),
    ]
    for act in ACTIVATIONS:
        full.append(C((7, 9), (act,), h=7, w=13))
    return full


# The shader MLP upscaler's fused kernels (clss/methods/mlp/mlp_upscale.cl) run with this family's
# cases, so that `clss verify` checks them (clss.ops.FAMILIES lists the families).
_cases_per_pixel_mlp = cases


def cases(level: str = "quick") -> list[Case]:  # noqa: F811
    from .mlp_upscale import cases as upscale_cases
    return _cases_per_pixel_mlp(level) + upscale_cases(level)
