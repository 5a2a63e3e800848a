"""The CLSS frame step on an OpenCL device: buffers, launches and timings.

`FrameStep` owns every device buffer of one render size and runs the fused kernels of
frame.cl (formulas: reference.md) plus, in mode "net", the classification
network through `clss.Model`. It works on device arrays only; clss.pipeline.Upscaler
puts the caller-facing contract around it.

Per frame (render res h x w, output res H x W, H16 x W16 the size padded to 16):

    clear         recon, flags <- 0
    prepare       color, depth, motion, reactive -> X (encoded colour), lr stack, recon
    depth_diff    recon -> lr[dd]; X -> lr[colour box]; net: X, lr, prev -> lr[measurements],
                  prev' (reference.md s4b)
    resolve       rule: X, lr, history -> history', output
                  net:  X, lr, history -> classifier input (H16 x W16; the measurements
                  at the render pixel holding each output pixel's centre), aux
    classifier    net: classifier input -> logits at H16/2 x W16/2   (clss.Model)
    compose       net: logits, classifier input, aux, history -> history', output

The history, and in net mode the render-res state `prev` (the previous accepted frame's
encoded colour and own, not dilated, depth, s4b), are double-buffered and swapped after a frame is
accepted; the depth reconstruction is per-frame scratch (reference.md s3).
"""
from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import onnx
import pyopencl as cl
import pyopencl.array as cla
from onnx import numpy_helper

from ... import selfcheck
from ...device import Device
from .networks import BASES, CLASSIFIER_CHANNELS, COMPOSITION_CHANNELS, pad16
from ...ops.conv import load_defines
from ...pipeline.method import input_buffers, summed_event_ms
from ...pipeline.contract import PQ_NITS, PQ_PEAK_NITS, output_size
from .contract import (AUTO_REACTIVE_LO, AUTO_REACTIVE_MAX, AUTO_REACTIVE_SLOPE, CLIP_GAMMA,
                       DEFAULT_CAP, DEPTH_SLOPE, DEPTH_THRESHOLD, HISTORY_CHANNELS, MEASURE_KNEES,
                       RULE_CLIP_EPS, VIS_MARGIN)

KERNEL = Path(__file__).with_name("frame.cl")   # the frame kernels, beside this file
# depth, motion 2, dd, reactive, the depth test's difference, clamp box low 3 and high 3
LR_CHANNELS = 12
# net mode: and the classifier's 4 measurements (reference.md s4b), then the pixel's own
# (not dilated) depth and motion 2 that prepare writes for them
LR_NET_CHANNELS = 19
LR_MEASURE = 12     # the first measurement plane (frame.cl's L_MEASURE)
PREV_CHANNELS = 4  # net mode's render-res state: encoded colour 3, own (not dilated) depth
# The buffer widths frame.cl is built with (it has no defaults for them); net
# mode builds with L_CHANNELS = LR_NET_CHANNELS.
WIDTH_DEFINES = dict(L_CHANNELS=LR_CHANNELS, HIST=HISTORY_CHANNELS,
                     CLS_IN=CLASSIFIER_CHANNELS, COMP_IN=COMPOSITION_CHANNELS)
# flags[0] bits, as frame.cl
FLAG_BITS = {1: ("color", "non-finite"), 2: ("depth", "non-finite"), 4: ("motion", "non-finite"),
             8: ("reactive", "non-finite"), 16: ("depth", "outside [0, 1]"),
             32: ("reactive", "outside [0, 1]")}
NONFINITE_BITS = 15
STAGES = ("prepare", "depth_diff", "resolve", "classifier", "compose")


def pixels_per_item(dev: Device, prec: str = "fp32", mode: str = "rule") -> int:
    """VEC of frame.cl: CPUs get 8 pixels per work-item as explicit vectors (what
    their OpenCL compilers vectorise) once the fast-path self-check has compared that
    with VEC = 1 on the device (clss/selfcheck.py), other devices one (a work-item is
    already a lane). $CLSS_FRAME_VEC (1, 4 or 8) overrides it, unchecked."""
    env = os.environ.get("CLSS_FRAME_VEC", "").strip()
    if env:
        if env not in ("1", "4", "8"):
            raise ValueError(f"CLSS_FRAME_VEC: expected 1, 4 or 8, got {env!r}")
        return int(env)
    if not dev.is_cpu:
        return 1
    return selfcheck.defines(dev, prec, f"frame.pixel_vectors.{mode}")["VEC"]


