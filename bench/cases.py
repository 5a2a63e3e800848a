"""Bench cases: each kernel at the shapes the CLSS frame step uses, with its ONNX twin
(built by the twin builders of the conformance cases, clss/verify/cases/<family>.py).

A BenchCase names one workload; ``case.build(dev, prec, params)`` uploads seeded
inputs and returns a Setup: the engine callable (enqueues on device arrays, returns
device outputs), the twin and its feeds for onnxruntime, the tolerance for the
one-time output check, and the compulsory bytes each side moves (inputs read once,
outputs written once: the floor every implementation pays).

Shapes come from the frame step at a render size and scale 2 (clss-frame.md). A tier is
named by the frame's output resolution, for every case and method alike: tier "1080p" is
540x960 -> 1080x1920 here (the default set), tier "2160p" is 1080x1920 -> 2160x3840
(--full). The classifier runs on the output padded to a multiple of 16 (1088x1920 at
1080p), after SpaceToDepth(2) at 544x960; its conv layers are read from
clss.methods.clss.networks so they follow the network's widths.

Any ONNX network's conv layers become cases the same way (`network_layers`, `layer_case`):
the classifier's here, the other methods' networks in their bench rooms
(bench/netcases.py network_cases).

A family's cases appear once its module exists in clss/ops (they land one by one);
network cases once clss/model/__init__.py exists, the frame step once clss.pipeline has an
OpenCL Upscaler.
"""
from __future__ import annotations

import importlib
import importlib.util
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import onnx
from onnx import helper

from clss.device import Device, DeviceError, storage_dtype
from clss.methods.clss.networks import CLASSIFIER_CHANNELS, CLASSIFIER_INPUTS, pad16
from clss.ops.base import rng
from clss.tolerance import DEFAULT_TOL, EXACT, Tolerance
from clss.pipeline.contract import output_size
from clss.verify.cases import conv as conv_twins, mlp as mlp_twins, resize as resize_twins
from clss.verify.cases import scatter as scatter_twins, space_to_depth as s2d_twins
from clss.verify.cases import warp as warp_twins
from clss.verify.twin import make_model, node_model

# Tiers are named by the OUTPUT resolution, so that one name means one frame whatever
# the method: "1080p" is a 1080x1920 output (540x960 at 2x, 360x640 at 3x, 270x480 at 4x),
# "2160p" a 2160x3840 one. The value is CLSS's frame step to that output (render size,
# scale), whose shapes this module's kernel cases take; the method rooms (bench/methods/)
# choose their render sizes and scales per tier.
TIERS = {"1080p": ((540, 960), 2.0), "2160p": ((1080, 1920), 2.0),
         # a quarter of 1080p's pixels: what a busy 2-core machine finishes with every peer
         # in minutes (clss bench --tier 540p; in no level's tiers)
         "540p": ((270, 480), 2.0),
         # a smoke test of the bench itself (tests, --tiny): every case, numbers meaningless
         "tiny": ((16, 32), 2.0)}
LEVEL_TIERS = {"quick": ("1080p",), "default": ("1080p",), "full": ("1080p", "2160p")}
# What each kind is judged against (the targets) and which peak bounds it.
KINDS = ("conv", "memory", "compute", "network", "frame")


@dataclass
class Setup:
    run: Callable[[], list]          # enqueue the engine once; its device outputs
    twin: onnx.ModelProto
    feeds: dict                      # onnxruntime inputs (fp16-rounded in half modes)
    tol: object                      # Tolerance or EXACT, for the output check
    bytes: float                     # compulsory bytes the engine moves
    ort_bytes: float                 # the same for onnxruntime (float32 tensors)
    refs_round: bool = False         # round references to fp16 (bit-exact data movement)
    release: Callable | None = None
    post: Callable | None = None     # host outputs -> the twin's layout, for the check
    out_index: int | None = None     # check only this twin output (others are state)
    note: str = ""
    # A frame step's {stage: event ms} of the frames since the last call, where the room
    # times its stages: its launches are prepared once (clss.device.Launch), out of the
    # sight of the runner's Capture, which sees only Device.launch.
    stages: Callable[[], dict] | None = None


@dataclass
class BenchCase:
    name: str
    family: str                      # clss/ops module (or "network", "frame")
    kind: str                        # one of KINDS
    tier: str
    flops: float
    build: Callable[[Device, str, dict], Setup]
    quick: bool = False              # in the --quick subset
    shape: str = ""
    tunables: dict = field(default_factory=dict)   # param -> candidates, for clss tune
    defaults: dict = field(default_factory=dict)   # the engine's defaults for those params
    tune_op: str = ""                # tuning-database op name and key
    tune_key: str = ""
    precisions: tuple = ("fp32", "fp16", "fp16-native")
    network: tuple | None = None     # a "network" case's (ONNX model, input shapes), for --layers

    @property
    def label(self) -> str:
        return f"{self.name} [{self.tier}]"


