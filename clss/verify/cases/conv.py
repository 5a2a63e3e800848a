"""Conformance cases of Conv / ConvTranspose with fused bias, activation and residual
(clss/ops/conv.py, kernels/conv.cl): ONNX twins and seeded cases, `cases(level)` for `clss
verify` and the tests."""
from __future__ import annotations

import numpy as np
from onnx import helper

from ...ops.base import rng
from ...ops.conv import (ACTIVATIONS, conv2d, conv_output_size, conv_transpose2d,
                         conv_transpose_output_size, conv_transpose_pads)
from ..case import Case, host_call
from ..twin import make_model

_ACT_NODES = {"relu": ("Relu", {}), "sigmoid": ("Sigmoid", {}), "tanh": ("Tanh", {})}


def twin(op: str, inputs: dict, *, activation="none", alpha=0.01, residual_before_act=True,
         consts=(), depth_to_space=None, **attrs):
    """ONNX twin of a fused conv: Conv/ConvTranspose -> [DepthToSpace] -> [Add(r)] -> act ->
    [Add(r)]. inputs: x, w, optional b, optional r (residual). `consts`: the inputs that are
    initializers, not graph inputs (a network's weights, as the bench runs them);
    depth_to_space: (blocksize, mode) of a fused shuffle."""
    names = ["x", "w"] + (["b"] if inputs.get("b") is not None else [])
    nodes = [helper.make_node(op, names, ["c"], **attrs)]
    cur = "c"
    if depth_to_space:
        nodes.append(helper.make_node("DepthToSpace", [cur], ["ds"], blocksize=int(depth_to_space[0]),
                                      mode=depth_to_space[1]))
        cur = "ds"
    res = inputs.get("r") is not None
    if res and residual_before_act:
        nodes.append(helper.make_node("Add", [cur, "r"], ["s"]))
        cur = "s"
    if activation != "none":
        if activation == "leaky_relu":
            nodes.append(helper.make_node("LeakyRelu", [cur], ["a"], alpha=float(alpha)))
        else:
            nodes.append(helper.make_node(_ACT_NODES[activation][0], [cur], ["a"]))
        cur = "a"
    if res and not residual_before_act:
        nodes.append(helper.make_node("Add", [cur, "r"], ["s2"]))
        cur = "s2"
    nodes.append(helper.make_node("Identity", [cur], ["y0"]))
    return make_model(nodes, {k: v for k, v in inputs.items() if v is not None and k not in consts},
                      ["y0"], initializers={k: inputs[k] for k in consts})


