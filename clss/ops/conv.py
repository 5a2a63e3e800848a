"""Conv / ConvTranspose (kernels/conv.cl): direct NCHW convolution with fused
bias, activation and residual add."""
from __future__ import annotations

import functools
import sys
from typing import NamedTuple

import numpy as np

from .. import selfcheck, tuning as tuning_db
from . import conv_gemm, conv_probe, conv_winograd_gemm, variants
from ..device import Device
from ..tolerance import DEFAULT_TOL
from .base import Unsupported, as_str, check_storage, onnx_op, rng

ACTIVATIONS = {"none": 0, "relu": 1, "leaky_relu": 2, "sigmoid": 3, "tanh": 4}

# Register block per work-item: XV A8 vectors along x (8*XV outputs) times CB
# output channels. XV=2, CB=4 keeps 8 accumulators in flight (FMA latency x
# throughput on AVX2) with 6 loads per 8 FMAs; see the report's timings.
TUNING = {"XV": 2, "CB": 4, "LX": 8, "LZ": 16, "S2K3": 1}
# S2K3: kernels/conv.cl -DCONV_S2K3 (de-interleaved stride-2 3-tap rows) where
# the layer allows it (stride 2, kernel width 3, dilation 1 along x) and the
# self-check (conv.stride2_taps) lets it; 0 selects the reference per-tap loads.
# What `clss tune` searches (bench/tune.py), per op; the engine reads the winner back
# from the tuning database (clss/tuning.py) at each launch (_tunables).
TUNABLES = {op: {"XV": (1, 2), "CB": (1, 2, 4, 8)} for op in ("conv2d", "conv_transpose2d")}
# The channel-blocked conv2d (kernels/conv.cl conv2d_blocked): PX output pixels times NV
# vectors of output channels per work-item, BLX work-items along x per work-group.
TUNABLES["conv2d_blocked"] = {"PX": (4, 6, 8, 12, 14, 16), "NV": (1, 2, 3, 4), "BLX": (8, 16)}

_F_BIAS, _F_RES_BEFORE, _F_RES_AFTER = 1, 2, 4


def builtin_free(dev: Device) -> int:
    """-DCLSS_CLANG_VECTORS for kernels/conv.cl and mlp.cl: PoCL's CPU devices call
    their OpenCL builtins out of line, so those kernels use clang vector loads there."""
    return int("portable computing language" in dev.info.platform.lower())


def load_defines(dev: Device, prec: str, stem: str) -> dict:
    """The load variant of kernels/<stem>.cl (conv or mlp): builtin-free loads where
    builtin_free() asks for them and the self-check (clss/selfcheck.py) lets them,
    the common.h macros otherwise."""
    if not builtin_free(dev):
        return {"CLSS_CLANG_VECTORS": 0}
    return selfcheck.defines(dev, prec, f"{stem}.builtin_free_loads")


def _fast_defines(dev: Device, prec: str) -> dict:
    return {**load_defines(dev, prec, "conv"), **selfcheck.defines(dev, prec, "conv.stride2_deinterleave")}


def _weights(dev: Device, prec: str, w):
    """The weight buffer the kernels read: float32 in fp16 storage mode (see
    kernels/conv.cl, TW), converted on the device each call; else w itself."""
    if prec != "fp16":
        return w.data
    wf = dev.empty(w.shape, "fp32")
    k = dev.kernel("conv", "weights_to_float", prec)
    dev.launch(k, (w.size,), (w.data, wf.data, np.int32(w.size)))
    return wf.data


def _act(activation: str) -> int:
    if activation not in ACTIVATIONS:
        raise ValueError(f"activation must be one of {', '.join(ACTIVATIONS)}, got {activation!r}")
    return ACTIVATIONS[activation]


def _pair(v, name):
    t = tuple(int(a) for a in (v if np.ndim(v) else (v, v)))
    if len(t) != 2:
        raise ValueError(f"{name} must have 2 values (y, x), got {v!r}")
    return t


def _pads(p):
    t = tuple(int(a) for a in (p if np.ndim(p) else (p,) * 4))
    if len(t) == 2:
        t = (t[0], t[1], t[0], t[1])
    if len(t) != 4:
        raise ValueError(f"pads must be [top, left, bottom, right] (ONNX order), got {p!r}")
    return t


def shape_tuning(kh: int, kw: int, cout_g: int) -> dict:
    """Per-layer defaults laid over TUNING (a caller's `tuning` still wins): spatial
    kernels with >= 32 output channels per group take CB=8 channels x one A8
    (XV=1) per work-item: every input vector then feeds 8 FMAs with 9
    accumulators live (measured on the CLSS down1-3 and enc3.mid layers)."""
    if kh * kw > 1 and cout_g >= 32:
        return {"XV": 1, "CB": 8}
    return {}


def _channel_block(cout_g: int, cb: int) -> int:
    """Shrink the channel block for groups with few output channels (depthwise:
    1), so work-items do not compute clamped duplicates."""
    while cb > 1 and cb // 2 >= cout_g:
        cb //= 2
    return cb


