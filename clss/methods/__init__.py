"""The upscaling methods, one room each; no room imports another (tests/test_architecture.py).

    clss/methods/bicubic/  the plain bicubic baseline "bicubic"
    clss/methods/clss/     CLSS: "jbicubic", rule mode "clss-rules" and net mode "clss"
    clss/methods/mlp/      the shader MLP: "mlp" and its ablation "mlp-nofeature"
    clss/methods/nsrr/     NSRR: "nsrr"
    clss/methods/nsrd/     NSRD: "nsrd"
    clss/methods/nss/      NSS: "nss"

A room exports SPECS {name: clss.pipeline.method.MethodSpec}; `ROOMS` below is the one
line a room adds here, and every other list of methods or rooms is derived from it and
the specs: the method names (`names()`), the bench's rooms (bench/methods/), the training
rooms (weights_tools/methods/), the import contracts (.importlinter's wildcards). Listing
the methods (`clss methods`) imports each room once and touches no device. What a method
owns (`MethodSpec.parts()`) and what it adds to the shared code (fast paths, command-line
options, the older mode= alias) is named by its spec; the shared code asks the spec
(`specs()`), never the room. docs/architecture.md walks through adding a method.
"""
from __future__ import annotations

import difflib
import functools
import importlib

# The registry: one line per room (a package clss/methods/<room>/ exporting SPECS), in the
# order `clss methods` lists their methods: the baselines first, then by increasing cost.
ROOMS = (
    "bicubic",
    "clss",
    "mlp",
    "nsrr",
    "nsrd",
    "nss",
)
# Names that earlier versions used (`--mode rules|net`, eval's `rules` / `net`).
ALIASES = {"rules": "clss-rules", "rule": "clss-rules", "net": "clss", "clss-net": "clss"}
# Methods the paper seeds describe that are not built yet (`clss methods` lists them as such).
PLANNED: dict = {}
# The method of clss.Upscaler() and `clss upscale` without one.
DEFAULT = "clss"


def room_specs(room: str) -> dict:
    """The SPECS of room `room` ({method name: MethodSpec}, in the room's order)."""
    return importlib.import_module(f"{__name__}.{room}").SPECS


@functools.lru_cache(maxsize=None)
def _by_name(rooms: tuple) -> dict:
    # {method name: MethodSpec} over the rooms, in their order; each room imported once.
    out = {}
    for room in rooms:
        for name, s in room_specs(room).items():
            if name in out:
                raise RuntimeError(f"method {name!r} is defined by two rooms "
                                   f"({out[name].room} and {room})")
            out[name] = s
    return out


def names() -> list[str]:
    """Every method's name, in the order `clss methods` lists them."""
    return list(_by_name(ROOMS))


def canonical(name: str) -> str:
    """The registry name of `name` (aliases resolved); a ValueError lists the methods."""
    key = str(name).strip().lower()
    key = ALIASES.get(key, key)
    known = _by_name(ROOMS)
    if key in known:
        return key
    if key in PLANNED:
        raise ValueError(f"method: {key!r} is not built yet ({PLANNED[key]}); available: "
                         f"{', '.join(known)}")
    close = difflib.get_close_matches(key, list(known) + list(ALIASES), n=1)
    hint = f"; did you mean {ALIASES.get(close[0], close[0])!r}?" if close else ""
    raise ValueError(f"method: expected one of {', '.join(known)}, got {name!r}{hint}")


def spec(name: str):
    """The MethodSpec of `name`."""
    return _by_name(ROOMS)[canonical(name)]


def specs() -> list:
    return list(_by_name(ROOMS).values())


