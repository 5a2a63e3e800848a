"""Per-pixel MLP (kernels/mlp.cl): a chain of dense layers (1x1 convolutions)
with activations, fused into one kernel whose hidden activations never leave
private memory. Its ONNX twin is the chain Conv 1x1 -> activation -> ...;
there is no ONNX op type of its own (fusing such chains is clss.Model's job)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import selfcheck, tuning as tuning_db
from ..device import Device, storage_dtype
from ..tolerance import DEFAULT_TOL
from .base import check_storage, rng
from .conv import ACTIVATIONS, builtin_free, load_defines

# Widest layer (input channels included) one kernel keeps in private memory:
# two arrays of MAX_WIDTH x 8*XV floats per work-item (8 KiB at 128, XV=1).
# Wider layers belong in conv2d 1x1 (clss.ops.conv).
MAX_WIDTH = 128
# Layers per kernel; longer chains run as several kernels through global memory.
MAX_LAYERS = 8
TUNING = {"XV": 1, "LX": 16}
# What `clss tune` searches; the engine reads the winner back per (device, shape, widths).
TUNABLES = {"mlp": {"XV": (1, 2), "LX": (8, 16, 32)}}


@dataclass(frozen=True)
class _Chunk:
    buffer: object                 # packed weights, storage type
    widths: tuple[int, ...]        # C0 .. Cn
    acts: tuple[int, ...]
    alphas: tuple[float, ...]
    offsets: tuple[int, ...]


@dataclass(frozen=True)
class MlpWeights:
    """Layers packed on the device, ready for mlp(); pack once per network."""
    prec: str
    chunks: tuple[_Chunk, ...]

    @property
    def widths(self) -> tuple[int, ...]:
        return self.chunks[0].widths[:1] + tuple(w for c in self.chunks for w in c.widths[1:])


def _layer(i, layer):
    if len(layer) == 2:
        (w, b), act = layer, "none"
    else:
        w, b, act = layer
    w = np.asarray(w.get() if hasattr(w, "get") else w, np.float32)
    if w.ndim == 4 and w.shape[2:] == (1, 1):      # ONNX Conv weight [Cout, Cin, 1, 1]
        w = w[:, :, 0, 0]
    if w.ndim != 2:
        raise ValueError(f"mlp layer {i}: weight must be [Cout, Cin] (or [Cout, Cin, 1, 1]), got {w.shape}")
    b = (np.zeros(w.shape[0], np.float32) if b is None
         else np.asarray(b.get() if hasattr(b, "get") else b, np.float32).reshape(-1))
    if b.shape != (w.shape[0],):
        raise ValueError(f"mlp layer {i}: bias shape {b.shape} != ({w.shape[0]},)")
    name, alpha = (act, 0.01) if isinstance(act, str) else (act[0], float(act[1]))
    if name not in ACTIVATIONS:
        raise ValueError(f"mlp layer {i}: activation must be one of {', '.join(ACTIVATIONS)}, got {name!r}")
    return w, b, ACTIVATIONS[name], alpha


def pack(dev: Device, prec: str, layers) -> MlpWeights:
    """layers: [(W [Cout,Cin], b [Cout] or None, act), ...] with act a name of
    conv.ACTIVATIONS or (name, alpha); numpy or device arrays."""
    if isinstance(layers, MlpWeights):
        return layers
    parsed = [_layer(i, l) for i, l in enumerate(layers)]
    if not parsed:
        raise ValueError("mlp: no layers")
    widths = [parsed[0][0].shape[1]] + [w.shape[0] for w, *_ in parsed]
    for i, (w, *_rest) in enumerate(parsed):
        if w.shape[1] != widths[i]:
            raise ValueError(f"mlp layer {i}: takes {w.shape[1]} inputs, previous layer gives {widths[i]}")
    if max(widths) > MAX_WIDTH:
        raise ValueError(f"mlp: widths {widths} exceed {MAX_WIDTH}, the most one kernel keeps in private "
                         "memory; run such layers as conv2d 1x1 (clss.ops.conv)")
    chunks = []
    for s in range(0, len(parsed), MAX_LAYERS):
        part = parsed[s:s + MAX_LAYERS]
        offsets, blobs, off = [], [], 0
        for w, b, _, _ in part:
            offsets.append(off)
            blobs += [w.reshape(-1), b]
            off += w.size + b.size
        # fp16 storage mode: values rounded to half, kept as float (kernels/mlp.cl, TW)
        packed = np.concatenate(blobs).astype(storage_dtype(prec))
        buf = dev.to_device(packed.astype(np.float32), "fp32") if prec == "fp16" else dev.to_device(packed, prec)
        chunks.append(_Chunk(buf, tuple(widths[s:s + len(part) + 1]), tuple(p[2] for p in part),
                             tuple(p[3] for p in part), tuple(offsets)))
    return MlpWeights(prec, tuple(chunks))


def mlp(dev: Device, prec: str, x, layers, out=None, tuning=None):
    """y = layer_n(...layer_1(x)) per pixel; x [N, C0, H, W] -> y [N, Cn, H, W].
    layers: an MlpWeights from pack(), or the layer list pack() takes."""
    check_storage("x", x, prec)
    net = pack(dev, prec, layers)
    if net.prec != prec:
        raise ValueError(f"mlp: weights packed for {net.prec}, called with {prec}")
    n, c, h, w = x.shape
    if c != net.widths[0]:
        raise ValueError(f"mlp: input has {c} channels, the first layer takes {net.widths[0]}")
    key = tuning_db.shape_key(tuple(x.shape), tuple(net.widths), prec)
    t = tuning_db.lookup(dev, "mlp", key, TUNING, explicit=tuning, allowed=TUNABLES["mlp"])
    xv = t["XV"]
    cur = x
    for i, ch in enumerate(net.chunks):
        last = i == len(net.chunks) - 1
        dst = out if (last and out is not None) else dev.empty((n, ch.widths[-1], h, w), prec)
        defines = dict(NL=len(ch.acts), CMAX=max(ch.widths), XV=xv, **load_defines(dev, prec, "mlp"))
        for k, wd in enumerate(ch.widths):
            defines[f"C{k}"] = wd
        for k, (a, al, off) in enumerate(zip(ch.acts, ch.alphas, ch.offsets), 1):
            defines.update({f"ACT{k}": a, f"ALPHA{k}": float(al), f"OFF{k}": off})
        kern = dev.kernel("mlp", "mlp", prec, **defines)
        # a fixed work-group size (global rounded up, the kernel guards) so PoCL
        # compiles one work-group function per network, not one per image size
        nb = -(-(h * w) // (8 * xv))
        dev.launch(kern, (-(-nb // t["LX"]) * t["LX"], n), (cur.data, ch.buffer.data, dst.data, np.int32(h * w)),
                   local_size=(t["LX"], 1))
        cur = dst
    return cur


def _selfcheck_run(dev: Device, prec: str) -> list[np.ndarray]:
    """A two-layer network over whole pixel vectors and a ragged last block."""
    g = rng("mlp selfcheck")
    x = dev.to_device(g.standard_normal((1, 6, 5, 7)).astype(np.float32), prec)
    layers = [(g.standard_normal((9, 6)).astype(np.float32) * 0.4, g.standard_normal(9).astype(np.float32),
               "relu"),
              (g.standard_normal((3, 9)).astype(np.float32) * 0.4, None, "sigmoid")]
    return [dev.to_host(mlp(dev, prec, x, layers))]


selfcheck.register(selfcheck.FastPath(
    "mlp.builtin_free_loads", "mlp", {"CLSS_CLANG_VECTORS": 1}, {"CLSS_CLANG_VECTORS": 0},
    check=_selfcheck_run, tolerance=DEFAULT_TOL.__getitem__, applies=builtin_free,
    what="loads and stores as clang vector types instead of vload/vstore builtins (PoCL)"))
