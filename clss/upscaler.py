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
    """The registry name for `method` and the older `mode` ("net" / "rules"): a method's
    spec names the modes that pick between the methods of its family (MethodSpec.modes)."""
    name = methods.canonical(method if method is not None else methods.DEFAULT)
    if mode is None:
        return name
    modes = methods.spec(name).modes
    if not modes:
        family = next((s.modes for s in methods.specs() if s.modes), {})
        owner = next(iter(family.values()), "?")
        raise ValueError(f"mode: applies to the method {owner!r} only "
                         f"({' or '.join(family)}), not to {name!r}; drop mode")
    key = str(mode).strip().lower()
    if key in modes:
        return modes[key]
    try:            # an alias of one of them ("rule", "clss-net")
        alias = methods.canonical(key)
    except ValueError:
        alias = None
    if alias not in modes.values():
        raise ValueError(f"mode: expected {' or '.join(map(repr, modes))}, got {mode!r}")
    return alias


class _UpscalerType(type):
    # isinstance(x, clss.Upscaler) holds for every method's upscaler.
    def __instancecheck__(cls, obj):
        return isinstance(obj, MethodUpscaler)


class Upscaler(metaclass=_UpscalerType):
    """Build the upscaler of a method: Upscaler(scale=2.0, mode=None, *args, method=None,
    **kwargs). `method`: a name of clss.methods.names() (default "clss"); `mode`: the older
    "net" / "rules" for CLSS, whose further positional arguments follow its signature
    (clss.methods.clss.upscaler.ClssUpscaler's weights, device, precision, ...). Keyword
    arguments go to the method's upscaler (`clss methods` lists the methods; every method
    takes device, precision, sanitize, profile and the caller's conventions, `contract=` a
    clss.Contract or its parameters as keywords: depth_inverted, motion_scale,
    jitter_scale, hdr, exposure, nits); one it does not take is a TypeError naming the
    closest one it does, and a convention it cannot honour a ContractError naming both."""

    def __new__(cls, scale=2.0, mode=None, *args, method=None, **kwargs):
        name = method_name(method, mode)
        if args:
            spec = methods.spec(name)
            if not spec.modes:
                raise TypeError(f"Upscaler(method={name!r}): pass its options as keywords")
            names = spec.positional()[1:]          # after the scale
            if len(args) > len(names):
                raise TypeError(f"Upscaler(method={name!r}): at most {len(names) + 2} "
                                f"positional arguments (scale, mode, {', '.join(names)})")
            for key, value in zip(names, args):
                if key in kwargs:
                    raise TypeError(f"Upscaler(method={name!r}): got multiple values for "
                                    f"argument {key!r}")
                kwargs[key] = value
        return methods.create(name, scale=scale, **kwargs)