def create(name: str, **kwargs):
    """The upscaler of method `name` (keyword arguments as clss.Upscaler's); a keyword
    argument the method does not take is a TypeError naming the closest one it does.
    The caller's conventions, `contract=` (a clss.Contract) or its parameters as
    keywords, go to every method, which refuses by name a value it cannot honour."""
    from ..pipeline.contract import Contract
    s = spec(name)
    s.check_arguments(kwargs)
    given = {k: kwargs.pop(k) for k in Contract.names() if k in kwargs}
    contract = Contract.of(kwargs.pop("contract", None), **given)
    check_contract(s.name, contract)
    takes = s.parameters()
    if takes is None or "contract" in takes:    # one that takes none honours the default only
        kwargs["contract"] = contract
    return s.create(**kwargs)


def check_contract(name: str, contract) -> None:
    """A ContractError (a UserError) where method `name` cannot honour a parameter of
    `contract` (a clss.Contract), naming the method, the parameter and the methods that
    can: before anything is built or written."""
    from ..pipeline.contract import CANNOT
    changed = contract.changed()
    others = [o.name for o in specs()
              if not any(o.handling(p)[0] == CANNOT for p in changed)]
    spec(name).check_contract(contract, others)


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


# ---- the rules' base (issue 53 part 2): a method that refines clss-rules (NSRR's and NSS's
# "base": "rules") runs clss-rules' own frame step and twin, asked of this registry as the
# shared code asks for a method (no room imports another: .importlinter) -----------------

# clss-rules' history: colour 3, counter, colour min 3, max 3, logits 6 (clss's contract)
RULES_HISTORY_CHANNELS = 16


def config_base(cfg, bases, default: str, method: str, key: str = "base") -> str:
    """The base a method's weights config names (`key`, "base": one of `bases`), `default`
    where the config has no key (files of the paper's form); a ValueError naming the method
    otherwise. CLSS, NSRR and NSS read their "base" through it (the rules' base and the
    paper's), NSRD its "out_base" (its "base" is the lighting's upsampling)."""
    b = (cfg or {}).get(key, default)
    if b not in bases:
        raise ValueError(f"{method} config: {key} expected one of {', '.join(bases)}, got {b!r}")
    return b


def rules_frame_step(dev, prec: str, render_size, scale, nits, profile=False):
    """clss-rules' own frame step (the rule-mode kernels of clss/methods/clss/frame.cl, its
    defaults) at `render_size`. Its `run(..., read_flags=False)`, `accept()`, `state`
    ([16, H, W], PQ colour in channels 0-2) and `out` ([H, W, 3] linear x exposure) are
    what a refining method's step uses."""
    up = create("clss-rules", scale=scale, device=dev, precision=prec, nits=nits,
                profile=profile)
    return up._build_frame_step(*render_size)


def run_rules_step(rs, color, depth, motion, jitter, reset, *, depth_inverted, motion_scale,
                   exposure, profile) -> list:
    """Enqueue a rules_frame_step's frame (no host wait, no flags read: a frame the rules
    would refuse is not refused by the refining method) and accept it; its output is
    rs.out, its PQ colour rs.state. Returns its profiled events as ("rules", event) pairs
    (none without profile)."""
    rs.run(color, depth, motion, None, (float(jitter[0]), float(jitter[1])), reset,
           depth_inverted=depth_inverted, motion_scale=motion_scale, exposure=exposure,
           read_flags=False)
    rs.accept()
    if not profile:
        return []
    ev = [("rules", e) for _, e in rs.events]
    rs.events.clear()
    return ev


def rules_graph(render_size, scale, nits=None):
    """clss-rules' whole frame graph (its twin's), inputs color, depth, motion, jitter,
    reset, reactive, history and outputs output [1,3,H,W] (linear / exposure), history_out
    [1,16,H,W] (PQ colour in channels 0-2): a refining method's twin inlines it."""
    kw = {} if nits is None else {"nits": nits}
    model = twin("clss-rules", tuple(render_size), scale, **kw).model
    hist = [i for i in model.graph.input if i.name == "history"][0]
    assert hist.type.tensor_type.shape.dim[1].dim_value == RULES_HISTORY_CHANNELS
    return model
