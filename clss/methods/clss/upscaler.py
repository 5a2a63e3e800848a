"""CLSS temporal supersampling on an OpenCL device, frame by frame: the upscaler of the
methods "clss" (net mode), "clss-rules" (rule mode) and "jbicubic" (rule mode without
history: the jitter-aware upsampled colour alone).

    up = clss.Upscaler(method="clss", scale=2.0)       # or method="clss-rules"
    up = clss.Upscaler(scale=2.0, mode="net")          # the same, as before (mode="rules")
    for f in frames:
        out = up.step(f.color, f.depth, f.motion, f.jitter, reset=f.reset)   # H x W x 3

Inputs follow the frame contract (contract.py, docs/input-contract.md): colour
h x w x 3 linear, depth h x w (reversed-Z by default), motion h x w x 2 in render pixels
(prev = p + motion * motion_scale), jitter (jx, jy) in render pixels. The output is
H x W x 3 float32 linear (H = round(h * scale)).

Non-finite inputs: refused by default (FrameInputError naming the input, the count and
the first bad pixel), and a refused frame leaves the state exactly as it was, a pending
reset included; `sanitize=True` replaces them instead (colour 0, depth far, motion 0,
reactive 0) and `last_report` says how many. The render size is fixed by the first
frame; a frame of another size is accepted only with reset=True (a camera cut).

`step_device` is the same step on pyopencl arrays (float32, image layout), so that an
application that renders with OpenCL never copies through the host; every buffer, the
16-channel history and the depth reconstruction stay on the device between frames.
"""
from __future__ import annotations

import functools
import inspect
import math
import numbers
import os

import numpy as np

from .networks import CLASSIFIER_CHANNELS, base_of, pad16
from ...pipeline.contract import FrameInputError, output_size, validate_frame
from .contract import DEPTH_SLOPE, DEPTH_THRESHOLD, HISTORY_CHANNELS, VIS_MARGIN, ghost_classes
from ...pipeline.method import UNTRAINED, WEIGHTS_DIR, MethodSpec, MethodUpscaler, conventions
from .frame import KERNEL as FRAME_KERNEL, STAGES, FrameStep
from .frame_selfcheck import register_fast_paths

MODE_NAMES = {"rules": "rule", "rule": "rule", "net": "net"}
# The trained networks shipped in the package (`make train` writes them; recipe in
# weights_tools/methods/clss/recipe.py), the default of mode "net", for every scale.
SHIPPED_NAME = "clss_trained.safetensors"
SHIPPED_WEIGHTS = os.path.join(WEIGHTS_DIR, SHIPPED_NAME)


def load_networks(weights=None, allow_untrained=False, with_config=False):
    """(classifier, composition, trained) from `weights`, and with `with_config` also the
    config stored with them (networks.read_config: {"base": "rules"}; {} for files
    without one, the paper's form):

    None: the shipped trained weights (SHIPPED_WEIGHTS); if the package has none, the
      untrained init with allow_untrained, else an error (MethodSpec.resolve_weights);
    "untrained": the seeded clss.networks (untrained, trained = False);
    a directory: classifier.onnx and composition.onnx if present (else the default
      architectures), then weights.safetensors (or the only *.safetensors) applied;
    a .safetensors file: applied to the default architectures (every tensor must fit).
    """
    from .networks import build_classifier, build_composition, read_config
    from ...networks import apply_weights, load_weights
    # None: the one shipped file, which serves every scale
    weights = SPECS["clss"].resolve_weights(weights, 1.0, allow_untrained)
    if isinstance(weights, str) and weights == UNTRAINED:
        return (build_classifier(), build_composition(), False) + (({},) if with_config else ())
    path = os.fspath(weights)
    if os.path.isdir(path):
        def net(name, build):
            from ...model.graph import load_proto      # a corrupt file: an error naming it
            p = os.path.join(path, name)
            return load_proto(p) if os.path.isfile(p) else build()
        cls = net("classifier.onnx", build_classifier)
        comp = net("composition.onnx", build_composition)
        st = os.path.join(path, "weights.safetensors")
        if not os.path.isfile(st):
            found = sorted(f for f in os.listdir(path) if f.endswith(".safetensors"))
            st = os.path.join(path, found[0]) if len(found) == 1 else None
        if st is None and not os.path.isfile(os.path.join(path, "classifier.onnx")):
            raise ValueError(f"weights: {path} holds neither classifier.onnx nor a .safetensors "
                             "file (write one with `python -m weights_tools build --out DIR`)")
        cfg = {}
        if st is not None:
            t = load_weights(st)
            apply_weights(cls, t)
            apply_weights(comp, t)
            cfg = read_config(st)
        return (cls, comp, True) + ((cfg,) if with_config else ())
    if os.path.isfile(path) and path.endswith(".safetensors"):
        t = load_weights(path)
        cls, comp = build_classifier(), build_composition()
        n = len(apply_weights(cls, t)) + len(apply_weights(comp, t))
        if n == 0:
            raise ValueError(f"weights: {path} has no tensor named like the networks' "
                             "(cls.* / comp.*; see clss/networks/weights.py)")
        return (cls, comp, True) + ((read_config(path),) if with_config else ())
    raise ValueError(f"weights: expected a directory or a .safetensors file, got {path!r}"
                     + ("" if os.path.exists(path) else " (does not exist)"))


