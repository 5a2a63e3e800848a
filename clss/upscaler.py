"""clss.Upscaler: the one entry point of every method.

    up = clss.Upscaler(method="clss", scale=2)          # clss.methods.names() lists them
    for f in frames:
        out = up.step(f.color, f.depth, f.motion, f.jitter, reset=f.reset, **f.gbuffers)

Every method's upscaler has the same `step(color, depth, motion, jitter, reset=False,
reactive=None, **gbuffers)` on numpy arrays and `step_device(...)` on pyopencl arrays
(docs/input-contract.md). The older `clss.Upscaler(scale, mode="net" | "rules")` is the
method "clss" / "clss-rules" and keeps working: `mode` is an alias that picks between them.
"""
from __future__ import annotations

from . import methods
from .pipeline.method import MethodUpscaler


def method_name(method=None, mode=None) -> str:
    """The registry name for `method` and the older `mode` ("net" / "rules")."""
    if mode is not None and str(mode).lower() not in methods.ALIASES:
        raise ValueError(f"mode: expected 'net' or 'rules', got {mode!r}")
    if method is None:
        return methods.canonical(mode if mode is not None else "clss")
    name = methods.canonical(method)
    if mode is None:
        return name
    by_mode = methods.canonical(mode)
    if name not in ("clss", "clss-rules"):
        raise ValueError(f"mode: applies to the method 'clss' only (net or rules), not to "
                         f"{name!r}; drop mode")
    return by_mode


class _UpscalerType(type):
    # isinstance(x, clss.Upscaler) holds for every method's upscaler.
    def __instancecheck__(cls, obj):
        return isinstance(obj, MethodUpscaler)


class Upscaler(metaclass=_UpscalerType):
    """Build the upscaler of a method: Upscaler(scale=2.0, mode=None, *args, method=None,
    **kwargs). `method`: a name of clss.methods.names() (default "clss"); `mode`: the older
    "net" / "rules" for CLSS. Further arguments go to the method's upscaler (CLSS:
    clss.methods.clss.upscaler.ClssUpscaler's weights, device, precision, ...; every
    method takes device, precision, exposure, sanitize and profile)."""

    def __new__(cls, scale=2.0, mode=None, *args, method=None, **kwargs):
        name = method_name(method, mode)
        if name in ("clss", "clss-rules"):
            from .methods.clss.upscaler import ClssUpscaler
            return ClssUpscaler(scale, "net" if name == "clss" else "rules", *args, **kwargs)
        if args:
            raise TypeError(f"Upscaler(method={name!r}): pass its options as keywords")
        return methods.create(name, scale=scale, **kwargs)
