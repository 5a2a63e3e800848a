"""Network weights as safetensors, for every method's networks: save, load (checked),
apply to a graph, fp16, and a method's file of weights plus its config."""
from __future__ import annotations

import json
import os
import struct
import tempfile
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from onnx import numpy_helper

from clss.errors import UserError


class WeightsError(UserError):
    """A weights file that cannot be used; the message names the file (and the tensor)."""


# A value beyond this magnitude in a weights file is a broken file or a diverged training
# run, not a network (the networks see PQ-encoded inputs in [0, 1]; trained weights and
# normalisation statistics stay orders of magnitude below it).
MAX_ABS_WEIGHT = 1e6


def _is_weight(name):
    # Resize scales are graph structure, not learned weights.
    return not name.endswith(".scales")


def model_weights(model) -> dict:
    return {t.name: numpy_helper.to_array(t) for t in model.graph.initializer
            if _is_weight(t.name)}


def to_fp16(tensors: dict) -> dict:
    """Float tensors cast to float16 (the fp16-storage engine path loads these)."""
    return {k: v.astype(np.float16) if v.dtype.kind == "f" else v for k, v in tensors.items()}


def save_weights(model_or_tensors, path, half=False):
    """Write the learned tensors of one or more models (or a dict) to safetensors.

    Accepts a ModelProto, a dict name -> array, or a list of either. Atomic."""
    items = model_or_tensors if isinstance(model_or_tensors, (list, tuple)) else [model_or_tensors]
    tensors = {}
    for it in items:
        tensors.update(it if isinstance(it, dict) else model_weights(it))
    if half:
        tensors = to_fp16(tensors)
    tensors = {k: np.ascontiguousarray(v) for k, v in tensors.items()}
    # One metadata entry: safetensors keeps the metadata in a hash map whose order
    # changes from process to process, so two entries made the same tensors into
    # files that differed in their header (and `make train` byte-identical by chance).
    write_safetensors(tensors, path, {"producer": f"weights_tools ({'float16' if half else 'float32'})"})


def write_safetensors(tensors: dict, path, metadata: dict) -> None:
    """tensors (contiguous arrays) and metadata (str -> str, one entry for a header that does
    not depend on a hash map's order) to `path`, atomically: a temporary file beside it,
    renamed over it, with the permissions a new file gets (mkstemp's 0600 would ignore the
    umask). Every weights file of clss is written here."""
    from safetensors.numpy import save_file

    from ..filemode import new_file_mode
    d = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(suffix=".safetensors.tmp", dir=d)
    os.close(fd)
    try:
        save_file(tensors, tmp, metadata=metadata)
        os.chmod(tmp, new_file_mode())
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def _bf16_to_f32(raw):
    return (np.frombuffer(raw, np.uint16).astype(np.uint32) << 16).view(np.float32)


_ST_DTYPES = {"F64": np.float64, "F32": np.float32, "F16": np.float16, "I64": np.int64,
              "I32": np.int32, "I16": np.int16, "I8": np.int8, "U8": np.uint8, "BOOL": np.bool_}


def load_weights(path) -> dict:
    """name -> numpy array. Reads the safetensors layout directly so that bf16 files
    written by torch load too (as float32). Refuses, naming the file and the tensor, a
    file that is not well-formed safetensors and weights that are not finite or
    larger than MAX_ABS_WEIGHT."""
    def bad(why):
        return WeightsError(f"{path}: not a valid safetensors file ({why})")
    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            head = f.read(8)
            if len(head) < 8:
                raise bad(f"{size} bytes, shorter than the 8-byte header length")
            (n,) = struct.unpack("<Q", head)
            if n > size - 8:
                raise bad(f"header length {n} exceeds the file size {size}")
            header = json.loads(f.read(n))
            data = f.read()
    except OSError as e:
        raise WeightsError(f"{path}: cannot read ({e.strerror or e})") from None
    except WeightsError:
        raise
    except (UnicodeDecodeError, ValueError) as e:
        raise bad(f"header is not JSON: {e}") from None
    if not isinstance(header, dict):
        raise bad(f"header is a JSON {type(header).__name__}, expected an object")
    out = {}
    for name, info in header.items():
        if name == "__metadata__":
            continue
        out[name] = _tensor(path, name, info, data, bad)
    return out