def _check_classifier_size(model, H16, W16):
    dims = model.graph.input[0].type.tensor_type.shape.dim
    got = [d.dim_value if d.HasField("dim_value") else None for d in dims]
    if len(got) == 4:
        if got[1] not in (None, CLASSIFIER_CHANNELS):
            raise ValueError(f"classifier: expected {CLASSIFIER_CHANNELS} input channels, got {got[1]}")
        for g, want, axis in zip(got[2:], (H16, W16), "HW"):
            if g is not None and g != want:
                raise ValueError(f"classifier: built for a fixed {axis} = {g}, this frame size "
                                 f"needs {want} (output padded to 16); build it with symbolic "
                                 "sizes (weights_tools build without --height/--width)")


class ClssUpscaler(MethodUpscaler):
    """CLSS temporal supersampling (see the module doc).

    scale: output / render size (>= 1; 1.5, 2, 3, 4 ...). mode: "net" (classifier +
    composition networks) or "rules" (depth test, neighbourhood clamp, 1/(1+n) blend).
    weights: None (the trained weights shipped in the package), "untrained" (the
    seeded init), a directory or a .safetensors file (see `load_networks`). device: a clss Device or a spec for clss.get_device. precision:
    "fp32" or "fp16" (half storage of the history and network tensors).
    Keyword-only: contract (clss.Contract, every parameter honoured: depth_inverted,
    motion_scale, hdr = PQ-encoded internal colour or LDR in [0, 1] in and out,
    exposure, nits; jitter_scale converted by the template), cap (the sample-counter
    cap, default 4 for rules and for net with the rules' base, 32 for net),
    depth_threshold (the depth test: the rule in rules, the floor under the classifier in
    net; > 1 turns it off), depth_slope (the test's
    tolerance per unit of local relative depth step, >= 0; contract.DEPTH_SLOPE, 0 = the
    plain test, reference.md s4), vis_margin (net: the
    classifier rejects the history where its visibility logit leads the larger of the
    other two by at least this, a finite number; contract.VIS_MARGIN, 0 = its argmax,
    reference.md s7), sanitize, classifier /
    composition (onnx.ModelProto, instead of weights), profile (per-stage times),
    debug (keep blend weight, ghost and depth difference for `debug_views`),
    classifier_backend (None: clss.Model, else onnxruntime with a warning;
    "clss" or "onnxruntime" to force one), allow_untrained (net: the seeded init where
    the package has no trained weights), base (net: the blend's base, networks.BASES;
    None: the config stored with the weights, "paper" for files without one; "rules":
    clss-rules' decision and cap, its weight 1/(1+n) corrected by the MLP, reference.md s9).

    The host step and step_device are MethodUpscaler's; the frame step reads a reactive
    mask and checks the values itself (its prepare kernel's flags, on both paths), so a
    frame is judged after it ran (`_run`).
    """

    STAGES = STAGES     # the per-stage timings (MethodUpscaler.stage_ms)
    REACTIVE = True
    VALUES_ON_DEVICE = True

    def __init__(self, scale=2.0, mode="net", weights=None, device=None, precision="auto", *,
                 contract=None, cap=None, depth_threshold=DEPTH_THRESHOLD,
                 depth_slope=DEPTH_SLOPE, vis_margin=VIS_MARGIN, sanitize=False,
                 classifier=None, composition=None, profile=False, debug=False,
                 classifier_backend=None, allow_untrained=False, base=None):
        if mode not in MODE_NAMES:
            raise ValueError(f"mode: expected 'net' or 'rules', got {mode!r}")
        self.mode = MODE_NAMES[mode]
        self.spec = SPECS["clss" if self.mode == "net" else "clss-rules"]
        if precision == "fp16-native":
            # frame.cl's arithmetic is float by design (PQ, coordinates); only storage halves.
            raise ValueError("precision: the frame kernels support 'fp32' and 'fp16' "
                             "(half storage, float arithmetic); 'fp16-native' is for clss.Model")
        self._init_common(scale, device, precision, contract=contract, sanitize=sanitize,
                          profile=profile)
        if cap is not None and not (isinstance(cap, (int, float)) and math.isfinite(cap) and cap >= 1):
            raise ValueError(f"cap: expected a number >= 1 (samples), got {cap!r}")
        self.cap = cap
        self.depth_threshold = float(depth_threshold)
        if (isinstance(depth_slope, bool) or not isinstance(depth_slope, numbers.Real)
                or not math.isfinite(depth_slope) or depth_slope < 0):
            raise ValueError(f"depth_slope: expected a finite number >= 0 (the depth test's "
                             f"tolerance per unit of depth step, 0 = the plain test), "
                             f"got {depth_slope!r}")
        self.depth_slope = float(depth_slope)
        if (isinstance(vis_margin, bool) or not isinstance(vis_margin, numbers.Real)
                or not math.isfinite(vis_margin)):
            raise ValueError(f"vis_margin: expected a finite number (the visibility logit's "
                             f"lead, 0 = argmax), got {vis_margin!r}")
        self.vis_margin = float(vis_margin)
        self.debug = bool(debug)
        self.classifier_backend = classifier_backend
        self.trained = None
        self.classifier_model = self.composition_model = None
        self.base = None
        if self.mode == "net":
            if (classifier is None) != (composition is None):
                raise ValueError("give both classifier and composition, or neither")
            cfg = {}
            if classifier is not None:
                if weights is not None:
                    raise ValueError("give weights or classifier/composition, not both")
                self.classifier_model, self.composition_model = classifier, composition
                self.trained = True
            else:
                self.classifier_model, self.composition_model, self.trained, cfg = \
                    load_networks(weights, allow_untrained, with_config=True)
            self.base = base_of({"base": base} if base is not None else cfg)
        elif base is not None:
            raise ValueError("base: only mode 'net' has networks to base")
        self._fs: FrameStep | None = None

    # -- sizes and state ----------------------------------------------------------
    @property
    def classifier_backend_name(self):
        if self.mode != "net":
            return None
        return None if self._fs is None else self._fs.classifier.backend

    @property
    def state(self) -> dict:
        """{"history": [1,16,H,W] float32} (a host copy), or {"history": None} before the
        first accepted frame (of this render size). Mode "net" adds "prev": [1,4,h,w]
        float32, the last accepted frame's encoded colour and own (not dilated) depth
        (reference.md s4b; None likewise), the oracle's state of the same name."""
        net = self.mode == "net"
        if self._fs is None or not self._fs.accepted:
            return {"history": None, "prev": None} if net else {"history": None}
        hist = self.dev.to_host(self._fs.state).astype(np.float32)
        st = {"history": hist.reshape((1, HISTORY_CHANNELS) + self.output_size)}
        if net:
            st["prev"] = self.dev.to_host(self._fs.prev_state)[None]
        return st

    def _build_frame_step(self, h, w):
        H, W = output_size(h, w, self.scale)
        if self.mode == "net":
            _check_classifier_size(self.classifier_model, pad16(H), pad16(W))
        fs = FrameStep(self.dev, self.precision, self.mode, (h, w), self.scale,
                       hdr=self.hdr, nits=self.nits, cap=self.cap,
                       depth_threshold=self.depth_threshold, depth_slope=self.depth_slope,
                       vis_margin=self.vis_margin, base=self.base or "paper",
                       sanitize=self.sanitize,
                       classifier=self.classifier_model, composition=self.composition_model,
                       classifier_backend=self.classifier_backend, profile=self.profile)
        fs.debug = self.debug
        return fs

    # -- one frame ------------------------------------------------------------------------
    def _run(self, fs, arrays, jitter, out, host=None):
        """Run the frame; the prepare kernel's flags decide on the values. `host`: the
        host arrays of step() (None on the device path, which copies them back only to
        explain a refusal)."""
        a = arrays
        ev = fs.run(a["color"], a["depth"], a["motion"], a.get("reactive"), jitter,
                    self._pending_reset, depth_inverted=self.depth_inverted,
                    motion_scale=self.motion_scale, exposure=self.exposure, out=out)
        ev.wait()
        refused, sanitized = fs.verdict()
        if refused:
            # The kernels already copied the history through; explain with the host check,
            # whose error names the input, the count and the first bad pixel.
            if host is None:
                host = {k: None if a.get(k) is None else a[k].get()
                        for k in ("color", "depth", "motion", "reactive")}
            validate_frame(host["color"], host["depth"], host["motion"], jitter,
                           host["reactive"], render_size=(fs.h, fs.w), sanitize=self.sanitize,
                           depth_inverted=self.depth_inverted)
            what = "; ".join(f"{n}: {w} values" for n, w in refused)
            raise FrameInputError(f"frame refused ({what}); the history is unchanged")
        fs.accept()
        self._frame_done(ev)
        self.last_report = sanitized
        return fs.out if out is None else out

    # -- timings and debug views ---------------------------------------------------------

    def debug_views(self) -> dict[str, np.ndarray]:
        """Host copies from the last frame (needs debug=True): "blend_weight",
        "ghost" (1 = history rejected), "depth_difference" (output res), "counter",
        and in mode net "ghost_class" (0 visibility, 1 shading, 2 none, as the decision
        at vis_margin makes them; "ghost" also has the depth floor) and
        "alias_class" (0 geometry, 1 texture, 2 none), H x W each."""
        if not self.debug:
            raise RuntimeError("debug_views needs Upscaler(..., debug=True)")
        if self._fs is None:
            return {}
        d = self._fs.dbg.get()
        hist = self.state["history"][0]
        views = {"blend_weight": d[0], "ghost": d[1], "depth_difference": d[2],
                 "counter": hist[3]}
        if self.mode == "net":
            # as the decision is made (the margin), from the stored logits
            views["ghost_class"] = ghost_classes(hist[10:13], self.vis_margin).astype(np.float32)
            views["alias_class"] = np.argmax(hist[13:16], 0).astype(np.float32)
        return views