def inline_math(dev: Device, prec: str = "fp32", mode: str = "rule") -> int:
    """CLSS_INLINE_MATH of frame.cl: the builtins as clang's elementwise builtins and plain
    operators, and the PQ transfer on pq.h's powq8, on PoCL (whose compiler is clang and whose
    builtins are calls) once the fast path frame.inline_math.<mode> checked itself.
    $CLSS_FRAME_INLINE_MATH (0 or 1) overrides it, unchecked."""
    from ...ops.conv import builtin_free
    env = os.environ.get("CLSS_FRAME_INLINE_MATH", "").strip()
    if env:         # 0 or 1, unchecked (the oclgrind test runs the fast path with it)
        if env not in ("0", "1"):
            raise ValueError(f"CLSS_FRAME_INLINE_MATH: expected 0 or 1, got {env!r}")
        return int(env)
    if not builtin_free(dev):
        return 0
    return selfcheck.defines(dev, prec, f"frame.inline_math.{mode}")["CLSS_INLINE_MATH"]


def composition_weights(model: onnx.ModelProto):
    """(w1 [hidden, 22], b1 [hidden], w2 [hidden], b2 [1]) float32 of a composition
    network Conv1x1 -> Relu -> Conv1x1 -> Sigmoid (weights_tools.build_composition),
    which `compose` evaluates per pixel inside the blend kernel."""
    inits = {t.name: numpy_helper.to_array(t) for t in model.graph.initializer}
    ops = [n.op_type for n in model.graph.node]
    if ops != ["Conv", "Relu", "Conv", "Sigmoid"]:
        raise ValueError("composition: expected the two-layer MLP Conv(1x1) -> Relu -> Conv(1x1) "
                         f"-> Sigmoid of weights_tools.build_composition, got {' -> '.join(ops)}")
    c1, _, c2, _ = model.graph.node
    try:
        w1, w2 = inits[c1.input[1]], inits[c2.input[1]]
        b1 = inits[c1.input[2]] if len(c1.input) > 2 and c1.input[2] else np.zeros(w1.shape[0])
        b2 = inits[c2.input[2]] if len(c2.input) > 2 and c2.input[2] else np.zeros(1)
    except KeyError as e:
        raise ValueError(f"composition: weight {e} is not an initializer") from None
    if w1.ndim != 4 or w1.shape[1:] != (22, 1, 1) or w2.shape != (1, w1.shape[0], 1, 1):
        raise ValueError(f"composition: expected weights [hidden, 22, 1, 1] and [1, hidden, 1, 1], "
                         f"got {list(w1.shape)} and {list(w2.shape)}")
    f = np.float32
    return (np.ascontiguousarray(w1.reshape(w1.shape[0], 22), f), np.ascontiguousarray(b1, f),
            np.ascontiguousarray(w2.reshape(-1), f), np.ascontiguousarray(np.reshape(b2, 1), f))