def _tensor(path, name, info, data, bad):
    """One tensor of a safetensors file, checked: its entry, its bytes, its values."""
    try:
        dtype, shape, (a, b) = info["dtype"], [int(d) for d in info["shape"]], info["data_offsets"]
        a, b = int(a), int(b)
    except (KeyError, TypeError, ValueError):
        raise bad(f"tensor {name!r}: expected an entry with dtype, shape and data_offsets "
                  f"[begin, end], got {info!r}") from None
    if dtype == "BF16":
        itemsize = 2
    elif dtype in _ST_DTYPES:
        itemsize = np.dtype(_ST_DTYPES[dtype]).itemsize
    else:
        raise WeightsError(f"{path}: tensor {name} has unsupported dtype {dtype}")
    want = itemsize * int(np.prod(shape, dtype=np.int64))
    if not 0 <= a <= b or b - a != want or any(d < 0 for d in shape):
        raise bad(f"tensor {name!r}: data_offsets [{a}, {b}] do not hold {dtype} {shape} "
                  f"({want} bytes)")
    if b > len(data):
        raise bad(f"tensor {name!r}: data ends at byte {b}, the file holds {len(data)} "
                  "(truncated?)")
    raw = data[a:b]
    arr = _bf16_to_f32(raw) if dtype == "BF16" else np.frombuffer(raw, _ST_DTYPES[dtype])
    arr = arr.reshape(shape).copy()
    if arr.dtype.kind == "f" and arr.size:
        finite = np.isfinite(arr)
        if not finite.all():
            raise WeightsError(f"{path}: tensor {name!r} holds {int((~finite).sum())} non-finite "
                               "(NaN/Inf) values; the weights are broken")
        peak = float(np.abs(arr).max())
        if peak > MAX_ABS_WEIGHT:
            raise WeightsError(f"{path}: tensor {name!r} holds a value of magnitude {peak:.3g} "
                               f"(more than {MAX_ABS_WEIGHT:g}); the weights are broken")
    return arr


def apply_weights(model, tensors: dict, strict=False):
    """Replace the model's initializers by same-named tensors (cast to the
    initializer's dtype). Shapes must match; with strict, every learned initializer
    must be given. Returns the names applied."""
    applied = []
    for i, t in enumerate(model.graph.initializer):
        if t.name not in tensors:
            continue
        old = numpy_helper.to_array(t)
        new = np.asarray(tensors[t.name])
        if new.shape != old.shape:
            raise WeightsError(f"{t.name}: shape {new.shape} does not match the graph's "
                               f"{old.shape}")
        model.graph.initializer[i].CopyFrom(numpy_helper.from_array(new.astype(old.dtype), t.name))
        applied.append(t.name)
    if strict:
        missing = sorted(set(model_weights(model)) - set(applied))
        if missing:
            raise WeightsError(f"no weights given for {', '.join(missing)}")
    return applied


def save_with_config(path, key: str, cfg: dict, weights: dict) -> None:
    """A method's network file: its float32 tensors, sorted, and its config as JSON under
    the one metadata entry `key` (one entry: safetensors' header order then does not
    depend on a hash map, so a rerun writes the same bytes)."""
    write_safetensors({k: np.ascontiguousarray(v, np.float32) for k, v in sorted(weights.items())},
                      path, {key: json.dumps(cfg, sort_keys=True)})


