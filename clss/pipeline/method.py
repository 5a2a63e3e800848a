"""What a method says about itself, and what every method's upscaler shares.

A method (clss/methods/<room>/) describes itself with a `MethodSpec`: the inputs of the
frame contract it reads, the G-buffers it needs or uses, the scales and precisions it
supports, the weights it ships, what it adds to the shared code (fast-path self-checks,
command-line options, the older mode= alias), and how to build its upscaler.
`clss methods` prints the specs; `clss.Upscaler(method=NAME)` builds through them, and
refuses a keyword argument the method does not take (naming the closest one).

Every method's upscaler derives from `MethodUpscaler`, a template that holds what they
share and must not be copied into each room: the argument checks (scale, precision,
the caller's clss.Contract and what the method cannot honour of it), the host `step` (the pending reset of a camera cut, the frame
and G-buffer checks of the contract, the upload into the frame step's input buffers,
the run and the read-back), the device `step_device` (the same on pyopencl arrays),
the rule that a new render size needs a reset, and the one weights resolver (the
package's files, UNTRAINED, WEIGHTS_DIR). A room implements only what differs: building
its frame step for a render size and enqueuing one frame (see MethodUpscaler).
"""
from __future__ import annotations

import difflib
import functools
import inspect
import math
import os
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..errors import ArgumentError, UserError
from .precision import AUTO, resolve as resolve_precision
from .contract import (CANNOT, CONVERTS, GBUFFERS, HANDLINGS, HONOURS, NOT_READ, Contract,
                       ContractError, FrameInputError, MissingInputError, gbuffer_sources,
                       output_size, validate_frame)

# The frame contract's inputs (docs/input-contract.md) in the order `step` takes them.
CONTRACT_INPUTS = ("color", "depth", "motion", "jitter")
PRECISIONS = ("fp32", "fp16")

# The package's trained weights (clss/weights/, written by the training recipes), and the
# weights= value that asks for a method's seeded init.
WEIGHTS_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                           "weights")
UNTRAINED = "untrained"


# The keys of MethodSpec.parts(): what a method owns (docs/architecture.md, "Adding a method").
PARTS = ("room", "kernels", "weights", "onnx_twin", "torch_twin", "recipe", "bench", "doc",
         "tests")