def _sizes(gs, nzin, t):
    """Global and local size. A work-group spans LZ channel blocks of the same
    pixels (dimension 2 walks channel blocks fastest), so the input window is
    read from memory once and reused from cache by every channel block,
    instead of the whole input streaming through once per channel block.
    The global size is rounded up to whole groups; the kernel guards its bounds."""
    lx = t["LX"]                  # fixed: PoCL compiles one work-group function per local size
    lz = max(1, min(t["LZ"], nzin))
    return tuple(-(-g // l) * l for g, l in zip(gs, (lx, 1, lz))), (lx, 1, lz)


def _tunables(dev: Device, prec: str, op: str, x, w, strides, explicit, groups: int = 1) -> dict:
    """The register block for this launch: defaults < the tuning database's entry for
    (device, op, shapes, stride, precision) < the caller's `tuning=`."""
    key = tuning_db.shape_key(tuple(x.shape), tuple(w.shape), "s" + "x".join(map(str, strides)), prec)
    # The defaults are the per-layer ones (shape_tuning) laid over TUNING.
    defaults = {**TUNING, **(shape_tuning(w.shape[2], w.shape[3], w.shape[0] // groups)
                             if op == "conv2d" else {})}
    t = tuning_db.lookup(dev, op, key, defaults, explicit=explicit, allowed=TUNABLES[op])
    # A register block is a fast path too: the default one is self-checked against one
    # output per work-item (tuned ones were checked by `clss tune` before being stored).
    if (t["XV"], t["CB"]) != (1, 1) and not selfcheck.enabled(dev, prec, "conv.register_block"):
        t.update(selfcheck.REGISTRY["conv.register_block"].reference)
    return t


def vector_width(dev: Device) -> int:
    """Output channels per accumulator vector of conv2d_blocked: on a CPU the lanes of the
    registers its compiler emits (Device.simd_lanes: 16 on AVX-512, 8 on AVX2), else the
    device's preferred float vector width; at least 8 (GPUs report 1; there a work-item's
    8 channels are 8 registers). The driver's preferred width alone misled: pip's PoCL 3.0
    reports 16 on a Zen 4 and compiles for AVX2, where 16-lane tiles spilled (NSRR's
    features ran at 0.52x onnxruntime, with 8-lane tiles at 0.81x: docs/benchmarks.md)."""
    w = getattr(dev, "simd_lanes", None)
    if not w:
        try:
            w = int(dev.cl_device.preferred_vector_width_float)
        except Exception:
            w = 8
    return 16 if w >= 16 else 8


# NCHW inputs of at most FEW_IN channels (a network's first layer: RGB-D, NSS's 12 input
# channels, an SR model's RGB) are read in place by conv2d_blocked as blocks of one channel
# (-DICV=1): the layout transform cost as much as the conv on so few channels (NSS's
# 12 -> 32 stride-2 layer at 540x960: 4.0 ms of to_blocked beside 10.6 of conv), and the
# blocked tile with a blocked output beat the NCHW kernel on 3-12 channels by 1.3-1.7x
# (docs/benchmarks.md, "First layers").
FEW_IN = 12


def blocked_eligible(x, w, group: int) -> bool:
    """Layers conv2d_blocked covers: dense (one group) spatial convolutions with enough
    output channels that a vector of them is mostly real work. 1x1 layers and thin ones
    (< 8 out) keep the NCHW kernel. Inputs of 8 or more channels are read blocked; fewer
    only come as NCHW (FEW_IN), read in place."""
    cout, cin_g, kh, kw = w.shape
    return group == 1 and kh * kw > 1 and cout >= 8


def thin_eligible(w, group: int, strides=(1, 1), dilations=(1, 1)) -> bool:
    """Layers conv2d_thin covers on a blocked input: dense, unit stride and dilation,
    fewer than 8 output channels (heads that conv2d_blocked's output-channel vectors would
    mostly leave empty) and at least 8 input channels."""
    cout, cin_g = w.shape[0], w.shape[1]
    return group == 1 and cout < 8 and cin_g >= 8 and tuple(strides) == (1, 1) and tuple(dilations) == (1, 1)


def _host_packed(dev: Device, prec: str, w, b, packed, key, nout: int, pack, store: str | None = None
                 ) -> "BlockedWeights":
    """A layer's weights packed once, on the host, for a kernel that reads them in its own
    order: pack(w as float64 numpy) -> the packed array; the bias zero-padded to nout. Kept in
    `packed` (the model node's) per precision, under `key`, in the kernels' arithmetic type
    (or the storage of precision `store`: a kernel that loads them as a tensor)."""
    pw = None if packed is None else packed.get(prec)
    if pw is None or pw.key != key:
        bpad = np.zeros(nout, np.float32)
        if b is not None:
            bpad[:w.shape[0]] = dev.to_host(b)
        apre = store or ("fp16" if prec == "fp16-native" else "fp32")
        wp = np.ascontiguousarray(pack(dev.to_host(w).astype(np.float64)), np.float32)
        pw = BlockedWeights(dev.to_device(wp, apre), dev.to_device(bpad, apre), key)
        if packed is not None:
            packed[prec] = pw
    return pw


# conv2d_thin's register tile: OC output channels x PX pixels of ICV-lane accumulators
THIN_OC, THIN_PX, THIN_LX = 4, 4, 16   # THIN_LX: work-items per group along x


def _conv2d_thin(dev, prec, x, w, b, packed, pads, activation, alpha, residual, residual_before_act,
                 out, ho, wo):
    """conv2d_thin (kernels/conv.cl): x blocked [N, Cb, H, W, ICV] (ICV 8 or 16), NCHW out."""
    cout, cin, kh, kw = w.shape
    n, cb, h, wd, icv = x.shape
    oc = min(cout, THIN_OC)
    ng = -(-cout // oc)
    key = ("thin", oc, icv, cb)
    def pack(wh):       # [ng, Cb, KH, KW, OC, ICV], zero past Cout and Cin
        wpad = np.zeros((ng * oc, cb * icv, kh, kw))
        wpad[:cout, :cin] = wh
        return wpad.reshape(ng, oc, cb, icv, kh, kw).transpose(0, 2, 4, 5, 1, 3)
    pw = _host_packed(dev, prec, w, b, packed, key, ng * oc, pack)
    px = THIN_PX
    k = dev.kernel("conv", "conv2d_thin", prec, KH=kh, KW=kw, ICV=icv, OC=oc, PX=px, ACT=_act(activation),
                   THIN_WIDE=builtin_free(dev), **load_defines(dev, prec, "conv"))
    flags = _flags(b, residual, residual_before_act) & ~_F_BIAS
    # 16 work-items a group along x, as conv2d_blocked: PoCL, left to choose, made
    # groups of thousands, whose private tiles overflowed a worker thread's stack
    lx = THIN_LX
    dev.launch(k, (-(-(-(-wo // px)) // lx) * lx, ho, n * ng),
               (x.data, pw.wp.data, pw.bp.data, None if residual is None else residual.data, out.data,
                np.int32(cb), np.int32(h), np.int32(wd), np.int32(cout), np.int32(ho), np.int32(wo),
                np.int32(pads[0]), np.int32(pads[1]), np.int32(flags), np.float32(alpha), np.int32(ng)),
               local_size=(lx, 1, 1))
    return out


def input_block(cin: int) -> int:
    """Channels per block of a conv2d_blocked input converted from NCHW: the fewest
    blocks of at most 16 channels, split evenly (60 -> 4 x 15, 18 -> 2 x 9), so that no
    block carries more zero channels than it must (each one is a wasted FMA per tap)."""
    return -(-cin // -(-cin // 16))


# conv2d_wino (Winograd F(2x2, 3x3)): TT tiles of 2x2 outputs along x per work-item; its
# transform sums stay in a private array, capped at WINO_ACC output channels x tiles
WINO_TT, WINO_ACC = 4, 256
# The 3x3 layers it takes: at least WINO_MIN_IN input and WINO_MIN_OUT output channels, the
# input in blocks of a multiple of 8 (its transform on 8-lane vectors). Below, the transforms
# and the private sums outweigh the 2.25x fewer multiplies: on a 2-core Zen 3, NSRR's
# 48->16 layer took 280 ms against the direct conv's 207, its 60->24 (blocks of 15, a
# scalar transform) 677 against 372, where 64->64 took 212 against 263 and 96->32 174
# against 230 (docs/benchmarks.md).
WINO_MIN_IN, WINO_MIN_OUT = 16, 32


def wino_eligible(w, group: int, strides, dilations, residual=None, gated: bool = False,
                  block: int = 0) -> bool:
    """Layers conv2d_wino covers: dense 3x3 convolutions with unit stride and dilation, at
    least WINO_MIN_IN channels in (in blocks of a multiple of 8: `block`, or input_block's
    for an NCHW input) and WINO_MIN_OUT out, with no residual."""
    cout, cin_g, kh, kw = w.shape
    return (group == 1 and (kh, kw) == (3, 3) and tuple(strides) == (1, 1) and tuple(dilations) == (1, 1)
            and cin_g >= WINO_MIN_IN and cout >= WINO_MIN_OUT and (block or input_block(cin_g)) % 8 == 0
            and residual is None and not gated)


def wino_tiling(dev: Device, cout: int) -> dict:
    """conv2d_wino's tile: NV vectors of OCV output channels (as blocked_tiling's), TT tiles,
    and OBI blocks of them per work-item, as many as fit WINO_ACC (every output channel in
    one work-item where they fit: the input transform is then done once per tile)."""
    ocv = vector_width(dev)
    nvec = -(-cout // ocv)
    nv = 2 if nvec % 2 == 0 else (3 if nvec % 3 == 0 else 1)
    ncb = -(-nvec // nv)
    obi = max(d for d in range(1, ncb + 1) if ncb % d == 0 and d * nv * ocv * WINO_TT <= WINO_ACC)
    return {"OCV": ocv, "NV": nv, "TT": WINO_TT, "OBI": obi, "ncb": ncb}


# F(2x2, 3x3)'s weight transform U = G g G^T
_WINO_G = np.array([[1, 0, 0], [.5, .5, .5], [.5, -.5, .5], [0, 0, 1]], np.float64)


def _conv2d_wino(dev, prec, x, w, b, packed, pads, activation, alpha, out, ho, wo, out_blocked=True):
    """conv2d_wino (kernels/conv.cl): x blocked [N, Cb, H, W, ICV]; y blocked, or NCHW."""
    cout, cin = w.shape[0], w.shape[1]
    n, cb, h, wd, icv = x.shape
    t = wino_tiling(dev, cout)
    ocb, ncb = t["OCV"] * t["NV"], t["ncb"]
    key = ("wino", t["OCV"], t["NV"], icv, cb)
    def pack(g):        # U [Cout, Cin, 16] -> [ncb, Cb, 16, ICV, OCB], zero past Cout and Cin
        up = np.zeros((ncb * ocb, cb * icv, 16))
        up[:cout, :cin] = np.einsum("ak,oikl,bl->oiab", _WINO_G, g, _WINO_G).reshape(cout, cin, 16)
        return up.reshape(ncb, ocb, cb, icv, 16).transpose(0, 2, 4, 3, 1)
    pw = _host_packed(dev, prec, w, b, packed, key, ncb * ocb, pack)
    k = dev.kernel("conv", "conv2d_wino", prec, OCV=t["OCV"], NV=t["NV"], TT=t["TT"], OBI=t["OBI"], ICV=icv,
                   ACT=_act(activation), WINO_WIDE=builtin_free(dev), OUT_BLOCKED=int(out_blocked),
                   **load_defines(dev, prec, "conv"))
    nz = n * ncb // t["OBI"]
    lx = 16     # as conv2d_blocked: PoCL, left to choose, makes groups whose private arrays overflow
    dev.launch(k, (-(-(-(-wo // (2 * t["TT"]))) // lx) * lx, -(-ho // 2), nz),
               (x.data, pw.wp.data, pw.bp.data, out.data, np.int32(cb), np.int32(h), np.int32(wd),
                np.int32(cout), np.int32(ho), np.int32(wo), np.int32(ncb), np.int32(pads[0]), np.int32(pads[1]),
                np.float32(alpha), np.int32(nz)),
               local_size=(lx, 1, 1))
    return out


def blocked_tiling(dev: Device, prec: str, x_shape, w, strides, explicit, blocked_in: int = 0,
                   out_blocked: bool = False) -> dict:
    """OCV, NV, PX, ICV and BLX for conv2d_blocked on this layer: defaults from the
    device's vector width and the layer's channels, laid under the tuning database's
    entry and the caller's `tuning=`. NV vectors cover the output channels with the
    least padding (at most 2, so NV*PX accumulators stay in registers); PX fills the
    register file (about 28 accumulators on a 32-register AVX-512 core). x_shape: the
    input's NCHW shape (the tuning key); blocked_in: the channels per block of an input
    that arrives blocked (a conv's output: OCV; a clss.ConcatBlocked's: input_block), 0
    for an NCHW input. An NCHW output takes PX = 8: its epilogue stores whole 8-pixel
    runs per channel (10-30 % faster than PX 14 or 6 on the NSRR and NSRD layers,
    docs/benchmarks.md)."""
    cout, cin = w.shape[0], w.shape[1]
    ocv = vector_width(dev)
    if ocv == 16 and cout <= 8 and not out_blocked:
        # at most 8 outputs stored NCHW (no blocked consumer fixes the lanes): 8-lane
        # vectors, not 16 with half the lanes multiplying zero weights
        ocv = 8
    nvec = -(-cout // ocv)
    nv = 2 if nvec >= 2 and nvec % 2 == 0 else 1
    px = (14 if nv == 1 else 6) if out_blocked else 8
    if ocv == 8:
        # Sixteen 8-wide registers (AVX2; NEON's 32 128-bit ones as pairs): NV 2 x PX 8
        # accumulators plus the weights spill, so an NCHW output takes PX 6 too (its stores
        # scalar), and an output of three vectors NV 3 x PX 4 (three FMAs per broadcast,
        # not one at NV 1). On a 2-core Zen 3 (docs/benchmarks.md): NSRD's 32->64 layer
        # 67 -> 45 ms, NSRR's 60->24 659 -> 476 ms.
        if nv == 1 and nvec % 3 == 0:
            nv, px = 3, 4
        elif nv == 2:
            px = 6
    # TUNING's PX/NV/BLX, where a test sets them, replace the per-layer defaults
    defaults = {"PX": px, "NV": nv, "BLX": 16, **{k: TUNING[k] for k in ("PX", "NV", "BLX") if k in TUNING}}
    # the lanes are in the key: a tile measured on 16-lane vectors says nothing of 8-lane ones
    key = tuning_db.shape_key(tuple(x_shape), tuple(w.shape), "s" + "x".join(map(str, strides)), prec, f"v{ocv}")
    t = tuning_db.lookup(dev, "conv2d_blocked", key, defaults,
                         explicit={k: v for k, v in (explicit or {}).items() if k in ("PX", "NV", "BLX")},
                         allowed=TUNABLES["conv2d_blocked"])
    # the input's blocks: as it arrives (clss/model/layout.py), as to_blocked makes them, or
    # one channel (an NCHW input of at most FEW_IN channels, read in place)
    icv = int(blocked_in) or (1 if cin <= FEW_IN else input_block(cin))
    t.update(OCV=ocv, ICV=icv, CB=-(-cin // icv))
    return t


class BlockedWeights:
    """A layer's weights and bias packed for conv2d_blocked (pack_blocked)."""

    def __init__(self, wp, bp, key):
        self.wp, self.bp, self.key = wp, bp, key

    @property
    def nbytes(self) -> int:
        return int(self.wp.nbytes + self.bp.nbytes)


def pack_blocked(dev: Device, prec: str, w, b, t: dict) -> BlockedWeights:
    """Weights [Cout, Cin, KH, KW] as [ncb][Cb][KH][KW][ICV][OCB] and the bias padded to
    whole OCB blocks, in the kernels' arithmetic type (float, half in fp16-native)."""
    cout, cin, kh, kw = w.shape
    ocb = t["OCV"] * t["NV"]
    ncb = -(-cout // ocb)
    apre = "fp16" if prec == "fp16-native" else "fp32"
    wp = dev.empty((ncb, t["CB"], kh, kw, t["ICV"], ocb), apre)
    bp = dev.empty((ncb * ocb,), apre)
    dev.launch(dev.kernel("conv", "pack_blocked_weights", prec), (ocb, t["ICV"], ncb * t["CB"] * kh * kw),
               (w.data, wp.data, np.int32(cout), np.int32(cin), np.int32(t["CB"]), np.int32(kh * kw),
                np.int32(t["ICV"]), np.int32(ocb)))
    dev.launch(dev.kernel("conv", "pack_blocked_bias", prec), (ncb * ocb,),
               (w.data if b is None else b.data, bp.data, np.int32(cout), np.int32(b is not None)))
    return BlockedWeights(wp, bp, _pack_key(t))


def _pack_key(t: dict) -> tuple:
    return t["OCV"], t["NV"], t["ICV"], t["CB"]


def to_blocked(dev: Device, prec: str, x, icv: int, cb: int):
    """NCHW -> [N][Cb][H][W][ICV] (zero channels past C): the conv2d_blocked input."""
    n, c, h, wd = x.shape
    xb = dev.empty((n, cb, h, wd, icv), prec)
    _to_blocked_at(dev, prec, x, xb, 0, c, 0, c)
    return xb


def _to_blocked_at(dev, prec, x, xb, c0: int, count: int, d0: int, total: int):
    """Channels c0 .. c0 + count of NCHW x into channels d0.. of blocked xb, whose channels
    past `total` are zeroed (kernels/conv.cl to_blocked_at)."""
    n, cbd, h, w, block = xb.shape
    nblk = (d0 + count - 1) // block - d0 // block + 1     # the blocks [d0, d0 + count) touches
    dev.launch(dev.kernel("conv", "to_blocked_at", prec, CLSS_CLANG_VECTORS=builtin_free(dev)), (-(-w // 16), h, n * nblk),
               (x.data, xb.data, *(np.int32(v) for v in (x.shape[1], c0, count, h, w, cbd, block, d0, total,
                                                           nblk))))


def blocked_shape(n: int, c: int, h: int, w: int, block: int) -> tuple:
    """The channel-blocked layout of an NCHW shape: [N][ceil(C / block)][H][W][block]."""
    return n, -(-c // block), h, w, block


def concat_to_blocked(dev: Device, prec: str, xs, block: int, ranges=None, scales=None):
    """Concat over channels of NCHW tensors, written in the blocked layout
    [N, ceil(C / block), H, W, block] (channels past the total zero): a concat that feeds
    only blocked convs, with no NCHW copy in between (clss/model/layout.py). ranges:
    per input (first channel, count) taken from it (a Slice absorbed), default all.
    scales: per input None, or (s, channel): the input times channel `channel` of the NCHW
    tensor s, broadcast over its channels (a Mul absorbed: to_blocked_table)."""
    ranges = ranges or [(0, x.shape[1]) for x in xs]
    scales = scales or [None] * len(xs)
    n, _, h, w = xs[0].shape
    total = sum(c for _, c in ranges)
    cbd = -(-total // block)
    out = dev.empty((n, cbd, h, w, block), prec)
    maps = {id(sc[0]): sc[0] for sc in scales if sc is not None}
    if len(xs) > 1 and all(x is xs[0] for x in xs) and len(maps) <= 1:
        # one source tensor (and one of scale maps): the whole concat in one launch
        _concat_table(dev, prec, xs[0], next(iter(maps.values()), xs[0]), out, ranges, scales, total)
        return out
    d0 = 0
    for x, (c0, count), sc in zip(xs, ranges, scales):
        check_storage("x", x, prec)
        if x.ndim != 4 or x.shape[0] != n or tuple(x.shape[2:]) != (h, w) or c0 + count > x.shape[1]:
            raise ValueError(f"concat_to_blocked: input {tuple(x.shape)} (channels {c0}..{c0 + count}) "
                             f"does not fit [N={n}, H={h}, W={w}]")
        if count > 0 and sc is None:       # the last block's channels past the total are zeroed
            _to_blocked_at(dev, prec, x, out, c0, count, d0, total)
        elif count > 0:     # a scaled input: its lanes only (the table's other entries skip)
            _concat_table(dev, prec, x, sc[0], out, [(c0, count)], [sc], total, d0)
        d0 += count
    return out


_TABLES: dict = {}      # (context, table) -> its device copy: to_blocked_table's argument


def _concat_table(dev, prec, x, m, out, ranges, scales, total: int, d0: int = 0):
    """concat_to_blocked of channel ranges of one tensor x, some times a channel of m, from
    output channel d0 on, as one to_blocked_table launch (its table of source channels kept
    on the device); the output's other channels below `total` are left as they are."""
    check_storage("x", x, prec)
    check_storage("scale", m, prec)
    tab = [(-1, -1)] * d0
    for (c0, count), sc in zip(ranges, scales):
        if c0 + count > x.shape[1] or (sc is not None and not 0 <= sc[1] < m.shape[1]):
            raise ValueError(f"concat_to_blocked: channels {c0}..{c0 + count} of {tuple(x.shape)} "
                             f"or scale channel {sc and sc[1]} of {tuple(m.shape)} out of range")
        tab += [(c0 + k, -1 if sc is None else sc[1]) for k in range(count)]
    tab += [(-1, -1)] * (total - len(tab))
    if m.ndim != 4 or tuple(m.shape[:1] + m.shape[2:]) != tuple(x.shape[:1] + x.shape[2:]):
        raise ValueError(f"concat_to_blocked: scale {tuple(m.shape)} does not fit {tuple(x.shape)}")
    base = getattr(dev, "base", dev)    # a model's planning device: the table outlives the plan
    key = (base.context, tuple(tab))
    t = _TABLES.get(key)
    if t is None:
        t = _TABLES[key] = base.to_device(np.asarray(tab, np.int32).reshape(-1))
    n, cbd, h, w, block = out.shape
    dev.launch(dev.kernel("conv", "to_blocked_table", prec), (-(-w // 16), h, n * cbd),
               (x.data, m.data, out.data, t.data,
                *(np.int32(v) for v in (x.shape[1], m.shape[1], h, w, cbd, block, total))))


def _conv2d_blocked(dev, prec, x, w, b, t, packed, strides, pads, dilations, activation, alpha,
                    residual, residual_before_act, out, ho, wo, out_blocked, gated=False):
    cout, cin, kh, kw = w.shape
    n, h, wd = x.shape[0], x.shape[2], x.shape[3]     # NCHW and blocked [N][Cb][H][W][V] alike
    sy, sx = strides
    dy, dx = dilations
    pt, pl = pads[0], pads[1]
    pw = None if packed is None else packed.get(prec)
    if pw is None or pw.key != _pack_key(t):
        pw = pack_blocked(getattr(dev, "base", dev), prec, w, b, t)
        if packed is not None:
            packed[prec] = pw
    if x.ndim == 5:
        xb = x
    elif t["ICV"] == 1:         # NCHW is the blocked layout with blocks of one channel
        xb = x.reshape(x.shape + (1,))
    else:
        xb = to_blocked(dev, prec, x, t["ICV"], t["CB"])
    ocb = t["OCV"] * t["NV"]
    ncb = -(-cout // ocb)
    k = dev.kernel("conv", "conv2d_blocked", prec, KH=kh, KW=kw, SX=sx, OCV=t["OCV"], NV=t["NV"],
                   PX=t["PX"], ICV=t["ICV"], ACT=_act(activation), OUT_BLOCKED=int(out_blocked),
                   **({"GATED": 1} if gated else {}), **load_defines(dev, prec, "conv"))
    nz = n * ncb
    lx = t["BLX"]
    gs = (-(-(-(-wo // t["PX"])) // lx) * lx, ho, nz)
    flags = _flags(b, residual, residual_before_act) & ~_F_BIAS
    dev.launch(k, gs, (xb.data, pw.wp.data, pw.bp.data, None if residual is None else residual.data, out.data,
                       np.int32(t["CB"]), np.int32(h), np.int32(wd), np.int32(cout // 2 if gated else cout),
                       np.int32(ho),
                       np.int32(wo),
                       np.int32(ncb), np.int32(sy), np.int32(pt), np.int32(pl), np.int32(dy), np.int32(dx),
                       np.int32(flags), np.float32(alpha), np.int32(nz)),
               local_size=(lx, 1, 1))
    return out


def _flags(b, residual, residual_before_act):
    f = _F_BIAS if b is not None else 0
    if residual is not None:
        f |= _F_RES_BEFORE if residual_before_act else _F_RES_AFTER
    return f


def _check_common(x, w, b, residual, prec, out_shape, cout):
    check_storage("x", x, prec)
    check_storage("w", w, prec)
    if b is not None:
        check_storage("b", b, prec)
        if b.shape != (cout,):
            raise ValueError(f"bias shape {b.shape} != ({cout},)")
    if residual is not None:
        check_storage("residual", residual, prec)
        if tuple(residual.shape) != tuple(out_shape):
            raise ValueError(f"residual shape {residual.shape} != output shape {tuple(out_shape)}")


def conv_output_size(size: int, k: int, stride: int, pad_total: int, dilation: int) -> int:
    return (size + pad_total - ((k - 1) * dilation + 1)) // stride + 1


def conv2d(dev: Device, prec: str, x, w, b=None, *, strides=(1, 1), pads=(0, 0, 0, 0),
           dilations=(1, 1), group: int = 1, activation: str = "none", alpha: float = 0.01,
           residual=None, residual_before_act: bool = True, out=None, tuning=None, packed=None,
           out_blocked: bool = False, gated: bool = False, depth_to_space=None):
    """ONNX Conv on NCHW: x [N,Cin,H,W], w [Cout,Cin/group,kh,kw], b [Cout] or None;
    pads [top,left,bottom,right]. Fused epilogue: y = act(conv + b + residual)
    (residual_before_act, the ResNet pattern Conv -> Add -> Relu), or
    y = act(conv + b) + residual. residual has the output's shape.

    depth_to_space=(r, "CRD" | "DCR"): ONNX DepthToSpace of the result fused into the store
    (a pixel shuffle is CRD): y and residual are [N, Cout / r^2, Ho r, Wo r], the activation
    and residual applied at the shuffled positions. Only the rows in D2S_ROWS store so; with
    another row chosen a ValueError says so (a clss.Model then runs the conv and the
    DepthToSpace apart: the fused node's unfused parts).

    The channel-blocked layout (a graph's blocked chains, clss/model/layout.py): x may be
    [N, ceil(Cin / V), H, W, V] with V = vector_width(dev), channels past Cin ignored;
    out_blocked=True returns y as [N, ceil(Cout / V), Ho, Wo, V] (no residual). Both need
    the conv2d_blocked path (blocked_eligible, fast path conv.blocked).

    gated=True (clss/model/passes.py fuse_gated_conv): w's 2C output channels interleave a
    feature conv's and a gate conv's in blocks of vector_width(dev); y [N, C, Ho, Wo] =
    act(features + b) * sigmoid(gates + b), on the conv2d_blocked path, no residual."""
    blocked_in = x.ndim == 5
    thin = blocked_in and not out_blocked and thin_eligible(w, group, _pair(strides, "strides"),
                                                            _pair(dilations, "dilations"))
    if blocked_in or out_blocked:
        v = vector_width(dev)
        if blocked_in and (not 1 <= x.shape[4] <= 16 or x.shape[1] != -(-w.shape[1] // x.shape[4])):
            raise ValueError(f"conv2d: blocked input {tuple(x.shape)} does not hold {w.shape[1]} channels "
                             f"in blocks of at most 16")
        if thin:
            if x.shape[4] not in (8, 16) or not selfcheck.enabled(dev, prec, "conv.thin"):
                raise ValueError("conv2d: a thin conv reads the blocked layout in blocks of 8 or 16 on the "
                                 "conv.thin path")
        elif (residual is not None and out_blocked) or not blocked_eligible(None, w, group) \
                or not selfcheck.enabled(dev, prec, "conv.blocked"):
            raise ValueError("conv2d: the blocked layout needs a dense spatial conv without residual on "
                             "the conv.blocked path")
    if blocked_in:
        n, h, wd, cin = x.shape[0], x.shape[2], x.shape[3], w.shape[1]
    else:
        n, cin, h, wd = x.shape
    cout, cin_g, kh, kw = w.shape
    sy, sx = _pair(strides, "strides")
    dy, dx = _pair(dilations, "dilations")
    pt, pl, pb, pr = _pads(pads)
    if group < 1 or cin % group or cout % group or cin_g != cin // group:
        raise ValueError(f"conv2d: input channels {cin}, weight {tuple(w.shape)} and group {group} disagree")
    if min(sy, sx, dy, dx) < 1:
        raise ValueError("conv2d: strides and dilations must be >= 1")
    ho = conv_output_size(h, kh, sy, pt + pb, dy)
    wo = conv_output_size(wd, kw, sx, pl + pr, dx)
    if ho < 1 or wo < 1:
        raise ValueError(f"conv2d: output would be {ho}x{wo} for input {h}x{wd}")
    d2s = _d2s(depth_to_space, cout, blocked_in or out_blocked or gated)
    r2 = d2s[0] if d2s else 1
    out_nchw = (n, cout // 2 if gated else cout // (r2 * r2), ho * r2, wo * r2)
    _check_common(x, w, b, residual, prec, out_nchw, cout)
    if gated and (residual is not None or group != 1 or not blocked_eligible(None, w, group)
                  or cout % (2 * vector_width(dev)) or not selfcheck.enabled(dev, prec, "conv.blocked")):
        raise ValueError("conv2d: a gated conv needs a dense spatial conv without residual whose outputs are "
                         "whole vector pairs, on the conv.blocked path")
    if out is None:
        out = dev.empty(blocked_shape(n, out_nchw[1], ho, wo, vector_width(dev)) if out_blocked else out_nchw,
                        prec)
    layer = ConvLayer((n, cin, h, wd), tuple(w.shape), (sy, sx), (pt, pl, pb, pr), (dy, dx), group,
                      int(x.shape[4]) if blocked_in else 0, bool(out_blocked), bool(gated), residual is not None)
    call = ConvCall(x, w, b, packed, activation, alpha, residual, residual_before_act, out, ho, wo, tuning, d2s)
    # WINO=0 / BLOCKED=0 in `tuning` (tests, ablations) leave those rows out for NCHW layers
    nchw = not (gated or blocked_in or out_blocked)
    exclude = [name for name, flag in (("winograd", "WINO"), ("blocked", "BLOCKED"))
               if not (tuning or {}).get(flag, 1) and (nchw or name == "winograd")]
    v = variants.choose(dev, prec, "conv2d", layer_key(layer, prec), VARIANTS, layer, tuning, exclude,
                        probe=functools.partial(conv_probe.probe, tensors=layer_tensors, run=run_layer)
                        if conv_probe.enabled() else None)
    if d2s and v.name not in D2S_ROWS:
        raise ValueError(f"conv2d: row {v.name!r} stores no DepthToSpace (the rows that do: "
                         f"{', '.join(sorted(D2S_ROWS))})")
    return v.run(dev, prec, layer, call)


# The rows whose kernels store a fused DepthToSpace (kernels/d2s_index.h)
D2S_ROWS = frozenset({"direct", "gemm", "gemm_global", "mma"})


def _d2s(depth_to_space, cout: int, blocked: bool) -> tuple | None:
    """(r, crd) of a fused DepthToSpace, checked, or None."""
    if depth_to_space is None:
        return None
    r, mode = depth_to_space
    r, mode = int(r), str(mode).upper()
    if r < 1 or mode not in ("CRD", "DCR") or cout % (r * r):
        raise ValueError(f"conv2d: depth_to_space {depth_to_space!r}: a blocksize >= 1 dividing the "
                         f"{cout} output channels by its square, mode CRD or DCR")
    if blocked:
        raise ValueError("conv2d: a fused DepthToSpace stores NCHW (no blocked or gated conv)")
    return (r, mode == "CRD") if r > 1 else None


class ConvLayer(NamedTuple):
    """What the variant chooser knows of a conv2d launch: x as NCHW (its logical shape when it
    arrives blocked), w, strides (y, x), pads (top, left, bottom, right), dilations, group,
    block_in (channels per block of a blocked input, else 0), out_blocked, gated, residual."""
    x: tuple
    w: tuple
    strides: tuple
    pads: tuple
    dilations: tuple
    group: int
    block_in: int = 0
    out_blocked: bool = False
    gated: bool = False
    residual: bool = False

    @property
    def nchw(self) -> bool:
        return not (self.block_in or self.out_blocked or self.gated)

    def __str__(self) -> str:
        n, c, h, w = self.x
        co, _, kh, kw = self.w
        lay = ("b" if self.block_in else "") + ("B" if self.out_blocked else "") + ("G" if self.gated else "")
        return (f"{n}x{c}x{h}x{w}->{co} k{kh}x{kw} s{self.strides[0]}{self.strides[1]} "
                f"d{self.dilations[0]}{self.dilations[1]} g{self.group}" + (f" {lay}" if lay else "")
                + (" +res" if self.residual else ""))


class ConvCall(NamedTuple):
    """The tensors and epilogue of one conv2d launch, as the variants' run functions take them."""
    x: object
    w: object
    b: object
    packed: object
    activation: str
    alpha: float
    residual: object
    residual_before_act: bool
    out: object
    ho: int
    wo: int
    tuning: object
    d2s: tuple | None = None        # (r, crd): a DepthToSpace fused into the store (D2S_ROWS)


def layer_key(layer: ConvLayer, prec: str) -> str:
    """The tuning key of a layer: shapes, strides, pads, dilations, group, layout, precision and
    the hash of the family's kernel sources (a choice measured on other kernels never applies)."""
    lay = f"in{layer.block_in}" + ("/outB" if layer.out_blocked else "") + ("/gated" if layer.gated else "") \
        + ("/res" if layer.residual else "")
    return tuning_db.shape_key(layer.x, layer.w, "s" + "x".join(map(str, layer.strides)),
                               "p" + "x".join(map(str, layer.pads)), "d" + "x".join(map(str, layer.dilations)),
                               f"g{layer.group}", lay, prec,
                               variants.source_hash("conv", "conv_gemm", "conv_winograd_gemm"))


def _run_thin(dev, prec, L: ConvLayer, c: ConvCall):
    return _conv2d_thin(dev, prec, c.x, c.w, c.b, c.packed, L.pads[:2], c.activation, c.alpha, c.residual,
                        c.residual_before_act, c.out, c.ho, c.wo)


def _run_wino(dev, prec, L: ConvLayer, c: ConvCall):
    cin = L.x[1]
    xb = c.x if L.block_in else to_blocked(dev, prec, c.x, input_block(cin), -(-cin // input_block(cin)))
    return _conv2d_wino(dev, prec, xb, c.w, c.b, c.packed, L.pads[:2], c.activation, c.alpha, c.out, c.ho, c.wo,
                        L.out_blocked)


def _run_blocked(dev, prec, L: ConvLayer, c: ConvCall):
    t = blocked_tiling(dev, prec, L.x, c.w, L.strides, c.tuning, L.block_in, L.out_blocked)
    if L.gated and t["NV"] % 2:
        t["NV"] = 2
    return _conv2d_blocked(dev, prec, c.x, c.w, c.b, t, c.packed, L.strides, L.pads[:2], L.dilations,
                           c.activation, c.alpha, c.residual, c.residual_before_act, c.out, c.ho, c.wo,
                           L.out_blocked, L.gated)


def _run_direct(dev, prec, L: ConvLayer, c: ConvCall):
    """The NCHW register-blocked kernel (conv2d): 8*XV pixels x CB channels per work-item."""
    x, w, b, residual, out = c.x, c.w, c.b, c.residual, c.out
    n, cin, h, wd = L.x
    cout, cin_g, kh, kw = L.w
    (sy, sx), (dy, dx), group = L.strides, L.dilations, L.group
    pt, pl, pb, pr = L.pads
    ho, wo = c.ho, c.wo
    cout_g = cout // group
    t = _tunables(dev, prec, "conv2d", x, w, (sy, sx), c.tuning, group)
    # A pointwise conv with unit stride and no padding is a GEMM over flattened
    # pixels: one row of H*W, so only the image's last block takes the edge path
    # (not with a DepthToSpace: its store needs each pixel's row).
    if kh == kw == 1 and sy == sx == 1 and pt == pl == pb == pr == 0 and not c.d2s:
        h, wd, ho, wo = 1, h * wd, 1, ho * wo
    cb = _channel_block(cout_g, t["CB"])
    xb = 8 * t["XV"]
    ncb = -(-cout_g // cb)
    s2k3 = int(bool(t["S2K3"]) and sx == 2 and kw == 3 and dx == 1
               and selfcheck.enabled(dev, prec, "conv.stride2_taps"))
    k = dev.kernel("conv", "conv2d", prec, KH=kh, KW=kw, SX=sx,
                   XV=t["XV"], CB=cb, ACT=_act(c.activation), **_fast_defines(dev, prec),
                   CONV_S2K3=s2k3, **conv_gemm.d2s_defines(c.d2s))
    nz = n * group * ncb
    gs, ls = _sizes((-(-wo // xb), ho, nz), ncb, t)
    dev.launch(k, gs,
               (x.data, _weights(dev, prec, w), None if b is None else b.data,
                None if residual is None else residual.data, out.data,
                np.int32(cin), np.int32(h), np.int32(wd), np.int32(cout), np.int32(ho), np.int32(wo),
                np.int32(cin_g), np.int32(cout_g), np.int32(ncb), np.int32(group),
                np.int32(sy), np.int32(pt), np.int32(pl), np.int32(dy), np.int32(dx),
                np.int32(_flags(b, residual, c.residual_before_act)), np.float32(c.alpha), np.int32(nz)),
               local_size=ls)
    return out


def _gemm_runner(variant: str, local: int = 1, mma: int = 0):
    def run(dev, prec, L: ConvLayer, c: ConvCall):
        return conv_gemm.launch(dev, prec, L, c, _act(c.activation), _flags(c.b, c.residual, c.residual_before_act),
                                key=layer_key(L, prec), variant=variant, local=local, mma=mma)
    return run


def _run_winograd_gemm(dev, prec, L: ConvLayer, c: ConvCall):
    """winograd_gemm's run (clss/ops/conv_winograd_gemm.py), handed this module's helpers."""
    return conv_winograd_gemm.run(dev, prec, L, c, sys.modules[__name__])


def _on_gpu(dev) -> bool:
    """The GEMM rows are timed at a layer's first use on GPUs (conv_probe), never on a CPU,
    where the register-tiled rows were measured faster (clss/tuning_tables/cpu-*.json)."""
    return not dev.is_cpu


class _W(NamedTuple):
    """A weight's shape where the eligibility rules (thin_eligible, ...) take a weight."""
    shape: tuple


# The conv2d variants, in the family's own order of preference (the last resort of the
# chooser, clss/ops/variants.py: a device's tuned entry and its class's shipped table come
# first). Thin, Winograd and channel-blocked are the CPU's register-tiled paths over the
# blocked layout; direct is the portable NCHW kernel every device runs; the GEMM rows are
# the GPU's tiled implicit GEMMs (kernels/conv_gemm.cl), and winograd_gemm the GPU's Winograd
# around them (clss/ops/conv_winograd_gemm.py).
VARIANTS = (
    variants.Variant("thin", "fewer than 8 outputs from a blocked input, its channels as the vector lanes",
                     lambda dev, prec, L: (L.block_in in (8, 16) and not L.out_blocked and not L.gated
                                           and thin_eligible(_W(L.w), L.group, L.strides, L.dilations)),
                     _run_thin, ("conv.thin",)),
    variants.Variant("winograd", "Winograd F(2x2, 3x3) on the blocked layout",
                     lambda dev, prec, L: wino_eligible(_W(L.w), L.group, L.strides, L.dilations,
                                                        True if L.residual else None, L.gated, L.block_in),
                     _run_wino, ("conv.blocked", "conv.winograd")),
    variants.Variant("blocked", "output-channel vectors x pixels per work-item on the blocked layout",
                     lambda dev, prec, L: (blocked_eligible(None, _W(L.w), L.group)
                                           and not (L.residual and L.out_blocked)),
                     _run_blocked, ("conv.blocked",), {k: TUNABLES["conv2d_blocked"][k] for k in ("PX", "NV")}),
    variants.Variant("direct", "NCHW, 8*XV pixels x CB channels per work-item, no local memory",
                     lambda dev, prec, L: L.nchw, _run_direct, (), dict(TUNABLES["conv2d"])),
    variants.Variant("gemm", "implicit GEMM, TM x TN tiles staged in local memory, RM x RN per work-item",
                     lambda dev, prec, L: L.nchw, _gemm_runner("gemm"), ("conv.gemm",), dict(conv_gemm.TUNABLES),
                     probe=_on_gpu),
    variants.Variant("gemm_global", "implicit GEMM, RM x RN per work-item read from global memory",
                     lambda dev, prec, L: L.nchw, _gemm_runner("gemm_global", local=0),
                     ("conv.gemm_global",), {k: conv_gemm.TUNABLES[k] for k in ("RM", "RN")}, probe=_on_gpu),
    variants.Variant("mma", "tensor cores: mma.sync m16n8k16 through inline PTX (NVIDIA, fp16 storage)",
                     lambda dev, prec, L: L.nchw and prec == "fp16" and conv_gemm.has_mma(dev),
                     _gemm_runner("mma", mma=2), ("conv.mma",),
                     dict(conv_gemm.MMA_TUNABLES), probe=_on_gpu),
    variants.Variant("winograd_gemm", "Winograd F(2x2, 3x3) on NCHW: input and output transforms around one "
                     "grouped 1x1 GEMM (any of the rows above), >= 16 channels in and out",
                     lambda dev, prec, L: conv_winograd_gemm.eligible(L), _run_winograd_gemm,
                     ("conv.gemm", "conv.winograd_gemm"), dict(conv_winograd_gemm.TUNABLES), probe=_on_gpu),
)


def layer_tensors(dev: Device, prec: str, layer: ConvLayer):
    """Seeded x (blocked where the layer takes a blocked input), w, b and residual of a layer:
    what the first-use probe and `clss tune --level` run each row on."""
    g = np.random.default_rng(abs(hash(layer)) % (2 ** 32))
    n, c, h, w = layer.x
    co = layer.w[0]
    x = dev.to_device(g.standard_normal(layer.x).astype(np.float32), prec)
    if layer.block_in:
        x = to_blocked(dev, prec, x, layer.block_in, -(-c // layer.block_in))
    wt = dev.to_device((g.standard_normal(layer.w) / np.sqrt(np.prod(layer.w[1:]))).astype(np.float32), prec)
    b = dev.to_device(g.standard_normal(co).astype(np.float32), prec)
    r = None
    if layer.residual:
        ho = conv_output_size(h, layer.w[2], layer.strides[0], layer.pads[0] + layer.pads[2], layer.dilations[0])
        wo = conv_output_size(w, layer.w[3], layer.strides[1], layer.pads[1] + layer.pads[3], layer.dilations[1])
        r = dev.to_device(g.standard_normal((n, co, ho, wo)).astype(np.float32), prec)
    return x, wt, b, r


def run_layer(dev: Device, prec: str, layer: ConvLayer, tensors, tuning=None):
    """conv2d of a layer on layer_tensors' tensors (a relu epilogue), with `tuning`."""
    x, w, b, r = tensors
    return conv2d(dev, prec, x, w, b, strides=layer.strides, pads=layer.pads, dilations=layer.dilations,
                  group=layer.group, activation="relu", residual=r, out_blocked=layer.out_blocked, tuning=tuning)


def describe_choice(dev: Device, prec: str, x_shape, w_shape, strides=(1, 1), pads=(0, 0, 0, 0),
                    dilations=(1, 1), group: int = 1, block_in: int = 0, out_blocked: bool = False) -> str:
    """The variant conv2d runs for this NCHW layer on dev, and where the choice came from:
    'winograd (tuned)', 'direct (shipped nvidia)', 'blocked (order)' (clss bench --layers,
    clss verify)."""
    layer = ConvLayer(tuple(x_shape), tuple(w_shape), _pair(strides, "strides"), _pads(pads),
                      _pair(dilations, "dilations"), int(group), int(block_in), bool(out_blocked))
    key = layer_key(layer, prec)
    v = variants.choose(dev, prec, "conv2d", key, VARIANTS, layer)
    e = tuning_db.entry(dev, "conv2d", key)
    if e and e.get("params", {}).get("VARIANT") == v.name:
        source = "tuned"
    elif v.name in tuning_db.shipped_order(dev, "conv2d", key)[:1]:
        source = f"shipped {tuning_db.device_class(dev)}"
    else:
        source = "order"
    return f"{v.name} ({source})"


def conv_transpose_output_size(size: int, k: int, stride: int, pad_total: int, dilation: int,
                               output_padding: int = 0) -> int:
    return stride * (size - 1) + output_padding + (k - 1) * dilation + 1 - pad_total


def conv_transpose2d(dev: Device, prec: str, x, w, b=None, *, strides=(1, 1), pads=(0, 0, 0, 0),
                     dilations=(1, 1), group: int = 1, output_padding=(0, 0), activation: str = "none",
                     alpha: float = 0.01, residual=None, residual_before_act: bool = True, out=None,
                     tuning=None):
    """ONNX ConvTranspose on NCHW: x [N,Cin,H,W], w [Cin,Cout/group,kh,kw], b [Cout] or None;
    pads [top,left,bottom,right] (may be negative: extra output rows/columns that get only
    the bias), output_padding (y, x). Output size per axis:
    stride*(in-1) + output_padding + (k-1)*dilation + 1 - pad_begin - pad_end.
    Epilogue as conv2d."""
    n, cin, h, wd = x.shape
    cin_w, cout_g, kh, kw = w.shape
    sy, sx = _pair(strides, "strides")
    dy, dx = _pair(dilations, "dilations")
    oph, opw = _pair(output_padding, "output_padding")
    pt, pl, pb, pr = _pads(pads)
    if group < 1 or cin % group or cin_w != cin:
        raise ValueError(f"conv_transpose2d: input channels {cin}, weight {tuple(w.shape)} and "
                         f"group {group} disagree")
    if min(sy, sx, dy, dx) < 1:
        raise ValueError("conv_transpose2d: strides and dilations must be >= 1")
    cout = cout_g * group
    ho = conv_transpose_output_size(h, kh, sy, pt + pb, dy, oph)
    wo = conv_transpose_output_size(wd, kw, sx, pl + pr, dx, opw)
    if ho < 1 or wo < 1:
        raise ValueError(f"conv_transpose2d: output would be {ho}x{wo} for input {h}x{wd}")
    _check_common(x, w, b, residual, prec, (n, cout, ho, wo), cout)
    out = out if out is not None else dev.empty((n, cout, ho, wo), prec)
    t = _tunables(dev, prec, "conv_transpose2d", x, w, (sy, sx), tuning)
    cb = _channel_block(cout_g, t["CB"])
    xb = 8 * t["XV"]
    ncb = -(-cout_g // cb)
    k = dev.kernel("conv", "conv_transpose2d", prec, KH=kh, KW=kw, XV=t["XV"], CB=cb,
                   ACT=_act(activation), **_fast_defines(dev, prec))
    nz = n * group * ncb * sx
    nt = -(-wo // sx)
    gs, ls = _sizes((-(-nt // xb), ho, nz), ncb * sx, t)
    dev.launch(k, gs,
               (x.data, _weights(dev, prec, w), None if b is None else b.data,
                None if residual is None else residual.data, out.data,
                np.int32(cin), np.int32(h), np.int32(wd), np.int32(cout), np.int32(ho), np.int32(wo),
                np.int32(cin // group), np.int32(cout_g), np.int32(ncb), np.int32(group),
                np.int32(sy), np.int32(sx), np.int32(pt), np.int32(pl), np.int32(dy), np.int32(dx),
                np.int32(_flags(b, residual, residual_before_act)), np.float32(alpha), np.int32(nz)),
               local_size=ls)
    return out


def _selfcheck_run(dev: Device, prec: str) -> list[np.ndarray]:
    """conv2d at strides 1 and 2 (rows wide enough for the vector paths, a ragged
    tail), with few and with >= 32 output channels (both default register blocks),
    and conv_transpose2d: every load path of kernels/conv.cl once."""
    g = rng("conv selfcheck")
    x = dev.to_device(g.standard_normal((1, 5, 9, 75)).astype(np.float32), prec)
    w = dev.to_device(g.standard_normal((6, 5, 3, 3)).astype(np.float32) * 0.3, prec)
    b = dev.to_device(g.standard_normal(6).astype(np.float32), prec)
    wt = dev.to_device(g.standard_normal((5, 3, 3, 3)).astype(np.float32) * 0.3, prec)
    # 33 outputs: the per-layer block of deep 3x3 layers (shape_tuning, CB=8) too
    w33 = dev.to_device(g.standard_normal((33, 5, 3, 3)).astype(np.float32) * 0.3, prec)
    outs = [conv2d(dev, prec, x, w, b, pads=(1, 1, 1, 1), activation="relu"),
            conv2d(dev, prec, x, w, None, strides=(2, 2), pads=(1, 0, 1, 2)),
            conv2d(dev, prec, x, w33, None, strides=(2, 2), pads=(1, 1, 1, 1)),
            conv2d(dev, prec, x, w33, b=None, pads=(1, 1, 1, 1), activation="relu"),
            conv_transpose2d(dev, prec, x, wt, None, strides=(2, 2), pads=(1, 1, 0, 0))]
    return [dev.to_host(o) for o in outs]


def _selfcheck_blocked(dev: Device, prec: str) -> list[np.ndarray]:
    """conv2d_blocked against the NCHW kernel: 17 input channels (two blocks of 9),
    9 and 20 outputs (partial vectors), residuals before and after the activation,
    stride 2 with a dilation, edge and inside work-items; 8 outputs stored NCHW; and 3 input
    channels read NCHW in place (FEW_IN) by a 5x5 stride-2 conv. Small: it runs under
    oclgrind too."""
    g = rng("conv blocked selfcheck")
    xw = dev.to_device(g.standard_normal((1, 17, 4, 31)).astype(np.float32), prec)
    w9 = dev.to_device(g.standard_normal((9, 17, 3, 3)).astype(np.float32) * 0.2, prec)
    w20 = dev.to_device(g.standard_normal((20, 17, 3, 3)).astype(np.float32) * 0.2, prec)
    b9 = dev.to_device(g.standard_normal(9).astype(np.float32), prec)
    r9 = dev.to_device(g.standard_normal((1, 9, 4, 31)).astype(np.float32), prec)
    outs = [conv2d(dev, prec, xw, w9, b9, pads=(1, 1, 1, 1), activation="relu", residual=r9),
            conv2d(dev, prec, xw, w9, None, pads=(1, 1, 1, 1), residual=r9, residual_before_act=False,
                   activation="relu"),
            conv2d(dev, prec, xw, w20, None, strides=(2, 2), pads=(2, 1, 2, 1), dilations=(2, 1),
                   activation="sigmoid")]
    # 8 outputs stored NCHW: 8-lane vectors on a 16-lane device too (blocked_tiling)
    w8 = dev.to_device(g.standard_normal((8, 17, 3, 3)).astype(np.float32) * 0.2, prec)
    outs.append(conv2d(dev, prec, xw, w8, None, pads=(1, 1, 1, 1), activation="relu"))
    x3 = dev.to_device(g.standard_normal((1, 3, 7, 29)).astype(np.float32), prec)
    w3 = dev.to_device(g.standard_normal((10, 3, 5, 5)).astype(np.float32) * 0.2, prec)
    outs.append(conv2d(dev, prec, x3, w3, None, strides=(2, 2), pads=(2, 2, 2, 1),
                       activation="relu"))
    return [dev.to_host(o) for o in outs]


for _name, _fast, _ref, _what, _applies in (
        ("conv.builtin_free_loads", {"CLSS_CLANG_VECTORS": 1}, {"CLSS_CLANG_VECTORS": 0},
         "loads and stores as clang vector types instead of vload/vstore builtins (PoCL)", builtin_free),
        ("conv.stride2_deinterleave", {"CONV_DEINTERLEAVE": 1}, {"CONV_DEINTERLEAVE": 0},
         "stride-2 rows as two vector loads and .even", lambda dev: True),
        ("conv.stride2_taps", {"CONV_S2K3": 1}, {"CONV_S2K3": 0},
         "stride-2 3-tap rows: one load per row and channel, taps by de-interleaving",
         lambda dev: True),
        ("conv.register_block", {k: TUNING[k] for k in ("XV", "CB")}, {"XV": 1, "CB": 1},
         "8*XV outputs times CB channels per work-item (default block) / one vector, one channel",
         lambda dev: True),
        ("conv.blocked", {"BLOCKED": 1}, {"BLOCKED": 0},
         "dense spatial convs on a channel-blocked input with a register tile of output-channel "
         "vectors x pixels (conv2d_blocked) / the NCHW kernel (conv2d)",
         # a CPU layout: on an NVIDIA H200 it ran NSRR's U-Net at 2.3x the NCHW kernel's
         # time (540p -> 1080p: 55.8 against 24.2 ms), so GPUs run the NCHW kernel
         lambda dev: dev.is_cpu)):
    selfcheck.register(selfcheck.FastPath(
        _name, "conv", _fast, _ref, check=_selfcheck_blocked if _name == "conv.blocked" else _selfcheck_run,
        tolerance=DEFAULT_TOL.__getitem__, what=_what, applies=_applies))


def _selfcheck_thin(dev: Device, prec: str) -> list[np.ndarray]:
    """conv2d_thin on a blocked input against conv2d on the same NCHW input: 1, 3 and 7
    outputs (a partial second group), 20 input channels in blocks of 16 (a padded block)
    and 8 in one block of 8, a residual before and after the activation, a 1x1 head; odd
    width, edge and inside work-items. Small: it runs under oclgrind too."""
    g = rng("conv thin selfcheck")
    outs = []
    for cin, cout, k, act, res in ((20, 3, 3, "tanh", None), (20, 7, 3, "relu", "after"),
                                   (8, 1, 1, "none", "before")):
        x = dev.to_device(g.standard_normal((1, cin, 5, 29)).astype(np.float32), prec)
        w = dev.to_device(g.standard_normal((cout, cin, k, k)).astype(np.float32) * 0.2, prec)
        b = dev.to_device(g.standard_normal(cout).astype(np.float32), prec)
        r = dev.to_device(g.standard_normal((1, cout, 5, 29)).astype(np.float32), prec) if res else None
        if selfcheck.enabled(dev, prec, "conv.thin"):
            block = 16 if cin > 8 else 8
            x = to_blocked(dev, prec, x, block, -(-cin // block))
        p = k // 2
        outs.append(dev.to_host(conv2d(dev, prec, x, w, b, pads=(p, p, p, p), activation=act, residual=r,
                                       residual_before_act=res == "before")))
    return outs


def _register_cpu_path(name: str, option: str, check, what: str) -> None:
    """A conv fast path the host chooses on CPU devices (-D`option`=1 / 0 in the registry),
    checked within the default tolerance."""
    selfcheck.register(selfcheck.FastPath(name, "conv", {option: 1}, {option: 0}, check=check,
                                          tolerance=DEFAULT_TOL.__getitem__, what=what,
                                          applies=lambda dev: dev.is_cpu))


conv_gemm.register_selfchecks(conv2d)
conv_winograd_gemm.register_selfcheck(conv2d)
_register_cpu_path("conv.thin", "THIN", _selfcheck_thin,
                   "convs with fewer than 8 outputs read a blocked input, its channels as the vector lanes "
                   "(conv2d_thin) / the input stored NCHW for the NCHW kernel (conv2d)")


def _selfcheck_wino(dev: Device, prec: str) -> list[np.ndarray]:
    """conv2d_wino against conv2d_blocked on the same input, blocked out: 20 input
    channels in blocks of 8 (a padded block), 16 in one block of 16 (one 16-lane transform
    on PoCL, two 8-lane halves elsewhere), 24 in three; 32, 48 and 40 outputs (NV 2, 2 and 1
    on 8-wide devices; several blocks per work-item); odd sizes (a partial tile row and
    column), edge and inside work-items, asymmetric padding, four activations; and an NCHW
    input and output. Small: it runs under oclgrind too."""
    g = rng("conv wino selfcheck")
    outs = []
    for cin, block, cout, hw, pads, act in ((20, 8, 32, (7, 37), (1, 1, 1, 1), "relu"),
                                            (16, 16, 48, (6, 19), (0, 2, 2, 0), "leaky_relu"),
                                            (24, 8, 40, (5, 11), (1, 1, 1, 1), "none")):
        x = dev.to_device(g.standard_normal((1, cin) + hw).astype(np.float32), prec)
        w = dev.to_device(g.standard_normal((cout, cin, 3, 3)).astype(np.float32) * 0.2, prec)
        b = dev.to_device(g.standard_normal(cout).astype(np.float32), prec)
        xb = to_blocked(dev, prec, x, block, -(-cin // block))
        outs.append(dev.to_host(conv2d(dev, prec, xb, w, b, pads=pads, activation=act, out_blocked=True)))
    # NCHW in and out: the input blocked by the host (2 x 16), the output stored NCHW (runs of
    # 8 pixels and a ragged end)
    x = dev.to_device(g.standard_normal((1, 32, 5, 21)).astype(np.float32), prec)
    w = dev.to_device(g.standard_normal((40, 32, 3, 3)).astype(np.float32) * 0.2, prec)
    b = dev.to_device(g.standard_normal(40).astype(np.float32), prec)
    outs.append(dev.to_host(conv2d(dev, prec, x, w, b, pads=(1, 1, 1, 1), activation="tanh")))
    return outs


_register_cpu_path("conv.winograd", "WINO", _selfcheck_wino,
                   "3x3 stride-1 convs with >= 16 inputs and >= 32 outputs, on a blocked input, by Winograd "
                   "F(2x2, 3x3) (conv2d_wino) / the direct register tile (conv2d_blocked)")


# --- ONNX -----------------------------------------------------------------------

def _spatial(attrs, name, default, x):
    v = attrs.get(name)
    if v is None:
        return default
    v = [int(a) for a in v]
    if len(v) != len(default):
        raise Unsupported(f"{name}={v} for a {x.ndim if hasattr(x, 'ndim') else len(x.shape)}-D input; "
                          "only 2-D convolutions (NCHW) are covered")
    return tuple(v)


def _check_2d(op, x, w, attrs):
    if len(x.shape) != 4 or len(w.shape) != 4:
        raise Unsupported(f"{op} on {len(x.shape) - 2}-D data; only 2-D convolutions (NCHW) are covered")
    ks = attrs.get("kernel_shape")
    if ks is not None and tuple(int(k) for k in ks) != tuple(w.shape[2:]):
        raise Unsupported(f"{op} kernel_shape {list(ks)} differs from the weight's {tuple(w.shape[2:])}")


def same_pads(size, k, stride, dilation, mode):
    """ONNX auto_pad SAME_UPPER/SAME_LOWER for Conv: output ceil(in/stride); the odd
    padding element goes at the end (UPPER) or the beginning (LOWER)."""
    out = -(-size // stride)
    need = max(0, (out - 1) * stride + (k - 1) * dilation + 1 - size)
    head = need // 2 if mode == "SAME_UPPER" else (need + 1) // 2
    return head, need - head


@onnx_op("Conv")
def _onnx_conv(dev, prec, attrs, inputs):
    x, w = inputs[0], inputs[1]
    b = inputs[2] if len(inputs) > 2 else None
    _check_2d("Conv", x, w, attrs)
    strides = _spatial(attrs, "strides", (1, 1), x)
    dil = _spatial(attrs, "dilations", (1, 1), x)
    auto_pad = as_str(attrs.get("auto_pad", "NOTSET"))
    if auto_pad in ("SAME_UPPER", "SAME_LOWER"):
        (pt, pb), (pl, pr) = (same_pads(x.shape[2 + i], w.shape[2 + i], strides[i], dil[i], auto_pad)
                              for i in range(2))
        pads = (pt, pl, pb, pr)
    elif auto_pad == "VALID":
        pads = (0, 0, 0, 0)
    elif auto_pad == "NOTSET":
        pads = _spatial(attrs, "pads", (0, 0, 0, 0), x)
    else:
        raise Unsupported(f"Conv auto_pad {auto_pad!r}")
    return [conv2d(dev, prec, x, w, b, strides=strides, pads=pads, dilations=dil,
                   group=int(attrs.get("group", 1)))]


def conv_transpose_pads(size, k, stride, dilation, output_padding, out_size, auto_pad):
    """ONNX ConvTranspose pads for an explicit output size (output_shape, or
    in*stride under auto_pad SAME_*): total = stride*(in-1) + output_padding +
    (k-1)*dilation + 1 - out, split with the odd element at the beginning unless
    auto_pad is SAME_UPPER."""
    total = stride * (size - 1) + output_padding + (k - 1) * dilation + 1 - out_size
    if auto_pad == "SAME_UPPER":
        return total // 2, total - total // 2
    return total - total // 2, total // 2


@onnx_op("ConvTranspose")
def _onnx_conv_transpose(dev, prec, attrs, inputs):
    x, w = inputs[0], inputs[1]
    b = inputs[2] if len(inputs) > 2 else None
    _check_2d("ConvTranspose", x, w, attrs)
    strides = _spatial(attrs, "strides", (1, 1), x)
    dil = _spatial(attrs, "dilations", (1, 1), x)
    opad = _spatial(attrs, "output_padding", (0, 0), x)
    auto_pad = as_str(attrs.get("auto_pad", "NOTSET"))
    if auto_pad not in ("NOTSET", "SAME_UPPER", "SAME_LOWER", "VALID"):
        raise Unsupported(f"ConvTranspose auto_pad {auto_pad!r}")
    out_shape = attrs.get("output_shape")
    if out_shape is not None:
        out_shape = [int(v) for v in out_shape][-2:]
    elif auto_pad in ("SAME_UPPER", "SAME_LOWER"):
        out_shape = [x.shape[2] * strides[0], x.shape[3] * strides[1]]
    if out_shape is not None:
        (pt, pb), (pl, pr) = (conv_transpose_pads(x.shape[2 + i], w.shape[2 + i], strides[i], dil[i],
                                                  opad[i], out_shape[i], auto_pad) for i in range(2))
        pads = (pt, pl, pb, pr)
    elif auto_pad == "VALID":
        pads = (0, 0, 0, 0)
    else:
        pads = _spatial(attrs, "pads", (0, 0, 0, 0), x)
    return [conv_transpose2d(dev, prec, x, w, b, strides=strides, pads=pads, dilations=dil,
                             group=int(attrs.get("group", 1)), output_padding=opad)]


NODE_DEVIATIONS = {
    "test_convtranspose_1d": "1-D ConvTranspose: the kernels cover 2-D (NCHW) convolutions only",
    "test_convtranspose_3d": "3-D ConvTranspose: the kernels cover 2-D (NCHW) convolutions only",
}