def load_with_config(path, key: str, what: str) -> tuple[dict, dict]:
    """(config, float32 tensors) of a file save_with_config wrote; a file without `key`
    is refused as not `what` (e.g. "<METHOD> weights")."""
    from safetensors import safe_open
    with safe_open(path, "np") as f:
        meta = f.metadata() or {}
        weights = {k: f.get_tensor(k).astype(np.float32) for k in f.keys()}
    if key not in meta:
        raise ValueError(f"weights: {path} has no {key} metadata (not {what})")
    return json.loads(meta[key]), weights


def preset_widths(widths, presets: dict) -> dict:
    """A config's widths: a preset by name (a key of `presets`, recorded as "name") or a
    dict of the room's own (named "custom" unless it says)."""
    if isinstance(widths, str):
        if widths not in presets:
            raise ValueError(f"widths: expected one of {', '.join(presets)}, got {widths!r}")
        return dict(presets[widths], name=widths)
    w = dict(widths)
    w.setdefault("name", "custom")
    return w


def zero_head(name: str, shapes: dict) -> dict:
    """Layer `name`'s tensors at zero (`shapes`: a network's {name: (out, in, k)})."""
    co, ci, k = shapes[name]
    return {f"{name}.weight": np.zeros((co, ci, k, k), np.float32),
            f"{name}.bias": np.zeros(co, np.float32)}


def with_rules_base(cfg: dict, weights: dict, *, key: str, layer: str, layer_shapes,
                    check) -> tuple[dict, dict]:
    """(cfg, weights) of paper-form weights given the rules' base (issue 53; NSS's and
    NSRD's): config `key` set to "rules", `layer` widened to the input channels the new
    config's `layer_shapes` give it (the new channels' weights zero) and the "mix" head at
    zero, so the step is exactly clss-rules and the network as trained: a fine-tune's start.
    `check(cfg, weights)` validates the result."""
    new = {**cfg, key: "rules"}
    w = dict(weights)
    w0 = np.asarray(w[f"{layer}.weight"], np.float32)
    pad = layer_shapes(new)[layer][1] - w0.shape[1]
    w[f"{layer}.weight"] = np.concatenate(
        [w0, np.zeros((w0.shape[0], pad) + w0.shape[2:], np.float32)], axis=1)
    w.update(zero_head("mix", layer_shapes(new)))
    check(new, w)
    return new, w


@dataclass(frozen=True)
class ConfiguredWeights:
    """The weights file of a method whose networks a config describes (a room's
    networks.py): float32 tensors, the config under the metadata entry `key`, and the
    check that the tensors are the ones the config's convolutions need. A room gives its
    name, its key and `layers(cfg) -> {layer: (cout, cin, k)}` (tensors "<layer>.weight"
    [cout, cin, k, k] and "<layer>.bias" [cout]); `describe(cfg)` names the config in
    messages."""
    method: str
    key: str
    layers: Callable[[dict], dict]
    describe: Callable[[dict], str] = field(default=lambda cfg: str(cfg.get("name")))

    def check(self, cfg: dict, weights: dict) -> None:
        """ValueError naming the first tensor missing or of a shape the config does not give."""
        for name, (co, ci, k) in self.layers(cfg).items():
            for key, shape in ((f"{name}.weight", (co, ci, k, k)), (f"{name}.bias", (co,))):
                if key not in weights:
                    raise ValueError(f"{self.method} weights: missing tensor {key}")
                if tuple(weights[key].shape) != shape:
                    raise ValueError(f"{self.method} weights: {key} has shape "
                                     f"{tuple(weights[key].shape)}, the config "
                                     f"{self.describe(cfg)} needs {shape}")

    def save(self, path, cfg: dict, weights: dict) -> None:
        self.check(cfg, weights)
        save_with_config(path, self.key, cfg, weights)

    def load(self, path) -> tuple[dict, dict]:
        """(config, weights) of a file `save` wrote, checked."""
        cfg, weights = load_with_config(path, self.key, f"{self.method.upper()} weights")
        self.check(cfg, weights)
        return cfg, weights