@dataclass(frozen=True)
class MethodSpec:
    """One method, as `clss methods` lists it and `clss.Upscaler(method=...)` builds it.

    name: the registry name (`--method NAME`); label: how tables and pictures call it;
    summary: one line; create: the upscaler class, or a functools.partial of it that
    fixes what tells the methods of one room apart (CLSS's mode, the MLP's feature): its
    signature is the method's keyword arguments (`parameters`), and any other one is
    refused; inputs: the contract inputs it reads; gbuffers: the optional inputs it needs
    (refused without them); optional: those it uses when given; scales: (lowest, highest)
    scale; precisions: what `precision=` accepts; temporal: whether it carries a history
    between frames; doc: its page under docs/; twin: "module:name" of its whole-frame
    ONNX twin, a callable(method, render_size, scale, **kwargs) -> a runner with the same
    `step` on onnxruntime (clss.methods.twin builds it); kernels: the OpenCL sources of its
    frame step, file names in its room (beside frame.py; headers shared by every method
    are in kernels/). `parts()` lists everything the method owns, where it lives.

    Weights (`resolve_weights`): shipped: ((scale, file name under WEIGHTS_DIR), ...) of
    the trained weights the package ships, scale None for a file that serves every scale
    (empty: the method needs none); nearest_scale: a scale without a file of its own
    takes the nearest shipped one (ties: the larger), for networks that do not depend on
    the scale (NSRR); otherwise such a scale is refused unless the caller gives weights=
    or allow_untrained=True.

    What the method adds to the shared code, named here so that the shared code asks the
    spec instead of importing the room: fast_paths: a module whose import registers the
    method's fast paths with clss.selfcheck (clss.selfcheck_runner imports it, so `clss
    verify` and a child process check them); cli: a module with the method's own options
    of `clss upscale` (add_arguments(parser); check(args, method, usage_error) -> its
    keyword arguments for the upscaler, refusing its options for another method;
    step_kwargs(args, i, frame) -> what `step` takes besides the frame at position i;
    report(args, up, number); finish(args, up)); modes: {older mode= value: method name} for the methods the older
    `clss.Upscaler(scale, mode)` picks between (CLSS's "net" / "rules"), the same on each
    of them; positional arguments after the mode go to such a method in its signature's
    order.

    The caller's conventions (clss.Contract, taken by every method): conventions:
    {parameter: (handling, why)}, what the method does with each (contract.HANDLINGS:
    honours, converts, not read, cannot honour; `handling()` fills in what it leaves
    out), so that a value it cannot honour is refused by name (`check_contract`)."""
    name: str
    label: str
    summary: str
    create: Callable = field(repr=False)
    inputs: tuple = CONTRACT_INPUTS
    gbuffers: tuple = ()
    optional: tuple = ()
    scales: tuple = (1.0, 16.0)
    precisions: tuple = PRECISIONS
    temporal: bool = True
    doc: str = ""
    twin: str = ""
    kernels: tuple = ()
    shipped: tuple = ()
    nearest_scale: bool = False
    fast_paths: str = ""
    cli: str = ""
    modes: dict = field(default_factory=dict, repr=False, compare=False)
    conventions: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        for param, (what, _why) in self.conventions.items():
            if param not in Contract.names() or what not in HANDLINGS:
                raise ValueError(f"{self.name}: conventions: {param!r}: {what!r} is not a "
                                 f"contract parameter ({', '.join(Contract.names())}) with "
                                 f"one of {', '.join(HANDLINGS)}")

    def check_scale(self, scale) -> float:
        try:
            s = float(scale)
        except (TypeError, ValueError):
            raise ValueError(f"scale: expected a number >= 1, got {scale!r}") from None
        lo, hi = self.scales
        if not math.isfinite(s) or s < lo or s > hi:
            raise ValueError(f"scale: expected a number in [{lo:g}, {hi:g}] (method "
                             f"{self.name!r}), got {scale!r}")
        return s

    def check_precision(self, precision) -> str:
        """precision itself, or "auto" (pipeline/precision.py resolves it on the device)."""
        if precision not in self.precisions and precision != AUTO:
            raise ValueError(f"precision: expected {' or '.join(repr(p) for p in (AUTO,) + self.precisions)} "
                             f"(method {self.name!r}), got {precision!r}")
        return precision

    # -- the caller's conventions ----------------------------------------------------
    def reads(self, name: str) -> bool:
        """Whether the method reads frame input `name` (its own or a G-buffer)."""
        return name in self.inputs or name in self.gbuffers or name in self.optional

    def handling(self, param: str) -> tuple:
        """(handling, why): what the method does with contract parameter `param`: not
        read when it reads no input the parameter describes (whatever `conventions`
        says, so that methods of one room share one table); else as `conventions` says;
        else, for the jitter's units, converted (the template scales the jitter before
        the frame step); else only the default is taken."""
        described = Contract.DESCRIBES[param]
        if not any(self.reads(n) for n in described):
            return NOT_READ, f"reads no {' or '.join(described)}"
        if param in self.conventions:
            return tuple(self.conventions[param])
        if param == "jitter_scale":
            return CONVERTS, "the jitter is scaled before the frame step"
        return CANNOT, "the method does not say what it would do with it"

    def check_contract(self, contract: Contract, others=()) -> None:
        """A ContractError for the first parameter of `contract` that differs from the
        default and that the method cannot honour, naming the method, the parameter, why,
        and `others` (the methods that can)."""
        for param, value in contract.changed().items():
            what, why = self.handling(param)
            if what != CANNOT:
                continue
            flag = Contract.FLAGS[param]
            alt = f"; methods that can: {', '.join(others)}" if others else ""
            raise ContractError(
                f"method {self.name!r} cannot honour {param}={value!r}: {why}{alt}",
                cli=f"{flag}: the method {self.name} cannot honour it ({why}); drop {flag}"
                    + (f" or use one of {', '.join(others)}" if others else ""))

    # -- what the method owns -----------------------------------------------------------
    @property
    def room(self) -> str:
        """The room (the package under clss.methods) whose SPECS define the method."""
        fn = self.create.func if isinstance(self.create, functools.partial) else self.create
        parts = fn.__module__.split(".")
        return parts[2] if parts[:2] == ["clss", "methods"] and len(parts) > 2 else ""

    def parts(self) -> dict:
        """Everything the method owns and where it lives, as paths from the repository's
        root (PARTS names the keys; docs/architecture.md walks a newcomer through them and
        tests/test_house.py holds the two to each other and to the files): its room, its
        frame kernels, the weights files the package ships for it, its whole-frame ONNX twin, its torch twin and
        training recipe (weights_tools/methods/<room>/, for a method that ships trained
        weights), its bench cases (bench/methods/<room>.py), its page and its tests. None
        where the method has no such part."""
        room = self.room
        trained = bool(self.shipped)
        return {
            "room": f"clss/methods/{room}/",
            "kernels": tuple(f"clss/methods/{room}/{k}" for k in self.kernels),
            "weights": tuple(f"clss/weights/{f}" for _, f in self.shipped
                             if os.path.isfile(os.path.join(WEIGHTS_DIR, f))),
            "onnx_twin": self.twin or None,
            "torch_twin": f"weights_tools/methods/{room}/twin.py" if trained else None,
            "recipe": f"weights_tools/methods/{room}/recipe.py" if trained else None,
            "bench": f"bench/methods/{room}.py",
            "doc": self.doc or None,
            "tests": f"tests/test_method_{room}.py",
        }

    # -- keyword arguments ------------------------------------------------------------
    def _signature(self):
        fn, fixed = self.create, {}
        if isinstance(fn, functools.partial):
            fn, fixed = fn.func, dict(fn.keywords)
        return inspect.signature(fn), fixed

    def parameters(self) -> tuple | None:
        """The keyword arguments the method's upscaler takes, in its signature's order
        (those `create` fixes left out); None when it takes any (a **kwargs test double)."""
        sig, fixed = self._signature()
        names = []
        for p in sig.parameters.values():
            if p.kind is p.VAR_KEYWORD:
                return None
            if p.kind is not p.VAR_POSITIONAL and p.name not in fixed:
                names.append(p.name)
        return tuple(names)

    def positional(self) -> tuple:
        """The parameters that may be given by position, in order (scale first)."""
        sig, fixed = self._signature()
        return tuple(p.name for p in sig.parameters.values()
                     if p.kind is p.POSITIONAL_OR_KEYWORD and p.name not in fixed)

    def check_arguments(self, kwargs) -> None:
        """An ArgumentError (a TypeError) for the first keyword argument the method does
        not take, naming the closest one it does. Every method takes the contract, as
        `contract=` or its parameters (Contract.names())."""
        names = self.parameters()
        if names is None:
            return
        names = tuple(dict.fromkeys(names + ("contract",) + Contract.names()))
        for key in kwargs:
            if key in names:
                continue
            close = difflib.get_close_matches(key, names, n=1)
            hint = (f"did you mean {close[0]!r}?" if close else
                    f"it takes {', '.join(names)}")
            raise ArgumentError(f"clss.Upscaler(method={self.name!r}): unexpected keyword "
                                f"argument {key!r}; {hint}")

    def options(self, kwargs: dict) -> dict:
        """Those of `kwargs` the method takes: for a caller that feeds several methods
        the same options (eval, the command line, the demo); None values left out. The
        contract is kept for every method (it refuses what it cannot honour)."""
        names = self.parameters()
        every = ("contract",) + Contract.names()      # every method takes these
        return {k: v for k, v in kwargs.items()
                if v is not None and (names is None or k in names or k in every)}

    # -- weights ----------------------------------------------------------------------
    def weights(self) -> str:
        """"trained", "untrained" or "none needed": the state of the package's weights."""
        if not self.shipped:
            return "none needed"
        return "trained" if any(os.path.isfile(os.path.join(WEIGHTS_DIR, f))
                                for _, f in self.shipped) else "untrained"

    def trained_scales(self) -> list:
        """The scales whose shipped weights file is in the package."""
        return [s for s, f in self.shipped
                if s is not None and os.path.isfile(os.path.join(WEIGHTS_DIR, f))]

    def shipped_file(self, scale) -> str | None:
        """The package's weights file that serves `scale`, if it is there."""
        if not self.shipped:
            return None
        files = dict(self.shipped)
        if None in files:
            key = None
        elif self.nearest_scale:
            key = min(files, key=lambda s: (abs(float(scale) - s), -s))
        else:
            key = next((s for s in files if float(s) == float(scale)), False)
            if key is False:
                return None
        path = os.path.join(WEIGHTS_DIR, files[key])
        return path if os.path.isfile(path) else None

    def resolve_weights(self, weights, scale, allow_untrained=False):
        """weights= as given (and None for a method that needs none); for None the
        package's file for `scale`; without one UNTRAINED (the seeded init) if the caller
        allows it, else a UserError naming the scales that have weights."""
        if weights is not None or not self.shipped:
            return weights
        path = self.shipped_file(scale)
        if path is not None:
            return path
        if allow_untrained:
            return UNTRAINED
        have = self.trained_scales()
        where = (f"the package has weights for scale{'s' if len(have) > 1 else ''} "
                 f"{' and '.join(f'{s:g}' for s in have)}" if have else
                 "the package has no trained weights for it")
        s = float(scale)
        raise UserError(
            f"{self.name}: no trained weights for scale {s:g} ({where}); pass weights= (a "
            f"weights file, or {UNTRAINED!r} for the seeded init) or allow_untrained=True",
            cli=f"--method {self.name} --scale {s:g}: no trained weights for this scale "
                f"({where}); give --weights FILE, or --weights {UNTRAINED} for the seeded init")

    def load_network(self, nets, weights, scale, make_config, allow_untrained=False,
                     what: str = "a .safetensors file") -> tuple[dict, dict, bool]:
        """(config, weights, trained) of a method's network, from weights= as the upscalers
        take it: None (the package's file, resolve_weights), UNTRAINED (the seeded init of
        make_config()), a .safetensors path (`what` names it in the error) or a
        (config, weights dict) pair. `nets` is the room's networks module (init_weights,
        check_weights, load)."""
        weights = self.resolve_weights(weights, scale, allow_untrained)
        if isinstance(weights, str) and weights == UNTRAINED:
            cfg = make_config()
            return cfg, nets.init_weights(cfg), False
        if isinstance(weights, tuple):
            cfg, w = weights
            nets.check_weights(cfg, w)
            return cfg, w, True
        cfg, w = nets.load(weights_file(weights, what))
        return cfg, w, True