class JitterBicubic(ClssUpscaler):
    """The jitter-aware bicubic baseline: CLSS's rule-mode frame step reset on every frame,
    so its output is the upsampled current colour alone (reference.md s5: each render
    sample placed where its jitter put it, a cubic over them, in the PQ domain). It is
    how a spatial upscaler that knows the jitter but keeps no history does."""

    def __init__(self, scale=2.0, device=None, precision="auto", **kwargs):
        super().__init__(scale, "rules", None, device, precision, **kwargs)
        self.spec = SPECS["jbicubic"]

    def step(self, color, depth, motion, jitter, reset=False, reactive=None, **gbuffers):
        return super().step(color, depth, motion, jitter, True, reactive)

    def step_device(self, color, depth, motion, jitter, reset=False, reactive=None, out=None,
                    **gbuffers):
        return super().step_device(color, depth, motion, jitter, True, reactive, out)


# JitterBicubic's keyword arguments are ClssUpscaler's less those of the networks (its
# **kwargs pass them on): the signature clss.Upscaler checks a caller's keywords against.
_sig = inspect.signature(ClssUpscaler)
JitterBicubic.__signature__ = _sig.replace(parameters=[
    p for p in _sig.parameters.values() if p.name not in (
        "mode", "weights", "classifier", "composition", "classifier_backend",
        "allow_untrained")])

