"""The upscaling methods, one room each; no room imports another (tests/test_architecture.py).

    clss/methods/clss/     CLSS: net mode "clss", rule mode "clss-rules", and "jbicubic"
    clss/methods/bicubic/  the plain bicubic baseline

A room exports SPECS {name: clss.pipeline.method.MethodSpec}. This registry names the
room of each method and imports it only when the method is asked for, so listing the
methods (`clss methods`) costs one import per room and no device. What a method adds to
the shared code (fast paths, command-line options, the older mode= alias) is named by its
spec; the shared code asks the spec (`specs()`), never the room.
"""
from __future__ import annotations

import importlib

# name -> room (a module under clss.methods), in the order `clss methods` lists them:
# the baselines first, then by increasing cost.
ROOMS = {"bicubic": "bicubic", "jbicubic": "clss", "clss-rules": "clss", "clss": "clss",
         "mlp": "mlp", "mlp-nofeature": "mlp", "nsrr": "nsrr", "nsrd": "nsrd"}
# Names that earlier versions used (`--mode rules|net`, eval's `rules` / `net`).
ALIASES = {"rules": "clss-rules", "rule": "clss-rules", "net": "clss", "clss-net": "clss"}
# Methods the paper seeds describe that are not built yet (`clss methods` lists them as such).
PLANNED: dict = {}
# The method of clss.Upscaler() and `clss upscale` without one.
DEFAULT = "clss"


def names() -> list[str]:
    return list(ROOMS)


def canonical(name: str) -> str:
    """The registry name of `name` (aliases resolved); a ValueError lists the methods."""
    key = str(name).strip().lower()
    key = ALIASES.get(key, key)
    if key in ROOMS:
        return key
    if key in PLANNED:
        raise ValueError(f"method: {key!r} is not built yet ({PLANNED[key]}); available: "
                         f"{', '.join(ROOMS)}")
    raise ValueError(f"method: expected one of {', '.join(ROOMS)}, got {name!r}")


def spec(name: str):
    """The MethodSpec of `name`."""
    key = canonical(name)
    return importlib.import_module(f"{__name__}.{ROOMS[key]}").SPECS[key]


def specs() -> list:
    return [spec(n) for n in ROOMS]


def create(name: str, **kwargs):
    """The upscaler of method `name` (keyword arguments as clss.Upscaler's); a keyword
    argument the method does not take is a TypeError naming the closest one it does."""
    s = spec(name)
    s.check_arguments(kwargs)
    return s.create(**kwargs)


def options(name: str, **kwargs) -> dict:
    """Those of `kwargs` that method `name` takes (None values left out): for a caller
    that feeds several methods the same options (eval, the command line, the demo)."""
    return spec(name).options(kwargs)


def twin(name: str, render_size, scale, **kwargs):
    """The whole-frame ONNX twin of method `name` (onnxruntime), with the same `step` as
    its upscaler: the oracle that tests hold the OpenCL frame step to."""
    s = spec(name)
    if not s.twin:
        raise ValueError(f"method {s.name!r} has no ONNX twin")
    module, attr = s.twin.split(":")
    return getattr(importlib.import_module(module), attr)(
        method=s.name, render_size=render_size, scale=scale, **kwargs)