def conventions(**overrides) -> dict:
    """MethodSpec.conventions of a method whose frame step takes the depth convention,
    the motion scale, the exposure, the nits and LDR colour itself (the jitter's units
    the template converts); `overrides` {parameter: (handling, why)} replace entries."""
    out = {"depth_inverted": (HONOURS, "its frame step reads either convention"),
           "motion_scale": (HONOURS, "its frame step scales the motion"),
           "hdr": (HONOURS, "LDR: a clamp to [0, 1] instead of the PQ transfer"),
           "exposure": (HONOURS, "divides on the way in, multiplies on the way out"),
           "nits": (HONOURS, "the PQ transfer's scale")}
    out.update(overrides)
    return out


def weights_file(weights, what: str) -> str:
    """weights= given as a path: it must be an existing .safetensors file (`what`, e.g.
    "an NSRR .safetensors file", names what was expected)."""
    path = os.fspath(weights)
    if not (os.path.isfile(path) and path.endswith(".safetensors")):
        raise ValueError(f"weights: expected {what}, got {path!r}"
                         + ("" if os.path.exists(path) else " (does not exist)"))
    return path


# The channels of the frame's own inputs in image layout (h x w x c; one channel: h x w).
FRAME_CHANNELS = {"color": 3, "depth": 1, "motion": 2, "reactive": 1}