class ClassifierRunner:
    """The classification network at the padded output size, on device arrays.

    clss.Model runs it when it can; otherwise onnxruntime on the host does, as a
    clearly labelled temporary fallback (`backend` says which)."""

    def __init__(self, dev: Device, prec: str, model: onnx.ModelProto, shape, force=None):
        self.dev, self.prec = dev, prec
        self.input_name = model.graph.input[0].name
        self.output_name = model.graph.output[0].name
        self.shape = tuple(int(s) for s in shape)
        self._model = None
        self._session = None
        err = None
        if force != "onnxruntime":
            try:
                from ...model import Model
                self._model = Model(model, device=dev, precision=prec,
                                    input_shapes={self.input_name: list(self.shape)})
                self.backend = "clss.Model"
            except ImportError as e:
                err = e
            except Exception as e:      # a Model that cannot take this network yet
                if force == "clss":
                    raise
                err = e
        if self._model is None:
            if force == "clss":
                raise RuntimeError(f"clss.Model is not usable: {err}")
            import onnxruntime as ort
            m = onnx.ModelProto()
            m.CopyFrom(model)
            dims = m.graph.input[0].type.tensor_type.shape.dim
            for d, s in zip(dims, self.shape):
                d.Clear()
                d.dim_value = s
            so = ort.SessionOptions()
            so.intra_op_num_threads = 2
            self._session = ort.InferenceSession(m.SerializeToString(), sess_options=so,
                                                 providers=["CPUExecutionProvider"])
            self.backend = "onnxruntime (temporary fallback: clss.Model unavailable)"
            if force is None:
                warnings.warn(f"clss.pipeline: the classifier runs on onnxruntime on the host "
                              f"(temporary fallback; clss.Model: {err})", RuntimeWarning, stacklevel=3)
        self._out = None
        if self._model is not None:
            # into a buffer of ours, allocated once: the frame's compose launch stays bound to it
            self._out = dev.empty(self._model.output_shapes[self.output_name], prec)

    def output_shape(self):
        """The logits' shape where known before a run (clss.Model), else None."""
        return None if self._model is None else self._out.shape

    def __call__(self, x: cla.Array, events: list | None = None) -> cla.Array:
        """The logits of x. clss.Model enqueues its prebuilt launch plan with no host wait
        (events, if a list, gets each command's event); the onnxruntime fallback reads x
        back to the host and waits."""
        if self._model is not None:
            return self._model.run_device({self.input_name: x}, out={self.output_name: self._out},
                                          events=events)[self.output_name]
        host = self.dev.to_host(x).astype(np.float32)
        (y,) = self._session.run([self.output_name], {self.input_name: host})
        if self._out is None or self._out.shape != y.shape:
            self._out = self.dev.empty(y.shape, self.prec)
        self._out.set(np.ascontiguousarray(y.astype(self._out.dtype)))
        return self._out