# --- helpers ----------------------------------------------------------------------

def _normal(key, shape, scale=1.0):
    return (rng(*key).standard_normal(shape, dtype=np.float32) * np.float32(scale))


def _rounded(a: np.ndarray, prec: str) -> np.ndarray:
    if prec == "fp32" or a.dtype.kind != "f":
        return a
    return a.astype(np.float16).astype(np.float32)


def _nbytes(shape, dtype) -> float:
    return float(np.prod(shape, dtype=np.float64) * np.dtype(dtype).itemsize)


def make_setup(dev: Device, prec: str, arrays: dict, twin_fn, engine, out_shapes, *,
               fp32=(), exact=False, tol=None) -> Setup:
    """Upload `arrays` (storage precision; names in `fp32` stay float32, e.g. grids),
    build the twin from the same values as the engine sees, and wrap
    engine(dev_arrays) -> device output(s) as the Setup's run."""
    host = {k: (v if k in fp32 else _rounded(v, prec)) for k, v in arrays.items()}
    st = storage_dtype(prec)
    sizes = {k: v.size * (v.itemsize if k in fp32 or v.dtype.kind != "f" else st.itemsize)
             for k, v in host.items()}
    sizes.update({f"output {i}": _nbytes(s, st) for i, s in enumerate(out_shapes)})
    for k, n in sizes.items():
        if n > dev.info.max_alloc:
            raise DeviceError(f"{k}: {n / 2**20:.0f} MiB exceeds the device's max allocation "
                              f"({dev.info.max_alloc / 2**20:.0f} MiB)")
    dev_arrays = {k: (dev.to_device(v, "fp32") if k in fp32 else dev.to_device(v, prec))
                  for k, v in host.items()}
    twin = twin_fn(host)
    graph_inputs = {i.name for i in twin.graph.input}
    feeds = {k: v for k, v in host.items() if k in graph_inputs}
    inits = sum(_nbytes(t.dims, onnx.helper.tensor_dtype_to_np_dtype(t.data_type))
                for t in twin.graph.initializer)
    out_eng = sum(_nbytes(s, st) for s in out_shapes)
    out_ort = sum(_nbytes(s, np.float32) for s in out_shapes)
    eng_bytes = sum(float(a.nbytes) for a in dev_arrays.values()) + out_eng
    ort_bytes = sum(float(v.nbytes) for v in feeds.values()) + inits + out_ort

    def run():
        out = engine(dev_arrays)
        return list(out) if isinstance(out, (list, tuple)) else [out]

    if tol is None:
        tol = EXACT if exact else DEFAULT_TOL[prec]
    return Setup(run, twin, feeds, tol, eng_bytes, ort_bytes, refs_round=exact and prec != "fp32",
                 release=dev_arrays.clear)


def _shape(*dims) -> str:
    return "x".join(str(int(d)) for d in dims)