def input_shape(name, render_size, output_size=None) -> tuple:
    """The contract's image-layout shape of input `name` (the frame's own or a G-buffer)
    for a frame of these sizes."""
    if name in FRAME_CHANNELS:
        c = FRAME_CHANNELS[name]
        return tuple(int(v) for v in render_size) + ((c,) if c > 1 else ())
    return GBUFFERS[name].shape(render_size, output_size)


def input_buffers(dev, names, render_size, output_size=None) -> list:
    """Float32 device buffers in the contract's image layout for the named inputs (the
    frame's own and the G-buffers), in order: a frame step's `in_<name>` buffers, which
    MethodUpscaler's host step uploads into."""
    return [dev.empty(input_shape(n, render_size, output_size), dtype=np.float32)
            for n in names]


def summed_event_ms(events, stages) -> dict:
    """{stage: milliseconds} of [(stage, pyopencl.Event)] (profiled events), in the order
    of `stages`; waits for each event and empties the list."""
    tot = {}
    for name, e in events:
        e.wait()
        tot[name] = tot.get(name, 0.0) + (e.profile.end - e.profile.start) * 1e-6
    events.clear()
    return {s: tot[s] for s in stages if s in tot}


class MethodUpscaler:
    """The part of every method's upscaler that is the same for all (see the module doc):
    a template whose `step` and `step_device` run any room's frame step.

    A room sets `spec` and calls `_init_common` (passing its `contract=` on) in its
    constructor, reads the conventions as self.depth_inverted, motion_scale, hdr,
    exposure and nits (the template converts the jitter and depth_hr), and implements:

    _build_frame_step(h, w): its frame step for render size h x w: an object with h, w,
      H, W, an `in_<name>` device buffer for each input the host step uploads (see
      `inputs`; float32, or the precision's storage type), and, where the method times
      its stages, stage_ms() (with STAGES) and device_bytes();
    _enqueue(fs, arrays, jitter, out): enqueue one frame on `fs` from `arrays` ({input
      name: device array}, the `in_` buffers on the host path, the caller's arrays on the
      device path), the checked jitter and `out` (None: the frame step's own output);
      returns (output array, the frame's last event). The pending reset is
      `self._pending_reset`.

    and where it differs from the default: REACTIVE (its frame step reads the reactive
    mask), VALUES_ON_DEVICE (its frame step checks the values itself: `_run` then judges
    the frame after it ran, as CLSS's prepare kernel does), `_run` (enqueue and complete
    one frame), `_host_frame_hook` (a method that learns from the host frame: the MLP's
    online training), `render_size` / `output_size` (None before the first frame) and
    `stage_ms` / `reset_timings`.

    Inputs are float32 in image layout on both paths (the contract's); step_device also
    takes float16 and converts it on the device. Either path returns H x W x 3 float32."""
    spec: MethodSpec
    REACTIVE = False
    VALUES_ON_DEVICE = False

    def _init_common(self, scale, device, precision, *, contract=None, sanitize=False,
                     profile=False):
        from ..device import get_device
        self.scale = self.spec.check_scale(scale)
        # the caller's conventions, refused here too for a room's class built directly
        self.contract = Contract.of(contract)
        self.spec.check_contract(self.contract)
        self.dev = get_device(device)
        # "auto": fp32 on a CPU, fp16 storage on a GPU where the method's fp16 step verifies
        self.precision = resolve_precision(self.spec, self.dev, self.spec.check_precision(precision))
        self.sanitize = bool(sanitize)
        self.profile = bool(profile)
        self._pending_reset = True
        self.frame_index = 0
        self.last_report: dict = {}
        self._fs = None             # the frame step of the current render size
        self._totals: dict[str, float] = {}     # per-stage ms summed over flushed frame steps
        self._timed = 0             # frames those sums cover (_frame_done counts them)

    @property
    def method(self) -> str:
        return self.spec.name

    # The contract's parameters, as the frame steps read them (self.contract holds them).
    depth_inverted = property(lambda self: self.contract.depth_inverted)
    motion_scale = property(lambda self: self.contract.motion_scale)
    jitter_scale = property(lambda self: self.contract.jitter_scale)
    hdr = property(lambda self: self.contract.hdr)
    exposure = property(lambda self: self.contract.exposure)
    nits = property(lambda self: self.contract.nits)

    def _jitter(self, jitter):
        """The caller's jitter in render pixels (Contract.jitter); (0, 0) for a method
        that reads none, whatever it was given."""
        if "jitter" not in self.spec.inputs:
            return np.zeros(2, np.float32)
        return self.contract.jitter(jitter)

    def _reversed_z(self, depth_hr):
        """depth_hr (numpy or pyopencl) in reversed-Z, as every frame step reads it: the
        contract's depth convention applies to it as to depth (1 - d for standard Z)."""
        return depth_hr if self.depth_inverted else 1.0 - depth_hr

    # The frame step (`_fs`, with h, w, H, W) has the sizes; None before the first frame.
    @property
    def render_size(self):
        fs = getattr(self, "_fs", None)
        return None if fs is None else (fs.h, fs.w)

    @property
    def output_size(self):
        fs = getattr(self, "_fs", None)
        return None if fs is None else (fs.H, fs.W)

    def device_bytes(self) -> int:
        """Bytes of the device buffers the frame step holds."""
        fs = getattr(self, "_fs", None)
        return 0 if fs is None or not hasattr(fs, "device_bytes") else fs.device_bytes()

    def reset(self):
        """The next frame starts afresh (a camera cut)."""
        self._pending_reset = True

    @property
    def inputs(self) -> tuple:
        """The inputs the frame step reads, in the order `step` takes them: the spec's
        contract inputs (the jitter aside, it is an argument), "reactive" where
        REACTIVE, then the G-buffers it needs or uses."""
        spec = self.spec
        return (tuple(n for n in spec.inputs if n != "jitter")
                + (("reactive",) if self.REACTIVE else ()) + tuple(spec.gbuffers)
                + tuple(spec.optional))

    # -- the host path ----------------------------------------------------------------
    def step(self, color, depth=None, motion=None, jitter=(0.0, 0.0), reset=False,
             reactive=None, **gbuffers) -> np.ndarray:
        """One frame from host arrays (docs/input-contract.md); returns the H x W x 3
        float32 linear output. G-buffers are keyword arguments; those the method does not
        use are ignored (one caller may feed every method the same frame), as are the
        contract inputs it does not read."""
        if reset:
            self._pending_reset = True          # kept if this frame is refused
        frame = self._host_frame(color, depth, motion, self._jitter(jitter), reactive, reset)
        hw = frame["color"].shape[:2]
        gb = self._gbuffers(gbuffers, hw, output_size(*hw, self.scale))
        self._host_frame_hook(frame, gb, gbuffers)
        fs = self._frame_step(hw, reset)
        arrays = {}
        for name in self.inputs:
            value = gb.get(name) if name in GBUFFERS else frame.get(name)
            if value is None:
                continue
            buf = getattr(fs, "in_" + name)
            buf.set(np.ascontiguousarray(value, buf.dtype))
            arrays[name] = buf
        return self.dev.to_host(self._run(fs, arrays, frame["jitter"], None, host=frame))

    def _host_frame(self, color, depth, motion, jitter, reactive, reset) -> dict:
        """validate_frame's dict for the host step: the layout always, the values unless
        the frame step checks them (VALUES_ON_DEVICE); the render size held to the
        sequence's. A method that reads the colour alone gets placeholders for the rest."""
        reset = reset or self._pending_reset
        if "depth" not in self.spec.inputs:
            return self._color_frame(color, jitter, reset)
        if isinstance(color, np.ndarray) and color.ndim == 3:
            # before validate_frame, whose shape error would not say that a reset is missing
            self._check_render_size(color.shape[:2], reset)
        return validate_frame(color, depth, motion, jitter,
                              reactive if self.REACTIVE else None,
                              render_size=None if reset or self._fs is None else self.render_size,
                              sanitize=self.sanitize, depth_inverted=self.depth_inverted,
                              values=not self.VALUES_ON_DEVICE)

    def _color_frame(self, color, jitter, reset):
        """For a method that reads the colour (and perhaps the jitter) alone:
        validate_frame's dict, the colour and jitter checked as the contract says and the
        render size held to the sequence's."""
        color = np.asarray(color)
        if color.ndim == 3:
            self._check_render_size(color.shape[:2], reset)
        h, w = color.shape[:2] if color.ndim >= 2 else (0, 0)
        # placeholders for the inputs such a method does not read
        return validate_frame(color, np.zeros((h, w), np.float32),
                              np.zeros((h, w, 2), np.float32), jitter,
                              sanitize=self.sanitize)

    def _host_frame_hook(self, frame, gbuffers, extra):
        """Called by the host step once the frame and its G-buffers (`gbuffers`) passed
        the checks, before the upload; `extra` holds every keyword argument of the step
        (a method may take more than G-buffers there: the MLP's `reference`)."""

    def _gbuffers(self, given: dict, render_size, output_size) -> dict:
        """The G-buffers this method needs or uses, checked against the contract; a
        missing needed one is a named error (nothing has run yet). Buffers the method
        does not use are ignored, so one caller can feed every method the same frame."""
        spec = self.spec
        if not spec.gbuffers and not spec.optional:
            return {}
        from . import contract
        out = contract.validate_gbuffers(spec.name, spec.gbuffers, spec.optional,
                                         {k: v for k, v in given.items() if v is not None},
                                         render_size, output_size, sanitize=self.sanitize)
        if "depth_hr" in out:
            out["depth_hr"] = self._reversed_z(out["depth_hr"])
        return out

    # -- the device path --------------------------------------------------------------
    def step_device(self, color, depth=None, motion=None, jitter=(0.0, 0.0), reset=False,
                    reactive=None, out=None, **gbuffers):
        """One frame from pyopencl arrays in image layout (float32; float16 is converted,
        which allocates), the G-buffers as keywords; returns the H x W x 3 float32 output
        on the device: `out` if given, else a buffer of the frame step that the next step
        overwrites. No host copies; the values are checked on the device by a method whose
        frame step does (VALUES_ON_DEVICE), else not here."""
        given = dict(gbuffers, color=color, depth=depth, motion=motion, reactive=reactive)
        names = [n for n in self.inputs if n != "reactive" or reactive is not None]
        missing = [n for n in self.spec.gbuffers if given.get(n) is None]
        if missing:
            if reset:
                self._pending_reset = True
            raise MissingInputError(
                f"method {self.spec.name!r} needs {', '.join(missing)}, which the frame "
                "does not carry; pass " + "; ".join(gbuffer_sources(n) for n in missing))
        hw = self._device_frame(reset, out=out, **{n: given[n] for n in names})
        fs = self._frame_step(hw, reset)
        arrays = {n: self._device_input(n, given[n], input_shape(n, hw, (fs.H, fs.W)))
                  for n in names}
        if "depth_hr" in arrays:
            arrays["depth_hr"] = self._reversed_z(arrays["depth_hr"])
        if out is not None and (out.shape != (fs.H, fs.W, 3) or out.dtype != np.float32):
            raise FrameInputError(f"out: expected a float32 array of shape {(fs.H, fs.W, 3)}, "
                                  f"got {out.dtype} {out.shape}")
        return self._run(fs, arrays, self._jitter(jitter), out)

    def _device_frame(self, reset, **arrays):
        """step_device's common entry: a reset is remembered (kept if the frame is then
        refused), every given array must be a pyopencl array, the colour h x w x 3;
        returns (h, w)."""
        import pyopencl.array as cla
        if reset:
            self._pending_reset = True
        for name, a in arrays.items():
            if (a is not None or name != "out") and not isinstance(a, cla.Array):
                raise FrameInputError(f"{name}: expected a pyopencl.array.Array, got "
                                      f"{type(a).__name__} (use step() for numpy arrays)")
        color = arrays["color"]
        if color.ndim != 3 or color.shape[2] != 3:
            raise FrameInputError(f"color: expected shape (h, w, 3), got {color.shape}")
        return tuple(color.shape[:2])

    def _device_input(self, name, a, shape):
        """A device input checked for shape (a plane may be h x w x 1), dtype (float32;
        float16 converted on the device) and layout (contiguous, at offset 0)."""
        shape = tuple(int(v) for v in shape)
        if a.shape != shape and not (len(shape) == 2 and a.shape == shape + (1,)):
            raise FrameInputError(f"{name}: expected shape {shape}, got {a.shape}")
        if a.dtype not in (np.float32, np.float16):
            raise FrameInputError(f"{name}: expected dtype float32 or float16, got {a.dtype}")
        if not a.flags.c_contiguous or a.offset:
            raise FrameInputError(f"{name}: expected a contiguous array at offset 0")
        return convert_storage(a, np.float32) if a.dtype == np.float16 else a

    # -- one frame --------------------------------------------------------------------
    def _frame_step(self, hw, reset):
        """The frame step for render size hw, built anew (buffers, programs) when it changes."""
        return self._frame_step_for(hw, reset, self._build_frame_step)

    def _build_frame_step(self, h, w):
        raise NotImplementedError(f"{type(self).__name__} builds no frame step")

    def _enqueue(self, fs, arrays, jitter, out):
        raise NotImplementedError(f"{type(self).__name__} enqueues no frame")

    def _run(self, fs, arrays, jitter, out, host=None):
        """Enqueue one frame and complete it; returns the output array (float32). `host`:
        the host step's validated frame (None on the device path)."""
        res, ev = self._enqueue(fs, arrays, jitter, out)
        self._frame_done(ev)
        self.last_report = {} if host is None else host["sanitized"]
        return res

    def _check_render_size(self, hw, reset):
        """A render size other than the sequence's needs a reset (a camera cut)."""
        have = self.render_size
        if have is not None and not reset and tuple(have) != tuple(int(v) for v in hw):
            raise FrameInputError(
                f"color: the frame is {hw[0]}x{hw[1]} (h x w) but this sequence renders at "
                f"{have[0]}x{have[1]}; a new render size needs reset=True (a camera cut)")

    def _frame_step_for(self, hw, reset, build):
        """The device frame step (`self._fs`, with .h and .w) for render size hw: the
        current one, or `build(h, w)` after `_release_frame_step()` (a new size is a new
        sequence: buffers and programs built anew, and the next frame a reset)."""
        self._check_render_size(hw, reset or self._pending_reset)
        fs = getattr(self, "_fs", None)
        if fs is not None and (fs.h, fs.w) == tuple(hw):
            return fs
        h, w = int(hw[0]), int(hw[1])
        if h < 1 or w < 1:
            raise FrameInputError(f"color: expected a non-empty h x w x 3 frame, got {h}x{w}")
        if fs is not None:
            self._release_frame_step()
        self._fs = None         # release the old buffers first
        self._fs = build(h, w)
        self._pending_reset = True
        return self._fs

    def _release_frame_step(self):
        """Called before the frame step of another render size replaces the current one:
        its per-stage timings are kept."""
        self._flush_timings()

    def _frame_done(self, event):
        """After a frame step enqueued a whole frame: wait for its last event, then count
        the frame (the pending reset is spent; a timed frame for stage_ms)."""
        event.wait()
        self._pending_reset = False
        self.frame_index += 1
        if self.profile:
            self._timed += 1

    # -- timings ----------------------------------------------------------------------
    # The stages a method's frame step times with OpenCL events (its `stage_ms()` gives the
    # milliseconds summed since its last call); a method without stage events names none
    # and reports none.
    STAGES: tuple = ()

    def _flush_timings(self):
        if self._fs is not None and self.profile and self.STAGES:
            for k, v in self._fs.stage_ms().items():
                self._totals[k] = self._totals.get(k, 0.0) + v

    def reset_timings(self):
        """Start the per-stage statistics afresh (e.g. after a first frame that paid for
        kernel compilation)."""
        self._flush_timings()
        self._totals, self._timed = {}, 0

    def stage_ms(self) -> dict:
        """Mean milliseconds per frame of each stage since construction or the last
        reset_timings (needs profile=True): OpenCL event times."""
        if not self.profile:
            raise RuntimeError("stage_ms needs Upscaler(..., profile=True)")
        self._flush_timings()
        n = max(self._timed, 1)
        return {k: self._totals[k] / n for k in self.STAGES if k in self._totals}