class FrameStep:
    """Device buffers and launches of one frame step at a fixed render size."""

    def __init__(self, dev: Device, prec: str, mode: str, render_size, scale, *, hdr=True,
                 nits=PQ_NITS, cap=None, depth_threshold=DEPTH_THRESHOLD,
                 depth_slope=DEPTH_SLOPE, vis_margin=VIS_MARGIN, sanitize=False,
                 base="paper", classifier: onnx.ModelProto | None = None,
                 composition: onnx.ModelProto | None = None, classifier_backend=None,
                 profile=False):
        self.dev, self.prec, self.mode = dev, prec, mode
        self.h, self.w = (int(s) for s in render_size)
        self.H, self.W = output_size(self.h, self.w, scale)
        self.H16, self.W16 = pad16(self.H), pad16(self.W)
        self.hdr, self.nits = bool(hdr), float(nits)
        if base not in BASES:
            raise ValueError(f"base: expected one of {', '.join(BASES)}, got {base!r}")
        # the rules' base (net): the rules' decision, cap and weight, which the MLP corrects
        self.base = base
        rules_base = mode == "net" and base == "rules"
        self.cap = float(DEFAULT_CAP["rule" if rules_base else mode] if cap is None else cap)
        self.depth_threshold = float(depth_threshold)
        self.depth_slope = float(depth_slope)
        self.vis_margin = float(vis_margin)
        self.sanitize = bool(sanitize)
        self.profile = bool(profile)
        net = mode == "net"
        self.vec = pixels_per_item(dev, prec, mode)
        defines = dict(HDR=int(self.hdr), NET=int(net), SANITIZE=int(self.sanitize), VEC=self.vec,
                       CLSS_CLANG_VECTORS=load_defines(dev, prec, f"frame.{mode}")["CLSS_CLANG_VECTORS"],
                       CLSS_INLINE_MATH=inline_math(dev, prec, mode))
        defines.update(CLIP_EPS=float(RULE_CLIP_EPS), CLIP_GAMMA=float(CLIP_GAMMA),
                       **WIDTH_DEFINES)
        if net:
            defines.update(L_CHANNELS=LR_NET_CHANNELS, RULES_BASE=int(rules_base),
                           **dict(zip(("KNEE_TDD", "KNEE_CC", "KNEE_EDGE", "KNEE_SPREAD"),
                                      (float(k) for k in MEASURE_KNEES))))
        defines.update(AR_LO=float(AUTO_REACTIVE_LO), AR_SLOPE=float(AUTO_REACTIVE_SLOPE),
                       AR_MAX=float(AUTO_REACTIVE_MAX))
        h, w, H, W = self.h, self.w, self.H, self.W
        f32 = np.float32
        e = dev.empty
        # The caller-facing inputs (image layout, float32) for the host path.
        self.in_color, self.in_depth, self.in_motion, self.in_reactive = input_buffers(
            dev, ("color", "depth", "motion", "reactive"), (h, w))
        self.recon = e((h * w,), dtype=np.uint32)
        self.X = e((3, h, w), prec)
        self.lr = e((LR_NET_CHANNELS if net else LR_CHANNELS, h, w), dtype=f32)
        self.flags = e((8,), dtype=np.uint32)
        self.history = [e((HISTORY_CHANNELS, H, W), prec), e((HISTORY_CHANNELS, H, W), prec)]
        # net: the render-res state (s4b), float whatever the precision (depth; the colour
        # is the stored X, which float holds exactly); ping-ponged with the history
        self.prev = ([e((PREV_CHANNELS, h, w), dtype=f32), e((PREV_CHANNELS, h, w), dtype=f32)]
                     if net else [])
        self.out = e((H, W, 3), dtype=f32)
        self.bx = dev.to_device(((np.arange(W, dtype=np.float64) + 0.5) * w / W - 0.5).astype(f32))
        self.by = dev.to_device(((np.arange(H, dtype=np.float64) + 0.5) * h / H - 0.5).astype(f32))
        self.flags_host = np.zeros(8, np.uint32)
        # blend weight, ghost, depth difference at output res, written when `debug`
        self.debug = False
        self.dbg = e((3, H, W), dtype=f32)
        self.cur = 0
        self.accepted = False       # holds a state once a frame was accepted
        self.classifier = None
        if net:
            if classifier is None or composition is None:
                raise ValueError("mode 'net' needs the classifier and composition networks")
            w1, b1, w2, b2 = composition_weights(composition)
            defines["HIDDEN"] = w1.shape[0]
            self.mlp = [dev.to_device(a) for a in (w1, b1, w2, b2)]
            self.cls_in = e((1, CLASSIFIER_CHANNELS, self.H16, self.W16), prec)
            # warped counter, valid, reactive, clipped history colour (3), the depth
            # test's difference
            self.aux = e((7, self.H16, self.W16), prec)
            self.classifier = ClassifierRunner(dev, prec, classifier, self.cls_in.shape,
                                               force=classifier_backend)
            self._check_logits(self.classifier.output_shape())
        self.k = {name: dev.kernel(KERNEL, name, prec, **defines) for name in
                  ("clear", "prepare", "depth_diff", "resolve") + (("compose",) if net else ())}
        # zeroed once: no kernel then ever reads uninitialised memory (oclgrind checks it)
        self._clear(*self.history)
        if net:
            self._clear(*self.prev)
        self.events: list[tuple[str, cl.Event]] = []
        self._launches()

    def _check_logits(self, shape):
        want = (1, 6, self.H16 // 2, self.W16 // 2)
        if shape is not None and tuple(shape) != want:
            raise RuntimeError(f"classifier: expected logits of shape {want}, got {tuple(shape)}")

    def _clear(self, a, b):
        na, nb = a.nbytes // 4, b.nbytes // 4
        return self.dev.launch(self.k["clear"], (max(na, nb),),
                               (a.data, np.int32(na), b.data, np.int32(nb)))

    # -- the launch list --------------------------------------------------------
    # Each launch's arguments in the order of the @param lines at its __kernel in
    # frame.cl (which name and explain them); run() re-binds the per-frame
    # ones by these names.
    PREPARE = ("color depth motion reactive has_reactive w h depth_inverted msx msy inv_exposure "
               "pq_scale recon X lr flags").split()
    DEPTH_DIFF = "recon X lr w h depth_slope".split()
    DEPTH_DIFF_NET = DEPTH_DIFF + "prev prev_out reset".split()
    RESOLVE = "X lr bx by jx jy w h W H sx sy reset hist".split()
    RESOLVE_RULE = RESOLVE + ("hist_out out flags depth_threshold cap inv_pq_scale exposure debug "
                              "dbg").split()
    RESOLVE_NET = RESOLVE + "cls_in aux flags W16 H16".split()
    COMPOSE = ("cls_in aux logits W H W16 H16 w1 b1 w2 b2 hist hist_out out flags depth_threshold "
               "vis_margin cap inv_pq_scale exposure debug dbg").split()

    def _launches(self):
        """Every launch of a frame with its arguments bound once (clss.device.Launch): a
        frame then enqueues them with no argument marshalling, re-binding only what
        changes per frame (inputs, jitter, reset, the state's ping-pong, exposure)."""
        dev, h, w, H, W = self.dev, self.h, self.w, self.H, self.W
        i32, f = np.int32, np.float32
        na, nb = self.recon.nbytes // 4, self.flags.nbytes // 4
        hist = self.history[0].data
        vals = dict(color=self.in_color.data, depth=self.in_depth.data, motion=self.in_motion.data,
                    reactive=self.in_depth.data, has_reactive=i32(0), w=i32(w), h=i32(h),
                    depth_inverted=i32(1), msx=f(1), msy=f(1), inv_exposure=f(1),
                    pq_scale=f(self.nits / PQ_PEAK_NITS), recon=self.recon.data, X=self.X.data,
                    lr=self.lr.data, flags=self.flags.data, bx=self.bx.data, by=self.by.data,
                    jx=f(0), jy=f(0), W=i32(W), H=i32(H), sx=f(W / w), sy=f(H / h), reset=i32(1),
                    hist=hist, hist_out=self.history[1].data, out=self.out.data,
                    depth_threshold=f(self.depth_threshold), depth_slope=f(self.depth_slope),
                    vis_margin=f(self.vis_margin), cap=f(self.cap),
                    inv_pq_scale=f(PQ_PEAK_NITS / self.nits), exposure=f(1), debug=i32(0),
                    dbg=self.dbg.data, W16=i32(self.W16), H16=i32(self.H16))
        if self.prev:
            vals.update(prev=self.prev[0].data, prev_out=self.prev[1].data)
        dd_names = self.DEPTH_DIFF_NET if self.mode == "net" else self.DEPTH_DIFF
        L = {"clear": dev.prepare(self.k["clear"], (max(na, nb),),
                                  (self.recon.data, i32(na), self.flags.data, i32(nb))),
             "prepare": dev.prepare(self.k["prepare"], (-(-w // self.vec), h),
                                    [vals[n] for n in self.PREPARE]),
             "depth_diff": dev.prepare(self.k["depth_diff"], (w, h), [vals[n] for n in dd_names])}
        if self.mode == "rule":
            L["resolve"] = dev.prepare(self.k["resolve"], (-(-W // self.vec), H),
                                       [vals[n] for n in self.RESOLVE_RULE])
        else:
            vals.update(cls_in=self.cls_in.data, aux=self.aux.data, logits=self.cls_in.data,
                        **{k: a.data for k, a in zip(("w1", "b1", "w2", "b2"), self.mlp)})
            # VEC pixels per work-item, as the rule resolve (a W16-wide launch left
            # VEC - 1 of every VEC work-items returning at once)
            L["resolve"] = dev.prepare(self.k["resolve"], (-(-self.W16 // self.vec), self.H16),
                                       [vals[n] for n in self.RESOLVE_NET])
            L["compose"] = dev.prepare(self.k["compose"], (-(-W // self.vec), H),
                                       [vals[n] for n in self.COMPOSE])
        self.launch = L
        self.pos = {k: {n: i for i, n in enumerate(names)} for k, names in (
            ("prepare", self.PREPARE), ("compose", self.COMPOSE), ("depth_diff", dd_names),
            ("resolve", self.RESOLVE_RULE if self.mode == "rule" else self.RESOLVE_NET))}

    def _bind(self, name, **values):
        launch, pos = self.launch[name], self.pos[name]
        for k, v in values.items():
            launch.bind(pos[k], v)

    # -- one frame ------------------------------------------------------------
    def run(self, color, depth, motion, reactive, jitter, reset, *, depth_inverted=True,
            motion_scale=(1.0, 1.0), exposure=1.0, out=None, read_flags=True):
        """Enqueue one frame (device arrays in image layout, float32) with no host wait:
        no finish, no host read or allocation between its launches. Returns the event of
        the flags read-back, enqueued last; the caller waits on it and calls `verdict()`.
        read_flags=False (a step inside another method's, NSRR's rules base): no read-back,
        the last kernel's event instead."""
        q, L = self.dev.queue, self.launch
        i32, f = np.int32, np.float32
        out = self.out if out is None else out
        hist, hist_out = self.history[self.cur], self.history[1 - self.cur]
        has_r = reactive is not None
        self._bind("prepare", color=color.data, depth=depth.data, motion=motion.data,
                   reactive=(reactive if has_r else depth).data, has_reactive=i32(has_r),
                   depth_inverted=i32(bool(depth_inverted)), msx=f(motion_scale[0]),
                   msy=f(motion_scale[1]), inv_exposure=f(1.0 / exposure))
        frame_args = dict(jx=f(jitter[0]), jy=f(jitter[1]), reset=i32(bool(reset)), hist=hist.data)
        blend_args = dict(hist_out=hist_out.data, out=out.data, exposure=f(exposure),
                          debug=i32(self.debug))
        if self.prev:
            self._bind("depth_diff", prev=self.prev[self.cur].data,
                       prev_out=self.prev[1 - self.cur].data, reset=i32(bool(reset)))
        ev = [("prepare", L["clear"]()), ("prepare", L["prepare"]()),
              ("depth_diff", L["depth_diff"]())]
        if self.mode == "rule":
            self._bind("resolve", **frame_args, **blend_args)
            ev.append(("resolve", L["resolve"]()))
        else:
            self._bind("resolve", **frame_args)
            ev.append(("resolve", L["resolve"]()))
            cls_events = [] if self.profile else None
            logits = self.classifier(self.cls_in, cls_events)
            if self.profile:
                ev += [("classifier", e) for e in cls_events]
            if self.classifier.output_shape() is None:      # the host fallback: known now
                self._check_logits(logits.shape)
            self._bind("compose", logits=logits.data, hist=hist.data, **blend_args)
            ev.append(("compose", L["compose"]()))
        if self.profile:
            self.events.extend(ev)
        if not read_flags:
            return ev[-1][1]
        # The one host read of a frame, last: later kernels only read the flags.
        return cl.enqueue_copy(q, self.flags_host, self.flags.data, is_blocking=False)

    def verdict(self) -> tuple[list[tuple[str, str]], dict]:
        """After the flags event: (refusals [(input, what)], sanitised {input: count})."""
        bits = int(self.flags_host[0])
        refuse_mask = 48 if self.sanitize else 63
        refused = [FLAG_BITS[b] for b in sorted(FLAG_BITS) if bits & b & refuse_mask]
        sanitized = {}
        if self.sanitize:
            for b, (name, _) in FLAG_BITS.items():
                if b & NONFINITE_BITS and bits & b:
                    sanitized[name] = int(self.flags_host[1 + {1: 0, 2: 1, 4: 2, 8: 3}[b]])
        return refused, sanitized

    def accept(self):
        """The frame was accepted: the new history (and net mode's prev) becomes the state."""
        self.cur = 1 - self.cur
        self.accepted = True

    @property
    def state(self) -> cla.Array:
        return self.history[self.cur]

    @property
    def prev_state(self) -> cla.Array | None:
        """Net mode: [4, h, w] float, the last accepted frame's encoded colour and own
        (not dilated) depth (reference.md s4b); None in rule mode."""
        return self.prev[self.cur] if self.prev else None

    # -- timings ----------------------------------------------------------------
    def stage_ms(self) -> dict[str, float]:
        """Milliseconds per stage summed since the last call (OpenCL event times; the
        classifier's are its kernels' and copies', summed)."""
        return summed_event_ms(self.events, STAGES)

    def device_bytes(self) -> int:
        arrays = [self.in_color, self.in_depth, self.in_motion, self.in_reactive, self.recon,
                  self.X, self.lr, self.flags, self.out, self.dbg, self.bx, self.by, *self.history,
                  *self.prev]
        if self.mode == "net":
            arrays += [self.cls_in, self.aux, *self.mlp]
        return int(sum(a.nbytes for a in arrays))
