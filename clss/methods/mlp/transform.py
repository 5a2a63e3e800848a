"""The shader MLP upscaler's geometry and transform, written once (docs/methods/mlp.md).

Everything the device frame step (mlp_upscale.cl, by -D options from
`kernel_defines`), the whole-frame ONNX twin (oracle.py) and the torch twin
(weights_tools/methods/mlp/twin.py) must agree on lives here: the neighbourhood and block
geometry at each scale, the DC removal and gamma ramp with their constants, the network's
widths and activations, and the weights file format.

Geometry (integer scale s = 2 or 3; render pixel (i, j), output pixels (y, x)):
  * one MLP evaluation per render pixel and colour channel;
  * beauty input: the 5x5 render pixels (i-2..i+2, j-2..j+2), edges clamped;
  * feature input: the 5x5 output pixels (s*i-1 .. s*i+3, s*j-1 .. s*j+3), edges clamped
    (depth_hr; zeros in the ablation "mlp-nofeature");
  * output block: B x B output pixels with B = s + 2, at the same origin (s*i-1, s*j-1):
    the s x s pixels of the render pixel plus a one-pixel ring. Output unit k < B*B is
    the output pixel (s*i-1 + k // B, s*j-1 + k % B); at 2x (B = 4) units 16..24 are
    unused, at 3x (B = 5) all 25 are the 5x5 block;
  * each output pixel is the mean of the blocks that cover it (2 x 2 at 2x everywhere;
    1, 2 or 4 at 3x; fewer at the frame's edges).

Transform (per neighbourhood, per channel): the colour is PQ-encoded (the contract's
transfer); the mean of the 25 values (the DC) is removed and the residual r goes through
the gamma ramp  ramp(r) = sign(r) * ((|r| + EPS)^(1/GAMMA) - EPS^(1/GAMMA)), which boosts
small residuals (GAMMA > 1) and is smooth at 0 (EPS). The feature pass gets the same.
The network's outputs are in the ramp domain of the beauty's residual: the block value is
mean + ramp_inv(y), then blocks are averaged and PQ-decoded.
"""
from __future__ import annotations

import os
import sys

import numpy as np

from ...pipeline.contract import PQ_C1, PQ_C2, PQ_C3, PQ_M1, PQ_M2, PQ_NITS, PQ_PEAK_NITS
from ...pipeline.method import UNTRAINED, WEIGHTS_DIR

SCALES = (2, 3)
TAPS = 5                      # the 5x5 neighbourhoods
HALF = TAPS // 2
INPUTS = 2 * TAPS * TAPS      # beauty + feature = 50
WIDTHS = (INPUTS, 50, 50, 25)
# Leaky ReLU on the hidden layers (the seed's slope is not given: 0.01, ONNX's default);
# the output layer is linear: the residuals it predicts are signed, and a leaky output
# would need 100x larger pre-activations for the negative half.
LEAKY_ALPHA = 0.01
ACTS = ("leaky_relu", "leaky_relu", "none")
GAMMA = 2.0
EPS = 1e-3
EPS_ROOT = EPS ** (1.0 / GAMMA)
LAYER_NAMES = ("fc1", "fc2", "fc3")
# The optional jitter input (issue 31): fc1 also sees the frame's jitter (jx, jy), render
# pixels, through JITTER_KEY [50, 2] (no bias). The jitter is one pair per frame, so its
# term is a per-frame constant of fc1's pre-activation: the engine adds JITTER_KEY @ jitter
# to fc1's bias on the host (jitter_bias) and the kernels' layout stays as it is. Files
# without the key ignore the jitter, as the seed does.
JITTER_KEY = "fcj.weight"


def check_scale(scale) -> int:
    s = float(scale)
    if s not in SCALES:
        raise ValueError(f"scale: the mlp method runs at integer scales "
                         f"{' and '.join(map(str, SCALES))} (its output block is "
                         f"(s+2)x(s+2)), got {scale!r}")
    return int(s)


def block(scale) -> int:
    """B: the output block's side at integer scale s (s + 2)."""
    return check_scale(scale) + 2


# ---- the transform, for numpy and torch alike (same operators on both) ------------------

def _lib(x):
    """numpy for arrays, else the array's own library (torch for the torch twin's tensors),
    which whoever made the tensor has loaded: the runtime never imports torch itself."""
    if isinstance(x, (np.ndarray, np.generic, float, int)):
        return np
    return sys.modules[type(x).__module__.split(".")[0]]


def ramp(r):
    """The gamma ramp of a DC-free residual (numpy or torch)."""
    xp = _lib(r)
    return xp.sign(r) * ((xp.abs(r) + EPS) ** (1.0 / GAMMA) - EPS_ROOT)


def ramp_inv(y):
    """Its inverse: sign(y) * ((|y| + EPS^(1/GAMMA))^GAMMA - EPS)."""
    xp = _lib(y)
    return xp.sign(y) * ((xp.abs(y) + EPS_ROOT) ** GAMMA - EPS)


def kernel_defines(scale, feature=True) -> dict:
    """The -D options of mlp_upscale.cl that carry this module's constants."""
    s = check_scale(scale)
    return dict(S=s, B=s + 2, FEATURE=int(bool(feature)), GAMMA=float(GAMMA),
                INV_GAMMA=float(1.0 / GAMMA), EPS=float(EPS), EPS_ROOT=float(EPS_ROOT),
                ALPHA=float(LEAKY_ALPHA), PQ_M1=float(PQ_M1), PQ_M2=float(PQ_M2),
                PQ_C1=float(PQ_C1), PQ_C2=float(PQ_C2), PQ_C3=float(PQ_C3))