# ---- float16 <-> float32 on the device ------------------------------------------------------
# OpenCL 1.2 reads and writes half storage with vload_half / vstore_half (no cl_khr_fp16
# needed; PoCL has none), so the buffers are passed as ushort. Round to nearest even, as
# numpy's astype(float16).
_CONVERT = {}


def convert_storage(a, dtype, out=None):
    """`a` (a float32 or float16 device array) as `dtype` (float32 or float16): into `out`
    (same shape) if given, else a new array; `a` itself when it has that dtype already."""
    import pyopencl.array as cla
    from pyopencl.elementwise import ElementwiseKernel
    dtype = np.dtype(dtype)
    if a.dtype == dtype and out is None:
        return a
    key = (a.context.int_ptr, a.dtype.char, dtype.char)
    k = _CONVERT.get(key)
    if k is None:
        src = "float" if a.dtype == np.float32 else "ushort"
        dst = "float" if dtype == np.float32 else "ushort"
        load = "x[i]" if src == "float" else "vload_half(i, (__global const half *)x)"
        op = (f"z[i] = {load}" if dst == "float" else
              f"vstore_half_rte({load}, i, (__global half *)z)")
        k = ElementwiseKernel(a.context, f"__global {dst} *z, __global const {src} *x", op,
                              f"clss_{src}_to_{dst}")
        _CONVERT[key] = k
    z = cla.empty(a.queue, a.shape, dtype) if out is None else out
    if z.dtype != dtype or z.shape != a.shape:
        raise ValueError(f"convert_storage: out is {z.dtype} {z.shape}, expected {dtype} {a.shape}")
    from ..device import first_build_lock
    with first_build_lock(f"convert-{key[1]}{key[2]}", a.context):     # built at its first call
        k(z.view(np.uint16) if dtype == np.float16 else z,
          a if a.dtype == np.float32 else a.view(np.uint16))
    return z