# The frame step's fast-path checks run two frames through this class.
register_fast_paths(ClssUpscaler)


DOC = "docs/methods/clss.md"
# The whole-frame ONNX twin, named rather than imported: the frame step never loads its
# oracle (.importlinter), whoever asks for the twin does (clss.methods.twin).
TWIN = "clss.methods.clss.oracle:twin"
# Importing this module registers the frame step's fast paths (clss verify checks them).
FAST_PATHS = __name__
# The frame step's kernels, beside frame.py (MethodSpec.kernels).
KERNELS = (FRAME_KERNEL.name,)
# Every contract parameter is the frame step's (docs/input-contract.md section 6).
CONVENTIONS = conventions()
# The older clss.Upscaler(scale, mode="net" | "rules") picks between the two modes.
MODES = {"net": "clss", "rules": "clss-rules"}
# In the order `clss methods` lists them: the baseline first.
SPECS = {
    "jbicubic": MethodSpec(
        "jbicubic", "jitter-aware bicubic", "each render sample placed at its jittered "
        "position, a cubic over them; no history", JitterBicubic,
        temporal=False, doc="docs/methods/baselines.md", twin=TWIN, kernels=KERNELS, fast_paths=FAST_PATHS,
        conventions=CONVENTIONS),
    "clss-rules": MethodSpec(
        "clss-rules", "CLSS rules", "CLSS's frame step with rules instead of networks: depth "
        "test, variance clamp, 1/(1+n) blend (TAAU-like)",
        functools.partial(ClssUpscaler, mode="rules"), doc=DOC, twin=TWIN,
        kernels=KERNELS, fast_paths=FAST_PATHS, modes=MODES, conventions=CONVENTIONS),
    "clss": MethodSpec(
        "clss", "CLSS net", "CLSS (Guo et al. 2022): a classifier of ghosting and aliasing, "
        "auxiliary history, a per-pixel MLP blend weight",
        functools.partial(ClssUpscaler, mode="net"), doc=DOC, twin=TWIN,
        shipped=((None, SHIPPED_NAME),), kernels=KERNELS, fast_paths=FAST_PATHS, modes=MODES,
        conventions=CONVENTIONS),
}