def _has(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False


def _family(name: str):
    return importlib.import_module(f"clss.ops.{name}")


# --- a network's conv layers -----------------------------------------------------------

def fixed_inputs(model: onnx.ModelProto, input_shapes: dict) -> onnx.ModelProto:
    """The model with its symbolic input dims fixed, so shape inference and onnxruntime
    plan for the shape."""
    m = onnx.ModelProto()
    m.CopyFrom(model)
    for vi in m.graph.input:
        if vi.name in input_shapes:
            for d, s in zip(vi.type.tensor_type.shape.dim, input_shapes[vi.name]):
                d.Clear()
                d.dim_value = int(s)
    return m


def network_layers(model: onnx.ModelProto, input_shapes: dict | None = None) -> list[dict]:
    """Every Conv and ConvTranspose node of an ONNX network, in graph order: its name (the
    weight's initializer name without ".weight", else the node's), op, input and output
    shapes (ONNX shape inference, the graph inputs' symbolic dims fixed by `input_shapes`),
    weight and bias (initializers), attributes, and the epilogue clss.Model fuses into it
    (clss.model.passes.fuse_conv_epilogues): the activation that alone reads its output,
    or a residual Add of the output's shape that alone reads it, then such an activation."""
    from clss.model.passes import ACT_OPS
    m = fixed_inputs(model, input_shapes or {})
    inferred = onnx.shape_inference.infer_shapes(m)
    shapes = {v.name: tuple(d.dim_value for d in v.type.tensor_type.shape.dim)
              for g in (inferred.graph.value_info, inferred.graph.input, inferred.graph.output) for v in g}
    inits = {t.name: onnx.numpy_helper.to_array(t) for t in m.graph.initializer}
    outputs = {o.name for o in m.graph.output}
    consumers: dict[str, list] = {}
    for n in m.graph.node:
        for i in n.input:
            consumers.setdefault(i, []).append(n)

    def only_reader(t):
        c = consumers.get(t, [])
        return c[0] if len(c) == 1 and t not in outputs else None

    layers = []
    for n in m.graph.node:
        if n.op_type not in ("Conv", "ConvTranspose"):
            continue
        a = {x.name: helper.get_attribute_value(x) for x in n.attribute}
        if a.get("auto_pad", b"NOTSET") not in (b"NOTSET", "NOTSET") or "output_shape" in a:
            raise ValueError(f"{n.name or n.op_type}: auto_pad / output_shape layers are not benched "
                             "(explicit pads only)")
        if n.input[1] not in inits:
            raise ValueError(f"{n.name or n.op_type}: its weight is not an initializer")
        y, act, alpha, residual = n.output[0], "none", 0.01, False
        nxt = only_reader(y)
        if (nxt is not None and nxt.op_type == "Add" and len(nxt.input) == 2
                and nxt.input[0] != nxt.input[1]):
            other = nxt.input[1] if nxt.input[0] == y else nxt.input[0]
            if shapes.get(other) == shapes[y]:
                residual, y = True, nxt.output[0]
                nxt = only_reader(y)
        if nxt is not None and nxt.op_type in ACT_OPS:
            act = ACT_OPS[nxt.op_type]
            alpha = float(next((helper.get_attribute_value(x) for x in nxt.attribute if x.name == "alpha"),
                               0.01))
        wname = n.input[1]
        bias = n.input[2] if len(n.input) > 2 and n.input[2] else None
        layers.append(dict(
            name=wname[:-len(".weight")] if wname.endswith(".weight") else (n.name or wname),
            op=n.op_type, x_shape=shapes[n.input[0]], o_shape=shapes[n.output[0]],
            w=inits[wname], b=None if bias is None else inits[bias],
            strides=tuple(a.get("strides", (1, 1))), pads=tuple(a.get("pads", (0,) * 4)),
            dilations=tuple(a.get("dilations", (1, 1))), group=int(a.get("group", 1)),
            output_padding=tuple(a.get("output_padding", (0, 0))),
            act=act, alpha=alpha, residual=residual))
    return layers


def layer_flops(L: dict) -> float:
    """2 x the multiply-adds of one layer of network_layers."""
    kh, kw = L["w"].shape[2:]
    if L["op"] == "ConvTranspose":        # every input value into Cout/group x kh x kw outputs
        return 2.0 * float(np.prod(L["x_shape"])) * L["w"].shape[1] * kh * kw
    return 2.0 * float(np.prod(L["o_shape"])) * L["w"].shape[1] * kh * kw


def layer_key(L: dict) -> tuple:
    """What makes two layers the same workload: op, weight shape, stride, pads, dilation,
    group, input shape and fused epilogue."""
    return (L["op"], tuple(L["w"].shape), L["strides"], L["pads"], L["dilations"], L["group"],
            tuple(L["x_shape"]), L["b"] is not None, L["act"], L["alpha"] if L["act"] == "leaky_relu" else None,
            L["residual"])


def layer_label(L: dict) -> str:
    """A layer's name and geometry: "<name> 3x3/s2 16->32 add+relu"."""
    T = L["op"] == "ConvTranspose"
    kh, kw = L["w"].shape[2:]
    cin, cout = (L["w"].shape[0], L["w"].shape[1] * L["group"]) if T else (L["x_shape"][1], L["w"].shape[0])
    s, d = L["strides"][0], L["dilations"][0]
    geo = (f"{kh}x{kw}{'T' if T else ''}{'/s' + str(s) if s > 1 else ''}{'/d' + str(d) if d > 1 else ''}"
           f"{' g' + str(L['group']) if L['group'] > 1 else ''}")
    epi = "+".join(filter(None, ["add" if L["residual"] else "", L["act"] if L["act"] != "none" else ""]))
    return f"{L['name']} {geo} {cin}->{cout}{' ' + epi if epi else ''}"


def layer_case(L: dict, tier: str, name: str, quick: bool = False) -> BenchCase:
    """One layer of network_layers as a bench case: clss.ops.conv on seeded inputs (the
    layer's own weights) against onnxruntime on the same single node and epilogue."""
    conv = _family("conv")
    T = L["op"] == "ConvTranspose"
    op = "conv_transpose2d" if T else "conv2d"
    x_shape, o_shape, wt = L["x_shape"], L["o_shape"], L["w"]
    attrs = dict(kernel_shape=list(wt.shape[2:]), strides=list(L["strides"]), pads=list(L["pads"]))
    if L["dilations"] != (1, 1):
        attrs["dilations"] = list(L["dilations"])
    if T and L["output_padding"] != (0, 0):
        attrs["output_padding"] = list(L["output_padding"])
    if L["group"] != 1:
        attrs["group"] = L["group"]

    def build(dev, prec, params):
        arrays = {"x": np.maximum(_normal(("bench conv x", L["name"]), x_shape), 0), "w": wt}
        if L["b"] is not None:
            arrays["b"] = L["b"]
        if L["residual"]:
            arrays["r"] = _normal(("bench conv r", L["name"]), o_shape)

        # As a network runs a layer: its weights packed once (conv2d's packed cache) and its
        # output written into one buffer (fresh ones paid their pages' first touch each run,
        # and the blocked rows repacked their weights every call)
        packed, out = {}, dev.empty(o_shape, prec)

        def engine(d):
            # params is read on every run: the tuner changes it between candidates.
            # (only what differs from the defaults: the tuning database decides the rest)
            defaults = getattr(conv, "TUNING", {})
            tuning = {k: v for k, v in params.items() if k in defaults and v != defaults[k]}
            kw = dict(strides=L["strides"], pads=L["pads"], dilations=L["dilations"], group=L["group"],
                      activation=L["act"], alpha=L["alpha"], residual=d.get("r"),
                      **({"tuning": tuning} if tuning else {}))
            if T:
                return conv.conv_transpose2d(dev, prec, d["x"], d["w"], d.get("b"),
                                             output_padding=L["output_padding"], out=out, **kw)
            return conv.conv2d(dev, prec, d["x"], d["w"], d.get("b"), packed=packed, out=out, **kw)
        # Long dot products: the reference's summation order differs (fp32: 9*C terms).
        tol = {"fp32": Tolerance(1e-5, 1e-4), "fp16": Tolerance(2e-3, 2e-3)}.get(prec)

        def twin(host):
            return conv_twins.twin(L["op"], {k: host.get(k) for k in ("x", "w", "b", "r")},
                                   activation=L["act"], alpha=L["alpha"],
                                   consts=tuple(k for k in ("w", "b") if k in host), **attrs)
        return make_setup(dev, prec, arrays, twin, engine, [o_shape], tol=tol)
    # conv.cl: XV in {1, 2} (A8 vectors along x), CB output channels per work-item.
    tunables = {k: tuple(v) for k, v in getattr(conv, "TUNABLES", {}).get(op, {}).items()}
    return BenchCase(name, "conv", "conv", tier, layer_flops(L), build, quick=quick,
                     shape=f"{_shape(*x_shape)}->{_shape(*o_shape)}",
                     tunables=tunables, defaults=dict(getattr(conv, "TUNING", {})), tune_op=op,
                     tune_key=f"{_shape(*x_shape)}/{_shape(*wt.shape)}/s{L['strides'][0]}")


# --- the classifier's layers ---------------------------------------------------------

def classifier_layers(height: int, width: int) -> list[dict]:
    """The conv layers of weights_tools' classifier for an output frame of
    height x width (padded to 16), with their input shapes, seeded weights, and
    the fused epilogue (ReLU, residual Add before the ReLU)."""
    from clss.methods.clss.networks import build_classifier
    return network_layers(build_classifier(height=pad16(height), width=pad16(width)))


def conv_cases(tier: str, quick_layers=("cls.stem", "cls.enc0.mid", "cls.down1")):
    (h, w), scale = TIERS[tier]
    H, W = output_size(h, w, scale)
    conv = _family("conv")
    out = [layer_case(L, tier, f"conv {layer_label(L)}", quick=L["name"] in quick_layers)
           for L in classifier_layers(H, W)]
    if hasattr(conv, "conv_transpose2d"):
        out.append(_conv_transpose_case(conv, tier, h, w))
    return out


def _conv_transpose_case(conv, tier, h, w):
    """Not a CLSS layer: the stride-2 learned upsampling NSRR-style decoders use, at
    the render size (32 channels at half res -> render res)."""
    x_shape, w_shape = (1, 32, h // 2, w // 2), (32, 32, 2, 2)
    o_shape = (1, 32, h // 2 * 2, w // 2 * 2)
    flops = 2.0 * 32 * 32 * 4 * x_shape[2] * x_shape[3]

    def build(dev, prec, params):
        g = rng("bench convT")
        arrays = {"x": _normal(("bench convT x",), x_shape),
                  "w": (g.standard_normal(w_shape) * 0.1).astype(np.float32),
                  "b": g.uniform(-0.05, 0.05, 32).astype(np.float32)}

        def twin(host):
            return conv_twins.twin("ConvTranspose", {k: host[k] for k in ("x", "w", "b")}, activation="relu",
                                   consts=("w", "b"), kernel_shape=[2, 2], strides=[2, 2])
        return make_setup(dev, prec, arrays, twin,
                          lambda d: conv.conv_transpose2d(dev, prec, d["x"], d["w"], d["b"], strides=(2, 2),
                                                          activation="relu"), [o_shape])
    return BenchCase("conv_transpose 2x2/s2 32->32 relu (NSRR-style)", "conv", "compute", tier, flops, build,
                     shape=f"{_shape(*x_shape)}->{_shape(*o_shape)}")


# --- memory-bound families ----------------------------------------------------------

def s2d_cases(tier):
    (h, w), scale = TIERS[tier]
    H, W = map(pad16, output_size(h, w, scale))
    s2d = _family("space_to_depth")
    x_shape, o_shape = (1, CLASSIFIER_CHANNELS, H, W), (1, 4 * CLASSIFIER_CHANNELS, H // 2, W // 2)

    def build(dev, prec, params):
        return make_setup(dev, prec, {"x": _normal(("bench s2d",), x_shape)},
                          lambda host: s2d_twins.twin("s2d", host["x"], 2, "DCR"),
                          lambda d: s2d.space_to_depth(dev, prec, d["x"], 2), [o_shape], exact=True)
    return [BenchCase("space_to_depth b2 23ch (classifier input)", "space_to_depth", "memory", tier, 0.0,
                      build, quick=True, shape=f"{_shape(*x_shape)}->{_shape(*o_shape)}")]


def _resize_flops(mode, out_elems):
    return {"cubic": 32.0, "linear": 8.0, "nearest": 0.0}[mode] * out_elems


def resize_cases(tier):
    (h, w), scale = TIERS[tier]
    H, W = output_size(h, w, scale)
    Hp, Wp = pad16(H), pad16(W)
    rs = _family("resize")
    specs = [  # name, input shape, scale, mode, quick
        ("resize cubic colour", (1, 3, h, w), 2, "cubic", True),
        ("resize linear motion+depth", (1, 3, h, w), 2, "linear", False),
        ("resize linear logits x2", (1, 6, Hp // 2, Wp // 2), 2, "linear", False),
        ("resize linear dec.up1 x2", (1, 32, Hp // 4, Wp // 4), 2, "linear", False),
        ("resize linear dec.up2 x4", (1, 64, Hp // 8, Wp // 8), 4, "linear", False),
        ("resize linear dec.up3 x8", (1, 128, Hp // 16, Wp // 16), 8, "linear", False),
    ]
    out = []
    for name, x_shape, s, mode, quick in specs:
        o_shape = x_shape[:2] + (x_shape[2] * s, x_shape[3] * s)
        scales = np.array([1, 1, s, s], np.float32)

        def build(dev, prec, params, x_shape=x_shape, o_shape=o_shape, s=s, mode=mode, scales=scales, name=name):
            def twin(host):
                return resize_twins.twin(host["x"], scales=scales, opset=18, mode=mode,
                                         coordinate_transformation_mode="half_pixel", cubic_coeff_a=-0.75)
            return make_setup(dev, prec, {"x": _normal(("bench resize", name), x_shape)}, twin,
                              lambda d: rs.resize(dev, prec, d["x"], scales=(s, s), mode=mode,
                                                  coord="half_pixel", cubic_a=-0.75),
                              [o_shape])
        out.append(BenchCase(name, "resize", "memory", tier, _resize_flops(mode, np.prod(o_shape)), build,
                             quick=quick, shape=f"{_shape(*x_shape)}->{_shape(*o_shape)}"))
    return out


def smooth_motion(key, shape, amplitude=4.0):
    """A motion field [1,2,H,W] in pixels: a smooth pan and swirl plus small noise,
    so neighbouring pixels read neighbouring texels, as in a rendered frame."""
    n, _, H, W = shape
    yy, xx = np.meshgrid(np.linspace(0, 1, H, dtype=np.float32), np.linspace(0, 1, W, dtype=np.float32),
                         indexing="ij")
    mx = amplitude * (0.6 + 0.4 * np.sin(6.0 * yy + 2.0 * xx))
    my = amplitude * 0.5 * np.cos(5.0 * xx - 3.0 * yy)
    m = np.stack([mx, my])[None].astype(np.float32)
    return m + 0.25 * rng(*key).standard_normal(m.shape, dtype=np.float32)


def warp_cases(tier):
    (h, w), scale = TIERS[tier]
    H, W = output_size(h, w, scale)
    wp = _family("warp")
    out = []
    # Stage 5: the 16-channel history (colour bicubic, the rest bilinear) at output res,
    # by the upsampled motion in output pixels.
    x_shape, m_shape = (1, 16, H, W), (1, 2, H, W)

    def build_hist(dev, prec, params):
        arrays = {"x": _normal(("bench warp x",), x_shape), "motion": smooth_motion(("bench warp",), m_shape)}
        return make_setup(dev, prec, arrays,
                          lambda host: warp_twins.twin_warp(host["x"], host["motion"], "bilinear", "border",
                                                            cubic_channels=3),
                          lambda d: wp.warp(dev, prec, d["x"], d["motion"], mode="bilinear", padding="border",
                                            cubic_channels=3),
                          [x_shape], tol=_warp_tol(prec, H, W))
    out.append(BenchCase("warp history 16ch (3 bicubic + 13 bilinear)", "warp", "memory", tier,
                         (3 * 32.0 + 13 * 8.0) * H * W, build_hist, quick=True,
                         shape=f"{_shape(*x_shape)}+motion"))

    # Stage 4: jitter-aware bicubic upsample of the colour, as GridSample from render res.
    c_shape = (1, 3, h, w)

    def build_up(dev, prec, params):
        gx = (2.0 * (np.arange(W) + 0.5) / W - 1.0 + 0.3 / w).astype(np.float32)
        gy = (2.0 * (np.arange(H) + 0.5) / H - 1.0 - 0.2 / h).astype(np.float32)
        grid = np.stack(np.broadcast_arrays(gx[None, :], gy[:, None]), -1)[None].astype(np.float32)
        arrays = {"x": _normal(("bench gs x",), c_shape), "grid": grid}
        return make_setup(dev, prec, arrays,
                          lambda host: warp_twins.twin_grid_sample(host["x"], host["grid"], "bicubic", "border",
                                                                   False),
                          lambda d: wp.grid_sample(dev, prec, d["x"], d["grid"], "bicubic", "border", False),
                          [(1, 3, H, W)], fp32=("grid",), tol=_warp_tol(prec, h, w))
    out.append(BenchCase("grid_sample bicubic colour upsample", "warp", "memory", tier, 32.0 * 3 * H * W,
                         build_up, shape=f"{_shape(*c_shape)}->{_shape(1, 3, H, W)}"))
    return out


def _warp_tol(prec, h, w):
    # The twin forms normalised grids in float32; see clss/verify/cases/warp.py.
    if prec == "fp32":
        return Tolerance(max(1e-5, 4e-7 * max(h, w)), 1e-4)
    return DEFAULT_TOL[prec]


def pool_cases(tier):
    (h, w), _ = TIERS[tier]
    pool = _family("pool")
    out = []
    for name, shape, quick in (("max_pool 3x3 depth dilation", (1, 1, h, w), False),
                               ("max_pool 3x3 colour neighbourhood", (1, 3, h, w), False)):
        def build(dev, prec, params, shape=shape, name=name):
            return make_setup(dev, prec, {"x": _normal(("bench pool", name), shape)},
                              lambda host: node_model("MaxPool", {"x": host["x"]}, kernel_shape=[3, 3],
                                                      pads=[1, 1, 1, 1], strides=[1, 1]),
                              lambda d: pool.max_pool(dev, prec, d["x"], (3, 3), (1, 1), (1, 1, 1, 1)),
                              [shape], exact=True)
        out.append(BenchCase(name, "pool", "memory", tier, 8.0 * np.prod(shape), build,
                             quick=quick, shape=_shape(*shape)))
    return out


# --- families reached through their ONNX handlers ------------------------------------

def run_nodes(dev, prec, model: onnx.ModelProto, values: dict, consts: dict):
    """Run a small graph node by node through the registered ONNX handlers:
    a minimal executor for bench twins (clss.Model does this with fusion and
    memory planning)."""
    from clss.ops import ONNX_HANDLERS
    from clss.ops.base import node_attrs
    env = dict(values)
    for node in model.graph.node:
        h = ONNX_HANDLERS[node.op_type]
        ins = []
        for i, name in enumerate(node.input):
            if not name:
                ins.append(None)
            elif i in h.const_inputs:
                ins.append(consts[name] if name in consts else dev.to_host(env[name]))
            else:
                ins.append(env[name])
        for name, v in zip(node.output, h.fn(dev, prec, node_attrs(node), ins)):
            env[name] = v
    return [env[o.name] for o in model.graph.output]


def graph_case(name, family, kind, tier, flops, twin_fn, arrays_fn, out_shapes, *, quick=False,
               shape="", exact=False, const_names=(), via_model=False):
    """A case whose engine runs the twin's nodes through the ONNX handlers, one by one
    (`via_model`: through clss.Model, its fusion passes included, as a user running
    that graph gets). `const_names`: initializers handed to handlers as numpy
    (shape-like inputs)."""
    def build(dev, prec, params):
        arrays = arrays_fn()
        holder = {}

        def twin(host):
            holder["m"] = twin_fn(host)
            return holder["m"]

        def engine(d):
            m = holder["m"]
            if via_model:
                if "model" not in holder:
                    from clss.model import Model
                    holder["model"] = Model(m, device=dev, precision=prec,
                                            input_shapes={k: tuple(v.shape) for k, v in d.items()})
                return list(holder["model"].run_device(d).values())
            inits = {t.name: onnx.numpy_helper.to_array(t) for t in m.graph.initializer}
            dev_inits = holder.setdefault("dev_inits", {k: dev.to_device(v, prec) if v.dtype.kind == "f"
                                                        else dev.to_device(v) for k, v in inits.items()
                                                        if k not in const_names})
            return run_nodes(dev, prec, m, {**d, **dev_inits}, inits)
        return make_setup(dev, prec, arrays, twin, engine, out_shapes, exact=exact)
    return BenchCase(name, family, kind, tier, flops, build, quick=quick, shape=shape)


def _handlers_for(model_ops) -> bool:
    from clss.ops import ONNX_HANDLERS
    return all(op in ONNX_HANDLERS for op in model_ops)


def elementwise_cases(tier):
    (h, w), scale = TIERS[tier]
    H, W = output_size(h, w, scale)
    Hp, Wp = pad16(H), pad16(W)
    out = []
    if _handlers_for(["Add", "Relu"]):
        s = (1, 16, Hp // 2, Wp // 2)
        out.append(graph_case(
            "add+relu residual enc0 16ch", "elementwise", "memory", tier, 2.0 * np.prod(s),
            lambda host: make_model([helper.make_node("Add", ["a", "b"], ["t"]),
                                     helper.make_node("Relu", ["t"], ["y0"])],
                                    {"a": host["a"], "b": host["b"]}, ["y0"]),
            lambda: {"a": _normal(("bench add a",), s), "b": _normal(("bench add b",), s)}, [s],
            quick=True, shape=_shape(*s), via_model=True))
    if _handlers_for(["Sub", "Mul", "Add"]):
        s, ws = (1, 3, H, W), (1, 1, H, W)
        out.append(graph_case(
            "blend w*cur+(1-w)*hist 3ch", "elementwise", "memory", tier, 3.0 * np.prod(s),
            lambda host: make_model([helper.make_node("Sub", ["cur", "hist"], ["d"]),
                                     helper.make_node("Mul", ["wt", "d"], ["t"]),
                                     helper.make_node("Add", ["hist", "t"], ["y0"])],
                                    {"cur": host["cur"], "hist": host["hist"], "wt": host["wt"]}, ["y0"]),
            lambda: {"cur": _normal(("bench blend c",), s), "hist": _normal(("bench blend h",), s),
                     "wt": rng("bench blend w").uniform(0, 1, ws).astype(np.float32)}, [s],
            shape=_shape(*s)))
    if _handlers_for(["Concat"]):
        parts = CLASSIFIER_INPUTS
        s = (1, CLASSIFIER_CHANNELS, H, W)
        out.append(graph_case(
            "concat classifier input 9->23ch", "elementwise", "memory", tier, 0.0,
            lambda host: make_model([helper.make_node("Concat", [n for n, _ in parts], ["y0"], axis=1)],
                                    {n: host[n] for n, _ in parts}, ["y0"]),
            lambda: {n: _normal(("bench concat", n), (1, c, H, W)) for n, c in parts}, [s],
            shape=_shape(*s), exact=True))
    if _handlers_for(["Pad"]) and Hp != H:
        s, so = (1, CLASSIFIER_CHANNELS, H, W), (1, CLASSIFIER_CHANNELS, Hp, Wp)
        pads = np.array([0, 0, 0, 0, 0, 0, Hp - H, Wp - W], np.int64)
        out.append(graph_case(
            f"pad classifier input {H}->{Hp}", "elementwise", "memory", tier, 0.0,
            lambda host: make_model([helper.make_node("Pad", ["x", "pads"], ["y0"], mode="edge")],
                                    {"x": host["x"]}, ["y0"], initializers={"pads": pads}),
            lambda: {"x": _normal(("bench pad",), s)}, [so], shape=f"{_shape(*s)}->{_shape(*so)}",
            exact=True, const_names=("pads",)))
    return out


def scatter_cases(tier):
    (h, w), _ = TIERS[tier]
    if not _handlers_for(["ScatterElements"]):
        return []
    n = h * w

    def arrays():
        g = rng("bench scatter")
        # Each pixel's 4 bilinear taps around p + motion (a smooth motion field).
        m = smooth_motion(("bench scatter m",), (1, 2, h, w), 3.0)[0]
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        px, py = np.floor(xx + m[0]).astype(np.int64), np.floor(yy + m[1]).astype(np.int64)
        idx = np.concatenate([np.clip(py + dy, 0, h - 1) * w + np.clip(px + dx, 0, w - 1)
                              for dy in (0, 1) for dx in (0, 1)], axis=None)
        upd = np.tile(g.uniform(0, 1, n).astype(np.float32), 4)
        return {"data": np.zeros((1, n), np.float32), "indices": idx.reshape(1, -1),
                "updates": upd.reshape(1, -1)}
    return [graph_case("scatter max depth reconstruction (4 taps)", "scatter", "memory", tier, 4.0 * n,
                       lambda host: scatter_twins.twin_scatter_elements(host["data"], host["indices"],
                                                                        host["updates"], 1, "max"),
                       arrays, [(1, n)], shape=f"{h}x{w} x4 taps", exact=True)]


MLP_TUNABLES = {"XV": (1, 2)}


def mlp_cases(tier):
    (h, w), scale = TIERS[tier]
    H, W = output_size(h, w, scale)
    mlp = _family("mlp")
    from clss.methods.clss.networks import build_composition
    m = build_composition(height=H, width=W)
    inits = {t.name: onnx.numpy_helper.to_array(t) for t in m.graph.initializer}
    w1, b1 = inits["comp.fc1.weight"], inits["comp.fc1.bias"]
    w2, b2 = inits["comp.fc2.weight"], inits["comp.fc2.bias"]
    cin, hid = w1.shape[1], w1.shape[0]
    x_shape = (1, cin, H, W)
    flops = 2.0 * (cin * hid + hid * w2.shape[0]) * H * W

    def build(dev, prec, params):
        def twin(host):
            return mlp_twins.twin(host["x"], [(host["w1"], host["b1"], "relu"), (host["w2"], host["b2"], "sigmoid")],
                                  consts=True)
        arrays = {"x": _normal(("bench mlp",), x_shape), "w1": w1, "b1": b1, "w2": w2, "b2": b2}
        # Packed once, as a network would be; the device copies in `arrays` only count the bytes.
        net = mlp.pack(dev, prec, [(w1, b1, "relu"), (w2, b2, "sigmoid")])

        def engine(d):
            defaults = getattr(mlp, "TUNING", {})
            tun = {k: v for k, v in params.items() if k in defaults and v != defaults[k]}
            return mlp.mlp(dev, prec, d["x"], net, **({"tuning": tun} if tun else {}))
        return make_setup(dev, prec, arrays, twin, engine, [(1, w2.shape[0], H, W)])
    return [BenchCase(f"mlp composition {cin}->{hid}->1 sigmoid", "mlp", "compute", tier, flops, build,
                      quick=True, shape=_shape(*x_shape), tunables=MLP_TUNABLES if hasattr(mlp, "TUNING") else {},
                      defaults=dict(getattr(mlp, "TUNING", {})), tune_op="mlp",
                      tune_key=f"{_shape(*x_shape)}/{cin}-{hid}-1")]


FAMILY_CASES = {
    "space_to_depth": s2d_cases,
    "resize": resize_cases,
    "warp": warp_cases,
    "pool": pool_cases,
    "conv": conv_cases,
    "mlp": mlp_cases,
    "elementwise": elementwise_cases,
    "scatter": scatter_cases,
}