def make_case(op="conv", n=1, cin=3, h=7, w=13, cout=5, k=(3, 3), strides=(1, 1), pads=(1, 1, 1, 1),
              dilations=(1, 1), group=1, output_padding=(0, 0), output_shape=None, bias=True,
              activation="none", alpha=0.01, residual=None, tol=None, tuning=None,
              depth_to_space=None) -> Case:
    """One seeded conformance case. residual: None, "before" or "after" the activation;
    depth_to_space: (r, mode) of a DepthToSpace fused into the store (then a row that stores
    it is forced through `tuning`), the residual and the activation in the shuffled space.
    output_shape (ConvTranspose): the twin states the output size and the pads follow
    from it (negative where the output is larger than the natural one)."""
    if output_shape is not None:
        (pt, pb), (pl, pr) = (conv_transpose_pads((h, w)[i], k[i], strides[i], dilations[i],
                                                  output_padding[i], output_shape[i], "NOTSET")
                              for i in range(2))
        pads = (pt, pl, pb, pr)
    kh, kw = k
    g = rng(op, n, cin, h, w, cout, k, strides, pads, dilations, group, output_padding, bias,
            activation, residual)
    x = g.standard_normal((n, cin, h, w)).astype(np.float32)
    if op == "conv":
        wt = g.standard_normal((cout, cin // group, kh, kw)).astype(np.float32)
        ho = conv_output_size(h, kh, strides[0], pads[0] + pads[2], dilations[0])
        wo = conv_output_size(w, kw, strides[1], pads[1] + pads[3], dilations[1])
    else:
        wt = g.standard_normal((cin, cout // group, kh, kw)).astype(np.float32)
        ho = conv_transpose_output_size(h, kh, strides[0], pads[0] + pads[2], dilations[0], output_padding[0])
        wo = conv_transpose_output_size(w, kw, strides[1], pads[1] + pads[3], dilations[1], output_padding[1])
    # weights scaled like a trained layer's (fan-in), so outputs stay O(1)
    wt *= np.float32(1.0 / np.sqrt(wt[0].size))
    inputs = {"x": x, "w": wt}
    if bias:
        inputs["b"] = g.standard_normal(cout).astype(np.float32)
    r2 = int(depth_to_space[0]) if depth_to_space else 1
    if residual:
        inputs["r"] = g.standard_normal((n, cout // (r2 * r2), ho * r2, wo * r2)).astype(np.float32)
    attrs = dict(strides=list(strides), pads=list(pads), dilations=list(dilations), group=group)
    fn = conv2d
    if op == "convT":
        attrs["output_padding"] = list(output_padding)
        if output_shape is not None:
            del attrs["pads"]
            attrs["output_shape"] = list(output_shape)
        fn = conv_transpose2d
    before = residual != "after"
    model = twin("Conv" if op == "conv" else "ConvTranspose", inputs, activation=activation,
                 alpha=alpha, residual_before_act=before, depth_to_space=depth_to_space, **attrs)
    kwargs = dict(strides=strides, pads=pads, dilations=dilations, group=group, activation=activation,
                  alpha=alpha, residual_before_act=before)
    if depth_to_space:
        kwargs["depth_to_space"] = depth_to_space
    if op == "convT":
        kwargs["output_padding"] = output_padding
    if tuning is not None:      # a row of the conv2d variant table forced (clss/verify/cases/conv_gemm.py)
        kwargs["tuning"] = tuning

    def run(dev, prec, x, w, b=None, r=None):
        return fn(dev, prec, x, w, b, residual=r, **kwargs)

    desc = (f"{n}x{cin}x{h}x{w}->{cout} k{kh}x{kw} s{strides[0]}{strides[1]} p{''.join(map(str, pads))}"
            f" d{dilations[0]}{dilations[1]} g{group}"
            + (f" op{output_padding[0]}{output_padding[1]}" if op == "convT" else "")
            + ("" if bias else " nobias") + (f" {activation}" if activation != "none" else "")
            + (f" res-{residual}" if residual else "")
            + (f" d2s{depth_to_space[0]}{depth_to_space[1]}" if depth_to_space else "")
            + (f" [{tuning['VARIANT']}]" if tuning and "VARIANT" in tuning and depth_to_space else ""))
    return Case("Conv" if op == "conv" else "ConvTranspose", desc, inputs, model, host_call(run),
                tol=tol or {})


def cases(level: str = "quick") -> list[Case]:
    C = make_case
    # tiny: every kernel variant (KH/KW, SX 1/2/gather, channel block 1/2/4, each
    # activation, residual before/after, bias or not, the vector and the edge
    # path, conv and transposed) on shapes of <= ~1000 outputs, for oclgrind.
    tiny = [
        C(cin=3, h=5, w=40, cout=3, activation="relu"),                          # inside + edge blocks
        C(cin=5, h=6, w=7, cout=3, k=(1, 1), pads=(0, 0, 0, 0), activation="leaky_relu", alpha=0.2,
          residual="before"),                                                    # 1x1 flattened
        C(cin=4, h=9, w=21, cout=4, strides=(2, 2), pads=(0, 1, 2, 1), dilations=(2, 2), group=4,
          activation="sigmoid"),                                                 # depthwise, SX=2
        C(n=2, cin=2, h=8, w=11, cout=3, k=(5, 5), strides=(3, 3), pads=(2, 2, 2, 2), bias=False,
          activation="tanh"),                                                    # gather stride, batch
        C(cin=4, h=7, w=9, cout=6, k=(7, 7), pads=(3, 3, 3, 3), group=2, residual="after",
          activation="relu"),                                                    # CB=2 per group... 3
        C("convT", cin=3, h=4, w=9, cout=2, strides=(2, 2), pads=(1, 1, 1, 1), output_padding=(1, 1),
          activation="relu"),
        C("convT", cin=4, h=3, w=5, cout=4, k=(4, 4), strides=(2, 2), pads=(1, 1, 1, 1), group=4,
          residual="before"),
        C("convT", cin=2, h=4, w=19, cout=3, k=(3, 3), strides=(1, 1), pads=(0, 2, 1, 0),
          dilations=(2, 2), bias=False, activation="leaky_relu", residual="after"),
        # the channel-blocked kernel (conv2d_blocked, >= 8 channels in and out, one group):
        # two input blocks of 5, a partial output vector, inside and edge work-items, stride 2
        C(cin=10, h=4, w=23, cout=9, activation="relu", residual="before"),
        C(n=2, cin=9, h=5, w=19, cout=11, strides=(2, 2), pads=(0, 1, 2, 1), dilations=(2, 1),
          bias=False, activation="leaky_relu", alpha=0.2, residual="after"),
        # a DepthToSpace fused into the store (kernels/d2s_index.h): both modes, the rows that
        # store it, a residual in the shuffled space, a partial vector of 8 pixels
        C(cin=3, h=5, w=11, cout=12, activation="relu", residual="after", depth_to_space=(2, "CRD"),
          tuning={"VARIANT": "direct"}),
        C(n=2, cin=4, h=3, w=7, cout=18, k=(1, 1), pads=(0, 0, 0, 0), residual="before",
          activation="sigmoid", depth_to_space=(3, "DCR"), tuning={"VARIANT": "direct"}),
        C(cin=5, h=4, w=9, cout=8, activation="tanh", residual="before", depth_to_space=(2, "DCR"),
          tuning={"VARIANT": "gemm"}),
        C(cin=3, h=6, w=5, cout=12, k=(1, 1), pads=(0, 0, 0, 0), depth_to_space=(2, "CRD"),
          tuning={"VARIANT": "gemm_global"}),
    ]
    if level == "tiny":
        return tiny
    quick = tiny + [
        C(cin=16, h=12, w=37, cout=16, activation="relu", residual="before"),
        C("convT", cin=16, h=9, w=13, cout=8, k=(2, 2), strides=(2, 2), pads=(0, 0, 0, 0), activation="relu"),
        C(cin=37, h=11, w=53, cout=40, strides=(2, 2), activation="sigmoid"),     # blocked: 3 input blocks
    ]
    if level == "quick":
        return quick
    full = [
        C(cin=17, h=9, w=33, cout=23, k=(3, 3), strides=(2, 2), pads=(1, 1, 1, 1)),
        C(cin=24, h=10, w=20, cout=24, k=(3, 3), group=24, activation="relu"),
        C(cin=23, h=11, w=29, cout=17, k=(1, 1), pads=(0, 0, 0, 0), activation="sigmoid"),
    ]
    for h, w in ((1, 1), (7, 13), (31, 27)):
        for k in (1, 3, 5, 7):
            p = k // 2
            full.append(C(cin=5, h=h, w=w, cout=3, k=(k, k), pads=(p, p, p, p)))
            full.append(C(n=2, cin=3, h=h, w=w, cout=17, k=(k, k), pads=(p, p, p, p), activation="relu",
                          residual="before"))
    for act in ACTIVATIONS:
        full.append(C(cin=5, h=7, w=13, cout=23, activation=act, alpha=0.1))
        full.append(C("convT", cin=5, h=7, w=13, cout=3, strides=(2, 2), pads=(1, 1, 1, 1),
                      output_padding=(1, 1), activation=act, alpha=0.1))
    full += [
        C(cin=6, h=31, w=27, cout=9, group=3, strides=(2, 2), pads=(0, 1, 2, 1), activation="leaky_relu"),
        C(cin=6, h=31, w=27, cout=6, group=2, dilations=(2, 2), pads=(2, 2, 2, 2), residual="after",
          activation="tanh"),
        C(cin=17, h=31, w=27, cout=17, group=17, k=(5, 5), pads=(2, 2, 2, 2), activation="relu"),
        C(cin=8, h=31, w=27, cout=16, group=8, k=(3, 3), strides=(2, 2), pads=(1, 1, 1, 1)),  # multiplier 2
        C(n=2, cin=3, h=31, w=27, cout=5, k=(3, 5), strides=(1, 2), pads=(1, 2, 0, 1), dilations=(2, 1)),
        C(cin=5, h=31, w=27, cout=3, k=(7, 7), strides=(4, 4), pads=(3, 0, 0, 3)),
        C(cin=64, h=9, w=37, cout=32, k=(3, 3), pads=(1, 1, 1, 1), activation="relu",
          residual="before"),                                                    # K = 576
        C(cin=64, h=16, w=40, cout=64, k=(1, 1), pads=(0, 0, 0, 0)),
        C(cin=3, h=32, w=32, cout=24, k=(3, 3), strides=(2, 2), pads=(0, 0, 1, 1)),
        # stride 2, 3 taps along x (-DCONV_S2K3): inside blocks, both edges, prime widths
        C(cin=5, h=13, w=71, cout=11, k=(3, 3), strides=(2, 2), pads=(1, 1, 1, 1), activation="relu"),
        C(cin=7, h=11, w=131, cout=9, k=(3, 3), strides=(2, 2), pads=(0, 0, 1, 1), activation="relu",
          residual="before"),
        C(cin=3, h=9, w=67, cout=5, k=(3, 3), strides=(2, 2), pads=(1, 1, 1, 1), dilations=(2, 1)),
        C(cin=3, h=9, w=67, cout=5, k=(3, 3), strides=(2, 2), pads=(2, 2, 2, 2), dilations=(1, 2)),
        C(cin=67, h=7, w=37, cout=131, k=(3, 3), strides=(2, 2), pads=(1, 1, 1, 1), activation="relu"),
        # blocked, at the networks' channel counts: 60 -> 24 (NSRR), 64 -> 64 (NSRD's ConvLSTM), 5x5
        C(cin=60, h=9, w=41, cout=24, activation="relu"),
        C(cin=64, h=7, w=43, cout=64, residual="before"),
        C(cin=12, h=13, w=29, cout=16, k=(5, 5), pads=(2, 2, 2, 2), activation="tanh"),
        C("convT", n=2, cin=8, h=7, w=13, cout=4, k=(2, 2), strides=(2, 2), pads=(0, 0, 0, 0)),
        C("convT", cin=6, h=9, w=11, cout=6, k=(3, 3), strides=(2, 2), pads=(1, 1, 1, 1), group=6,
          output_padding=(1, 1)),
        C("convT", cin=6, h=9, w=11, cout=4, k=(3, 3), strides=(3, 2), pads=(0, 1, 2, 0), group=2,
          dilations=(1, 2), output_padding=(2, 1), residual="after", activation="relu"),
        C("convT", cin=32, h=17, w=31, cout=16, k=(4, 4), strides=(2, 2), pads=(1, 1, 1, 1),
          activation="relu"),
        C("convT", cin=5, h=1, w=1, cout=3, k=(3, 3), strides=(2, 2)),
        C("convT", cin=3, h=5, w=6, cout=2, k=(3, 3), strides=(2, 2), output_shape=(12, 12)),
    ]
    return quick + full