def pq_scales(nits=PQ_NITS):
    """(linear 1.0 in PQ units, its inverse) for the kernels' encode and decode."""
    return np.float32(nits / PQ_PEAK_NITS), np.float32(PQ_PEAK_NITS / nits)


# ---- weights --------------------------------------------------------------------------------

def shipped_name(feature=True, scale=2) -> str:
    """The shipped generalist's file name under clss/weights (`make train-mlp`): one file
    per variant and scale (the block geometry, and so the network, differs between 2x and
    3x)."""
    return f"mlp_{'generalist' if feature else 'nofeature'}_x{check_scale(scale)}.safetensors"


def init_weights(seed=0) -> dict:
    """The seeded init: He-normal hidden layers, a zero output layer (an untrained network
    then returns each block's mean: a box upscale)."""
    g = np.random.default_rng(seed)
    out = {}
    for k, name in enumerate(LAYER_NAMES):
        ci, co = WIDTHS[k], WIDTHS[k + 1]
        w = g.standard_normal((co, ci)) * np.sqrt(2.0 / ci) if k < 2 else np.zeros((co, ci))
        out[f"{name}.weight"] = w.astype(np.float32)
        out[f"{name}.bias"] = np.zeros(co, np.float32)
    return out


def check_weights(tensors: dict, where="weights") -> dict:
    """{fc1.weight [50,50], fc1.bias [50], ..., fc3.weight [25,50], fc3.bias [25]} (and,
    optionally, the jitter input JITTER_KEY [50, 2]) as float32, or a ValueError naming the
    file and tensor."""
    want = {}
    for k, name in enumerate(LAYER_NAMES):
        want[f"{name}.weight"] = (WIDTHS[k + 1], WIDTHS[k])
        want[f"{name}.bias"] = (WIDTHS[k + 1],)
    if JITTER_KEY in tensors:
        want[JITTER_KEY] = (WIDTHS[1], 2)
    out = {}
    for key, shape in want.items():
        if key not in tensors:
            raise ValueError(f"{where}: no tensor {key!r} (the mlp method's weights are "
                             f"{', '.join(f'{n}.weight/bias' for n in LAYER_NAMES)})")
        a = np.asarray(tensors[key], np.float32)
        if a.shape != shape:
            raise ValueError(f"{where}: {key} has shape {a.shape}, expected {shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{where}: {key} holds non-finite values")
        out[key] = np.ascontiguousarray(a)
    return out


def has_jitter(tensors: dict) -> bool:
    """Whether the network takes the frame's jitter (JITTER_KEY)."""
    return JITTER_KEY in tensors


def jitter_bias(tensors: dict, jitter) -> np.ndarray:
    """fc1's bias for a frame with `jitter` (jx, jy): fc1.bias + JITTER_KEY @ jitter, float32
    (fc1.bias itself for a network without the jitter input)."""
    b = np.asarray(tensors["fc1.bias"], np.float32)
    if JITTER_KEY not in tensors:
        return b
    j = np.asarray(jitter, np.float32).reshape(2)
    return (b + np.asarray(tensors[JITTER_KEY], np.float32) @ j).astype(np.float32)


def bias_offset() -> int:
    """Where fc1's bias starts in packed()."""
    return WIDTHS[1] * WIDTHS[0]


def load_weights(weights=None, feature=True, scale=2):
    """(tensors, trained) from None (the shipped file of the variant and scale; the
    upscaler resolves None through its MethodSpec, which refuses a scale without one),
    "untrained", a dict of arrays, or a .safetensors path."""
    if isinstance(weights, dict):
        return check_weights(weights), True
    if weights is None:
        weights = os.path.join(WEIGHTS_DIR, shipped_name(feature, scale))
    if isinstance(weights, str) and weights == UNTRAINED:
        return init_weights(), False
    path = os.fspath(weights)
    if not os.path.isfile(path):
        raise ValueError(f"weights: {path} is not a file (an mlp .safetensors)")
    from safetensors.numpy import load_file
    try:
        tensors = load_file(path)
    except Exception as e:  # noqa: BLE001 (a corrupt file: one line naming it)
        raise ValueError(f"weights: {path} is not a readable safetensors file ({e})") from None
    return check_weights(tensors, path), True


def save_weights(tensors: dict, path, metadata=None):
    """Atomic write; one metadata entry (a deterministic header)."""
    import json

    from ...networks.weights import write_safetensors
    t = check_weights(tensors)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    write_safetensors(t, path, {"clss": json.dumps(metadata or {}, sort_keys=True)})


def packed(tensors: dict) -> np.ndarray:
    """The kernel's weight buffer: per layer W [out][in] row-major, then b [out] (the
    jitter input is not in it: jitter_bias goes into fc1's b per frame)."""
    t = check_weights(tensors)
    return np.concatenate([t[f"{n}.{p}"].reshape(-1) for n in LAYER_NAMES
                           for p in ("weight", "bias")]).astype(np.float32)


def offsets() -> tuple:
    """Offsets of each layer's W in packed() (b follows W)."""
    out, off = [], 0
    for k in range(len(LAYER_NAMES)):
        out.append(off)
        off += WIDTHS[k + 1] * WIDTHS[k] + WIDTHS[k + 1]
    return tuple(out)
