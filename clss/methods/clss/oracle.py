"""The whole CLSS frame step as one ONNX graph, run by onnxruntime: the oracle.

Every formula here is written down in clss/methods/clss/reference.md (stage numbers match);
the OpenCL frame path is checked against this graph.  State is explicit: the graph takes
the history tensor [1,16,H,W] and returns the next one, nothing is hidden in the session.

Graph inputs (internal conventions, see contract.to_internal):
    color    [1,3,h,w]  linear / exposure        depth   [1,1,h,w] reversed-Z
    motion   [1,2,h,w]  render pixels            jitter  [2] render pixels
    reset    [1]        1.0 = camera cut         reactive [1,1,h,w] in [0,1]
    history  [1,16,H,W] PQ colour 3, counter 1, colour min 3, max 3, logits 6
    prev     [1,4,h,w]  mode "net" only: the previous frame's encoded colour 3 and own
                        (not dilated) depth (reference.md s4b), the previous step's prev_out
Graph outputs: output [1,3,H,W] linear (/ exposure), history_out [1,16,H,W], in mode
"net" prev_out [1,4,h,w], and with debug=True the intermediate buffers listed in
DEBUG_OUTPUTS (and DEBUG_OUTPUTS_NET).
"""
from __future__ import annotations

import math
import numbers
from typing import NamedTuple

import numpy as np
import onnx
from onnx import TensorProto, helper

from .networks import BASES, CLASSIFIER_CHANNELS, COMPOSITION_CHANNELS
from .networks import pad16 as _pad16
from ...model.graph import fill_output_shapes
from ...pipeline.twin import GraphBuilder as _Graph
from ...pipeline.twin import IR_VERSION, make_model  # noqa: F401 (IR_VERSION: read as oracle.IR_VERSION)
from ...pipeline.twin import pq_decode as _pq_decode
from ...pipeline.twin import pq_encode as _pq_encode
# (H_* and the other constants are also read as oracle.NAME by tests and tools.)
from ...pipeline.contract import (PQ_C1, PQ_C2, PQ_C3, PQ_M1, PQ_M2, PQ_NITS, PQ_PEAK_NITS,
                                  output_size, to_internal, validate_frame)
from .contract import (AUTO_REACTIVE_LO, AUTO_REACTIVE_MAX, AUTO_REACTIVE_SLOPE, CLIP_GAMMA,
                       DEFAULT_CAP, DEPTH_EPS, DEPTH_SLOPE, DEPTH_THRESHOLD, DILATE_OFFSETS,
                       H_COLOR, H_COUNTER, H_LOGITS, H_MAX, H_MIN, HISTORY_CHANNELS, MEASURE_KNEES,
                       MODES, RULE_CLIP_EPS, SCATTER_WEIGHT_THRESHOLD, VIS_MARGIN)

OPSET = 18
PREV_CHANNELS = 4   # mode "net": the render-res state prev (encoded colour 3, own depth)

DEBUG_OUTPUTS = {
    # render resolution
    "dbg_dilated_depth": "[1,1,h,w] stage 1 nearest depth of the 3x3 neighbourhood",
    "dbg_dilated_motion": "[1,2,h,w] stage 1 motion of that neighbour (render px)",
    "dbg_recon_depth": "[1,1,h,w] stage 2 reconstructed previous depth (0 = far)",
    "dbg_depth_diff": "[1,1,h,w] stage 3 relative depth difference, > 0 = disocclusion",
    # output resolution
    "dbg_upsampled": "[1,3,H,W] stage 4 jitter-aware bicubic colour (PQ)",
    "dbg_depth_hr": "[1,1,H,W] stage 4 bilinear dilated depth",
    "dbg_motion_hr": "[1,2,H,W] stage 4 bilinear dilated motion (output px)",
    "dbg_depth_diff_hr": "[1,1,H,W] stage 4 bilinear depth difference",
    "dbg_depth_test_hr": "[1,1,H,W] stage 4 bilinear depth test's difference (less the slope term)",
    "dbg_reactive_hr": "[1,1,H,W] stage 4 bilinear reactive mask",
    "dbg_valid": "[1,1,H,W] stage 5 1 = history usable (on-screen and no reset)",
    "dbg_warped": "[1,16,H,W] stage 5 warped history, invalid pixels re-initialised",
    "dbg_ghost": "[1,1,H,W] stage 7 1 = history rejected (counter reset)",
    "dbg_counter": "[1,1,H,W] stage 7 new sample counter",
    "dbg_w": "[1,1,H,W] stage 8 blend weight of the current frame",
    "dbg_blend_history": "[1,3,H,W] stage 9 history colour entering the blend (PQ)",
    "dbg_clamp_min": "[1,3,H,W] stage 4 bilinear clamp box low (3x3 render-res, PQ)",
    "dbg_clamp_max": "[1,3,H,W] stage 4 bilinear clamp box high (3x3 render-res, PQ)",
}
DEBUG_OUTPUTS_NET = {
    "dbg_measurements": "[1,4,h,w] s4b the classifier's measurements (render res, compressed)",
    "dbg_measurements_hr": "[1,4,H,W] s4b stage 4 those of the render pixel holding each output pixel's centre",
    "dbg_cls_input": "[1,27,H,W] stage 6 classifier input, before padding",
    "dbg_logits": "[1,6,H,W] stage 6 current logits after the bilinear x2 and crop",
    "dbg_comp_input": "[1,22,H,W] stage 8 composition input",
}


def _model_opset(model):
    if model is None:
        return 0
    return max((o.version for o in model.opset_import if o.domain in ("", "ai.onnx")), default=0)


def _real_input(model, what, want_channels):
    init_names = {t.name for t in model.graph.initializer}
    ins = [i for i in model.graph.input if i.name not in init_names]
    if len(ins) != 1 or len(model.graph.output) != 1:
        raise ValueError(f"{what}: expected one input and one output, got "
                         f"{[i.name for i in ins]} -> {[o.name for o in model.graph.output]}")
    dims = [d.dim_value if d.HasField("dim_value") else None
            for d in ins[0].type.tensor_type.shape.dim]
    if len(dims) == 4 and dims[1] not in (None, want_channels):
        raise ValueError(f"{what}: expected {want_channels} input channels, got {dims[1]}")
    return ins[0].name, model.graph.output[0].name, dims


def _check_static_hw(what, dims, hw):
    if len(dims) == 4:
        for got, want, axis in zip(dims[2:], hw, "HW"):
            if got is not None and got != want:
                raise ValueError(f"{what}: built for a fixed {axis} = {got}, the pipeline "
                                 f"feeds {want} (build it with height/width None or {hw})")


def _clip_towards(g, hist, up, lo, hi):
    """The history clip (reference.md s9): up + t (hist - up), one t in [0, 1] for the
    three channels, the largest that keeps every channel inside [lo - eps, hi + eps]
    (when `up` is inside; an `up` outside only stops the history from moving further
    out)."""
    eps = g.const(RULE_CLIP_EPS)
    d = g.sub(hist, up)
    lim = g.where(g.op("Greater", d, g.const(0.0)), g.sub(g.add(hi, eps), up),
                  g.sub(g.sub(lo, eps), up))
    nz = g.op("Not", g.op("Equal", d, g.const(0.0)))
    tc = g.where(nz, g.div(lim, g.where(nz, d, g.const(1.0))), g.const(1.0))
    t = g.op("Min", g.op("ReduceMin", g.op("Max", tc, g.const(0.0)), g.i64([1]), keepdims=1),
             g.const(1.0))
    return g.add(up, g.mul(t, d))


def check_vis_margin(vis_margin) -> float:
    """`vis_margin` (reference.md s7) as a float; a ValueError naming it unless it is a
    finite real number (a string or NaN would silently make every or no logit lead)."""
    if (isinstance(vis_margin, bool) or not isinstance(vis_margin, numbers.Real)
            or not math.isfinite(vis_margin)):
        raise ValueError(f"vis_margin: expected a finite number (the visibility logit's "
                         f"lead, 0 = argmax), got {vis_margin!r}")
    return float(vis_margin)


def build_frame_graph(mode="rule", render_size=(540, 960), scale=2.0, classifier=None,
                      composition=None, cap=None, *, depth_threshold=DEPTH_THRESHOLD,
                      depth_slope=DEPTH_SLOPE, vis_margin=VIS_MARGIN, hdr=True, nits=PQ_NITS,
                      debug=False, base="paper") -> onnx.ModelProto:
    """One CLSS frame step as an ONNX model (see reference.md for every formula).

    mode "rule": no networks, ghost = off-screen or reset or the depth test's difference
    (the depth difference less `depth_slope` x the local relative depth step) >
    `depth_threshold`, w = 1/(1+counter), history clipped towards the current colour
    into the current 3x3 neighbourhood's box.  mode "net": `classifier` and `composition` (onnx.ModelProto from
    networks.py) are inlined; ghost = the visibility logit leads the larger of the
    other two by >= `vis_margin` (0: the argmax) or the depth test, or off-screen or
    reset.  `base` "rules" (net, networks.BASES; reference.md s9): the rule's decision and
    cap, and the composition's sigmoid s corrects the rule weight 1/(1+n) as
    s / (s + n (1 - s)) = 1/(1 + n exp(-z)).  `render_size` = (h, w).  `cap`: counter cap
    (default 4 for rule and the rules' base, 32 for net).  `hdr=False`: LDR in/out, no PQ (values clamped
    to [0,1]).  `debug=True` adds the DEBUG_OUTPUTS(_NET) graph outputs.
    """
    if mode not in MODES:
        raise ValueError(f"mode: expected one of {MODES}, got {mode!r}")
    h, w = int(render_size[0]), int(render_size[1])
    H, W = output_size(h, w, scale)
    if base not in BASES:
        raise ValueError(f"base: expected one of {', '.join(BASES)}, got {base!r}")
    rules_base = mode == "net" and base == "rules"
    cap = float(DEFAULT_CAP["rule" if rules_base else mode] if cap is None else cap)
    if not cap >= 0:
        raise ValueError(f"cap: expected a number >= 0, got {cap}")
    vis_margin = check_vis_margin(vis_margin)
    if mode == "net":
        if classifier is None or composition is None:
            raise ValueError("mode 'net' needs both classifier and composition models")
    opset = max(OPSET, _model_opset(classifier), _model_opset(composition))
    if opset > 21:
        raise ValueError(f"network opset {opset} > 21 (onnxruntime with IR 10)")
    g = _Graph(opset)
    dbg = {}

    f32 = TensorProto.FLOAT
    inputs = [helper.make_tensor_value_info("color", f32, [1, 3, h, w]),
              helper.make_tensor_value_info("depth", f32, [1, 1, h, w]),
              helper.make_tensor_value_info("motion", f32, [1, 2, h, w]),
              helper.make_tensor_value_info("jitter", f32, [2]),
              helper.make_tensor_value_info("reset", f32, [1]),
              helper.make_tensor_value_info("reactive", f32, [1, 1, h, w]),
              helper.make_tensor_value_info("history", f32, [1, HISTORY_CHANNELS, H, W])]
    if mode == "net":
        inputs.append(helper.make_tensor_value_info("prev", f32, [1, PREV_CHANNELS, h, w]))

    # Transfer function: everything below works on encoded colour.
    if hdr:
        X = _pq_encode(g, "color", nits)
    else:
        X = g.clip("color", 0.0, 1.0)

    d_dil, m_dil = _stage1_dilate(g, h, w, dbg)
    taps, recon = _stage2_reconstruct(g, h, w, d_dil, m_dil, dbg)
    dd = _stage3_depth_diff(g, taps, recon, d_dil, dbg)
    ddt = _depth_test_diff(g, h, w, dd, d_dil, depth_slope)
    # s4b: of the pixel's own depth and motion (the graph inputs), not the dilated ones
    meas = _measurements(g, h, w, X, "depth", "motion", dbg) if mode == "net" else None
    hr = _stage4_upsample(g, (h, w), (H, W), X, d_dil, m_dil, dd, ddt, meas, dbg)
    warped = _stage5_warp(g, (H, W), hr, dbg)
    ghost, logits = _stage6_classify(g, mode, (H, W), classifier, depth_threshold, vis_margin,
                                     hr, warped, dbg, rules_base)
    cnt, c_min, c_max = _stage7_aux(g, cap, ghost, hr.up, warped, dbg)
    wgt, new_logits = _stage8_blend_weight(g, mode, (H, W), composition, hr, warped,
                                           (cnt, c_min, c_max), logits, ghost, dbg, rules_base)
    _stage9_blend(g, hdr, nits, wgt, hr.up, warped.blend_hist, (cnt, c_min, c_max), new_logits)

    outputs = [helper.make_tensor_value_info("output", f32, [1, 3, H, W]),
               helper.make_tensor_value_info("history_out", f32, [1, HISTORY_CHANNELS, H, W])]
    if mode == "net":
        outputs.append(helper.make_tensor_value_info("prev_out", f32, [1, PREV_CHANNELS, h, w]))
    if debug:
        for name, t in dbg.items():
            g.op("Identity", t, name=name)
            outputs.append(helper.make_tensor_value_info(name, f32, None))
    model = make_model(g.nodes, g.inits, f"clss_frame_{mode}", inputs, outputs, __name__, opset,
                       doc_string=f"CLSS frame step, mode={mode}{', base rules' if rules_base else ''}, "
                                  f"render {h}x{w} -> {H}x{W}, "
                                  f"cap={cap:g}, hdr={hdr}, nits={nits:g}")
    if debug:
        fill_output_shapes(model)
    onnx.checker.check_model(model)
    return model


# The stages of build_frame_graph, numbered as in reference.md. Each adds its nodes to g
# (in the order the graph lists them) and its debug outputs to dbg.

class _Upsampled(NamedTuple):
    """Stage 4's output-resolution tensors."""
    up: str          # [1,3,H,W] jitter-aware bicubic colour (encoded)
    depth: str       # [1,1,H,W] bilinear dilated depth
    motion: str      # [1,2,H,W] bilinear dilated motion, output pixels
    depth_diff: str  # [1,1,H,W]
    depth_test: str  # [1,1,H,W] the depth test's difference (s4)
    reactive: str    # [1,1,H,W]
    box_lo: str      # [1,3,H,W] the current 3x3 neighbourhood's clamp box
    box_hi: str
    measure: str | None  # [1,4,H,W] net: the classifier's measurements (s4b); rule: None


class _Warped(NamedTuple):
    """Stage 5's warped history (invalid pixels re-initialised) and its validity."""
    valid: str       # [1,1,H,W] bool
    color: str
    counter: str
    c_min: str
    c_max: str
    logits: str
    blend_hist: str  # the colour clipped into the box (s9), the one the blend uses


def _shifted(g, x, dx, dy, h, w):
    """The [h,w] window of x (padded by 1 on each side) shifted by (dx, dy)."""
    return g.op("Slice", x, g.i64([1 + dy, 1 + dx]), g.i64([1 + dy + h, 1 + dx + w]),
                g.i64([2, 3]))


def _auto_reactive(g, m_dil, h, w):
    """max(reactive, clip((divergence - LO) * SLOPE, 0, MAX)) at render res: the divergence
    is the largest |dmx| + |dmy| of the dilated motion over the 3x3 neighbourhood
    (contract.AUTO_REACTIVE_*). Edge padding repeats in-bounds neighbours, so the maximum
    is the kernel's over the in-bounds ones."""
    pm = g.op("Pad", m_dil, g.i64([0, 0, 1, 1, 0, 0, 1, 1]), mode="edge")
    mx, my = g.chan(m_dil, slice(0, 1)), g.chan(m_dil, slice(1, 2))
    div = g.const(0.0)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            n = _shifted(g, pm, dx, dy, h, w)
            d = g.add(g.op("Abs", g.sub(g.chan(n, slice(0, 1)), mx)),
                      g.op("Abs", g.sub(g.chan(n, slice(1, 2)), my)))
            div = g.op("Max", div, d)
    auto = g.clip(g.mul(g.sub(div, g.const(AUTO_REACTIVE_LO)), g.const(AUTO_REACTIVE_SLOPE)),
                  0.0, AUTO_REACTIVE_MAX)
    return g.op("Max", "reactive", auto)


def _inv_counter(g, c):
    one = g.const(1.0)
    return g.div(one, g.add(one, c))


def _stage1_dilate(g, h, w, dbg):
    """Stage 1 (render res): depth and motion of the nearest of the 3x3 neighbourhood."""
    pads = g.i64([0, 0, 1, 1, 0, 0, 1, 1])
    # -1 is nearer to nothing: off-screen neighbours never win.
    pd = g.op("Pad", "depth", pads, g.const(-1.0), mode="constant")
    pm = g.op("Pad", "motion", pads, g.const(0.0), mode="constant")
    d9 = g.concat([_shifted(g, pd, dx, dy, h, w) for dx, dy in DILATE_OFFSETS])  # [1,9,h,w]
    m9 = g.concat([g.op("Unsqueeze", _shifted(g, pm, dx, dy, h, w), g.i64([1]))
                   for dx, dy in DILATE_OFFSETS])                                # [1,9,2,h,w]
    nearest = g.op("ArgMax", d9, axis=1, keepdims=1, select_last_index=0)         # [1,1,h,w]
    d_dil = g.op("GatherElements", d9, nearest, axis=1, name="dilated_depth")
    idx5 = g.op("Expand", g.op("Unsqueeze", nearest, g.i64([2])), g.i64([1, 1, 2, h, w]))
    m_dil = g.op("Squeeze", g.op("GatherElements", m9, idx5, axis=1), g.i64([1]),
                 name="dilated_motion")                                          # [1,2,h,w]
    dbg["dbg_dilated_depth"], dbg["dbg_dilated_motion"] = d_dil, m_dil
    return d_dil, m_dil


def _tap_index(g, xk, yk, h, w):
    """(on screen, linear index into h x w with the tap clamped to the edge) of the render
    index coordinates xk, yk: the scatter's taps (s3) and the measurements' tap (s4b)."""
    on = g.op("And",
              g.op("And", g.op("GreaterOrEqual", xk, g.const(0.0)),
                   g.op("LessOrEqual", xk, g.const(float(w - 1)))),
              g.op("And", g.op("GreaterOrEqual", yk, g.const(0.0)),
                   g.op("LessOrEqual", yk, g.const(float(h - 1)))))
    xi = g.op("Cast", g.clip(xk, 0.0, float(w - 1)), to=TensorProto.INT64)
    yi = g.op("Cast", g.clip(yk, 0.0, float(h - 1)), to=TensorProto.INT64)
    return on, g.add(g.mul(yi, g.i64(w)), xi)


def _stage2_reconstruct(g, h, w, d_dil, m_dil, dbg):
    """Stage 2: the previous frame's depth, scatter-max of the dilated depth along the
    motion (reversed-Z). Returns the bilinear taps (weight, on-screen, index, scatter
    index) and the flat reconstruction [h*w + 1]."""
    jj = g.const(np.arange(w, dtype=np.float32).reshape(1, 1, 1, w), hint="jj")
    ii = g.const(np.arange(h, dtype=np.float32).reshape(1, 1, h, 1), hint="ii")
    ux = g.add(jj, g.chan(m_dil, slice(0, 1)))
    uy = g.add(ii, g.chan(m_dil, slice(1, 2)))
    x0, y0 = g.op("Floor", ux), g.op("Floor", uy)
    fx, fy = g.sub(ux, x0), g.sub(uy, y0)
    wx = (g.sub(g.const(1.0), fx), fx)
    wy = (g.sub(g.const(1.0), fy), fy)
    taps = []
    for a, b in ((0, 0), (1, 0), (0, 1), (1, 1)):
        wk = g.mul(wx[a], wy[b])
        xk = g.add(x0, g.const(float(a))) if a else x0
        yk = g.add(y0, g.const(float(b))) if b else y0
        on, lin = _tap_index(g, xk, yk, h, w)                                     # [1,1,h,w]
        scat = g.op("And", on, g.op("Greater", wk, g.const(SCATTER_WEIGHT_THRESHOLD)))
        # Refused taps go to one spare slot past the image, sliced off afterwards.
        sidx = g.where(scat, lin, g.i64(h * w))
        taps.append((wk, on, lin, sidx))
    sidx = g.reshape(g.concat([t[3] for t in taps]), [-1])
    upd = g.reshape(g.concat([d_dil] * 4), [-1])
    recon = g.op("ScatterElements", g.const(np.zeros(h * w + 1, np.float32), hint="far"),
                 sidx, upd, axis=0, reduction="max")
    recon_img = g.reshape(g.slice(recon, 0, 0, h * w), [1, 1, h, w])
    dbg["dbg_recon_depth"] = recon_img
    return taps, recon


def _stage3_depth_diff(g, taps, recon, d_dil, dbg):
    """Stage 3: depth difference, bilinear of the reconstruction at p + motion."""
    rs = None
    for wk, on, lin, _ in taps:
        v = g.mul(g.mul(g.op("Gather", recon, lin, axis=0), g.op("Cast", on, to=TensorProto.FLOAT)), wk)
        rs = v if rs is None else g.add(rs, v)
    dd = g.clip(g.div(g.sub(rs, d_dil), g.op("Max", rs, g.const(DEPTH_EPS))), -1.0, 1.0)
    dd = g.op("Identity", dd, name="depth_diff")
    dbg["dbg_depth_diff"] = dd
    return dd


def _measurements(g, h, w, X, d, m, dbg):
    """s4b (mode "net", render res): the classifier's four measurements [1,4,h,w] of the
    pixel's own depth d and motion m (not the dilated ones), each compressed as
    v / (|v| + MEASURE_KNEES[k]); and the graph output prev_out, this frame's encoded
    colour and depth d, which the next frame reads as `prev`."""
    g.concat([X, d], name="prev_out")
    # The previous frame at the pixel nearest to p + motion: floor((j + m.x) + 0.5), the
    # kernel's and the torch twin's order of float operations, so all read the same pixel.
    jj = g.const(np.arange(w, dtype=np.float32).reshape(1, 1, 1, w), hint="jj")
    ii = g.const(np.arange(h, dtype=np.float32).reshape(1, 1, h, 1), hint="ii")
    half = g.const(0.5)
    qx = g.op("Floor", g.add(g.add(jj, g.chan(m, slice(0, 1))), half))
    qy = g.op("Floor", g.add(g.add(ii, g.chan(m, slice(1, 2))), half))
    on, lin = _tap_index(g, qx, qy, h, w)
    lin = g.reshape(lin, [-1])                                                     # [h*w]
    pv = g.reshape(g.op("Gather", g.reshape("prev", [1, PREV_CHANNELS, h * w]), lin, axis=2),
                   [1, PREV_CHANNELS, h, w])
    pd = g.chan(pv, slice(3, 4))
    zero, one = g.const(0.0), g.const(1.0)
    tdd = g.clip(g.div(g.sub(pd, d), g.op("Max", pd, g.const(DEPTH_EPS))), -1.0, 1.0)
    cc = g.op("ReduceMax", g.op("Abs", g.sub(X, g.chan(pv, slice(0, 3)))), g.i64([1]),
              keepdims=1)
    # off screen: no previous frame, the largest change; a reset: none either, and 0
    # (Where, not a product: `prev` is not read on a reset, whatever it holds)
    keep = g.reshape(g.op("Less", "reset", g.const([0.5])), [1, 1, 1, 1])
    tdd = g.where(keep, g.where(on, tdd, one), zero)
    cc = g.where(keep, g.where(on, cc, one), zero)
    # 3x3 ranges over the in-bounds neighbours (MaxPool pads with -inf)
    win = dict(kernel_shape=[3, 3], pads=[1, 1, 1, 1], strides=[1, 1])
    dmax = g.op("MaxPool", d, **win)
    dmin = g.op("Neg", g.op("MaxPool", g.op("Neg", d), **win))
    edge = g.div(g.sub(dmax, dmin), g.op("Max", dmax, g.const(DEPTH_EPS)))
    xmin = g.op("Neg", g.op("MaxPool", g.op("Neg", X), **win))
    spread = g.op("ReduceMax", g.sub(g.op("MaxPool", X, **win), xmin), g.i64([1]), keepdims=1)
    meas = g.concat([g.div(v, g.add(g.op("Abs", v), g.const(k)))
                     for v, k in zip((tdd, cc, edge, spread), MEASURE_KNEES)])
    dbg["dbg_measurements"] = meas
    return meas


def _depth_test_diff(g, h, w, dd, d_dil, depth_slope):
    """s4: the depth test's difference, dd less depth_slope x the local relative depth
    step (the smaller one-sided step in x plus that in y; edge pixels repeat, a step of 0),
    in the kernel's order: a grazing floor steps steadily on both sides and passes, a
    silhouette is flat on one side and stays tested."""
    pd = g.op("Pad", d_dil, g.i64([0, 0, 1, 1, 0, 0, 1, 1]), mode="edge")
    step = []
    for (ax, ay), (bx, by) in (((1, 0), (-1, 0)), ((0, 1), (0, -1))):
        ahead = g.op("Abs", g.sub(_shifted(g, pd, ax, ay, h, w), d_dil))
        behind = g.op("Abs", g.sub(d_dil, _shifted(g, pd, bx, by, h, w)))
        step.append(g.op("Min", ahead, behind))
    rel = g.div(g.add(step[0], step[1]), g.op("Max", d_dil, g.const(DEPTH_EPS)))
    return g.sub(dd, g.mul(g.const(float(depth_slope)), rel))


def _stage4_upsample(g, hw, HW, X, d_dil, m_dil, dd, ddt, meas, dbg) -> _Upsampled:
    """Stage 4: upsample at output pixel centres, jitter-aware; the clamp box; in mode
    "net" (meas given) the classifier's measurements, nearest (s4b)."""
    (h, w), (H, W) = hw, HW
    jx, jy = g.slice("jitter", 0, 0, 1), g.slice("jitter", 0, 1, 2)
    bx = ((np.arange(W, dtype=np.float64) + 0.5) * w / W - 0.5).astype(np.float32)
    by = ((np.arange(H, dtype=np.float64) + 0.5) * h / H - 0.5).astype(np.float32)
    gx = g.normalised(g.clip(g.sub(g.const(bx, hint="bx"), jx), 0.0, float(w - 1)), w)
    gy = g.normalised(g.clip(g.sub(g.const(by, hint="by"), jy), 0.0, float(h - 1)), h)
    shape_hw1 = g.i64([1, H, W, 1])
    grid_up = g.concat([g.op("Expand", g.reshape(gx, [1, 1, W, 1]), shape_hw1),
                        g.op("Expand", g.reshape(gy, [1, H, 1, 1]), shape_hw1)], axis=3)
    up = g.clip(g.grid_sample(X, grid_up, cubic=True), 0.0, 1.0)
    up = g.op("Identity", up, name="upsampled")
    # 3x3 neighbourhood box of the current frame (both modes clip the history into it):
    # min/max narrowed to mean +- CLIP_GAMMA std, off-screen neighbours left out (MaxPool
    # pads with -inf; the moments use in-bounds masks). The moments are those of the
    # differences to the centre pixel, summed row by row as the kernel does: the moments
    # of the values themselves cancel (E[x^2] - E[x]^2) badly enough in float to move the
    # box by 1e-4.
    win = dict(kernel_shape=[3, 3], pads=[1, 1, 1, 1], strides=[1, 1])
    nmax = g.op("MaxPool", X, **win)
    nmin = g.op("Neg", g.op("MaxPool", g.op("Neg", X), **win))
    px = g.op("Pad", X, g.i64([0, 0, 1, 1, 0, 0, 1, 1]), mode="edge")
    s1 = s2 = None
    count = np.zeros((1, 1, h, w), np.float32)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            on = np.zeros((h + 2, w + 2), np.float32)
            on[1:h + 1, 1:w + 1] = 1.0
            on = on[1 + dy:1 + dy + h, 1 + dx:1 + dx + w].reshape(1, 1, h, w)
            count += on
            d = g.mul(g.sub(_shifted(g, px, dx, dy, h, w), X), g.const(on, hint="in_bounds"))
            s1 = d if s1 is None else g.add(s1, d)
            s2 = g.mul(d, d) if s2 is None else g.add(s2, g.mul(d, d))
    cnt = g.const(count, hint="neighbours")
    md = g.div(s1, cnt)
    var = g.sub(g.div(s2, cnt), g.mul(md, md))
    gsd = g.mul(g.const(CLIP_GAMMA), g.op("Sqrt", g.op("Max", var, g.const(0.0))))
    mu = g.add(X, md)
    nmin = g.op("Max", nmin, g.sub(mu, gsd))
    nmax = g.op("Min", nmax, g.add(mu, gsd))
    react = _auto_reactive(g, m_dil, h, w)
    # the kernel's render-res stack (its lr buffer), in its channel order
    aux = g.grid_sample(g.concat([d_dil, m_dil, dd, react, ddt, nmin, nmax]), grid_up,
                        cubic=False)
    depth_hr = g.chan(aux, slice(0, 1))
    motion_hr = g.mul(g.chan(aux, slice(1, 3)),
                      g.const(np.array([W / w, H / h], np.float32).reshape(1, 2, 1, 1)))
    dd_hr = g.chan(aux, slice(3, 4))
    react_hr = g.chan(aux, slice(4, 5))
    ddt_hr = g.chan(aux, slice(5, 6))
    c_lo = g.chan(aux, slice(6, 9))
    c_hi = g.chan(aux, slice(9, 12))
    meas_hr = None
    if meas is not None:
        # s4b: output pixel (I, J) takes the measurements of the render pixel holding its
        # centre, ((2I + 1) h) // (2H) in integers (no jitter): Gather, exact data movement
        ri = (2 * np.arange(H, dtype=np.int64) + 1) * h // (2 * H)
        rj = (2 * np.arange(W, dtype=np.int64) + 1) * w // (2 * W)
        meas_hr = g.op("Gather", g.op("Gather", meas, g.i64(ri), axis=2), g.i64(rj), axis=3)
        dbg["dbg_measurements_hr"] = meas_hr
    dbg.update(dbg_upsampled=up, dbg_depth_hr=depth_hr, dbg_motion_hr=motion_hr,
               dbg_depth_diff_hr=dd_hr, dbg_depth_test_hr=ddt_hr, dbg_reactive_hr=react_hr,
               dbg_clamp_min=c_lo, dbg_clamp_max=c_hi)
    return _Upsampled(up, depth_hr, motion_hr, dd_hr, ddt_hr, react_hr, c_lo, c_hi, meas_hr)


def _stage5_warp(g, HW, hr: _Upsampled, dbg) -> _Warped:
    """Stage 5: warp the history at P + motion_hr; and (s9) the colour the blend uses."""
    H, W = HW
    JJ = g.const(np.arange(W, dtype=np.float32).reshape(1, 1, 1, W), hint="JJ")
    II = g.const(np.arange(H, dtype=np.float32).reshape(1, 1, H, 1), hint="II")
    su = g.add(JJ, g.chan(hr.motion, slice(0, 1)))
    sv = g.add(II, g.chan(hr.motion, slice(1, 2)))
    off = g.op("Or",
               g.op("Or", g.op("Less", su, g.const(-0.5)), g.op("Greater", su, g.const(W - 0.5))),
               g.op("Or", g.op("Less", sv, g.const(-0.5)), g.op("Greater", sv, g.const(H - 0.5))))
    no_reset = g.op("Less", "reset", g.const([0.5]))
    valid = g.op("And", g.op("Not", off), g.reshape(no_reset, [1, 1, 1, 1]))
    gxw = g.normalised(g.clip(su, 0.0, float(W - 1)), W)
    gyw = g.normalised(g.clip(sv, 0.0, float(H - 1)), H)
    grid_w = g.op("Transpose", g.concat([gxw, gyw]), perm=[0, 2, 3, 1])
    hist_c = g.clip(g.grid_sample(g.chan("history", H_COLOR), grid_w, cubic=True), 0.0, 1.0)
    hist_o = g.grid_sample(g.chan("history", slice(3, HISTORY_CHANNELS)), grid_w, cubic=False)
    up, zero = hr.up, g.const(0.0)
    w_col = g.where(valid, hist_c, up)
    w_cnt = g.where(valid, g.chan(hist_o, slice(0, 1)), zero)
    w_min = g.where(valid, g.chan(hist_o, slice(1, 4)), up)
    w_max = g.where(valid, g.chan(hist_o, slice(4, 7)), up)
    w_log = g.where(valid, g.chan(hist_o, slice(7, 13)), zero)
    dbg["dbg_valid"] = g.op("Cast", valid, to=TensorProto.FLOAT)
    dbg["dbg_warped"] = g.concat([w_col, w_cnt, w_min, w_max, w_log])
    # s9 the history the blend uses: clipped into the current neighbourhood's box
    blend_hist = _clip_towards(g, w_col, up, hr.box_lo, hr.box_hi)
    dbg["dbg_blend_history"] = blend_hist
    return _Warped(valid, w_col, w_cnt, w_min, w_max, w_log, blend_hist)


def _stage6_classify(g, mode, HW, classifier, depth_threshold, vis_margin, hr: _Upsampled,
                     warped: _Warped, dbg, rules_base=False):
    """Stage 6: which pixels reject their history (ghost); the classifier's logits in
    mode "net" (None in mode "rule"). The rules' base: the rule's decision."""
    H, W = HW
    logits = None
    if mode == "net":
        cls_in = g.concat([hr.up, warped.color, hr.depth, hr.motion,
                           _inv_counter(g, warped.counter), warped.c_min, warped.c_max,
                           hr.depth_diff, warped.logits, hr.measure])
        dbg["dbg_cls_input"] = cls_in
        H16, W16 = _pad16(H), _pad16(W)
        cin, cout, dims = _real_input(classifier, "classifier", CLASSIFIER_CHANNELS)
        _check_static_hw("classifier", dims, (H16, W16))
        x = cls_in
        if (H16, W16) != (H, W):
            x = g.op("Pad", cls_in, g.i64([0, 0, 0, 0, 0, 0, H16 - H, W16 - W]), mode="edge")
        half = g._name("cls_logits_half")
        g.inline(classifier, "classifier", {cin: x}, {cout: half})
        full = g.op("Resize", half, "", g.const([1.0, 1.0, 2.0, 2.0]), mode="linear",
                    coordinate_transformation_mode="half_pixel")
        logits = full
        if (H16, W16) != (H, W):
            logits = g.op("Slice", full, g.i64([0, 0]), g.i64([H, W]), g.i64([2, 3]))
        dbg["dbg_logits"] = logits
    # the rule's decision: its depth test (the rules' base and rule mode decide by it alone)
    reject = g.op("Greater", hr.depth_test, g.const(float(depth_threshold)))
    if mode == "net" and not rules_base:
        # visibility leads the larger of the other two by vis_margin (0: the argmax,
        # first index on ties), lead in the kernel's and the torch twin's order; the
        # rule's depth test is a floor under the classifier (reference.md section 7)
        lead = g.sub(g.chan(logits, slice(0, 1)),
                     g.op("Max", g.chan(logits, slice(1, 2)), g.chan(logits, slice(2, 3))))
        reject = g.op("Or", g.op("GreaterOrEqual", lead, g.const(vis_margin)), reject)
    ghost = g.op("Or", reject, g.op("Not", warped.valid))
    dbg["dbg_ghost"] = g.op("Cast", ghost, to=TensorProto.FLOAT)
    return ghost, logits


def _stage7_aux(g, cap, ghost, up, warped: _Warped, dbg):
    """Stage 7: the new counter and colour min / max."""
    zero, one = g.const(0.0), g.const(1.0)
    cnt = g.where(ghost, zero, g.op("Min", g.add(warped.counter, one), g.const(cap)),
                  name="counter")
    c_min = g.where(ghost, up, g.op("Min", warped.c_min, up))
    c_max = g.where(ghost, up, g.op("Max", warped.c_max, up))
    dbg["dbg_counter"] = cnt
    return cnt, c_min, c_max


def _stage8_blend_weight(g, mode, HW, composition, hr: _Upsampled, warped: _Warped, aux,
                         logits, ghost, dbg, rules_base=False):
    """Stage 8: the current frame's blend weight, and the logits the history keeps. A
    ghost (the classifier's visibility ghosting, off screen, reset) drops its history:
    w = 1 (as the paper does; the rule weight 1/(1+0) is 1 there already)."""
    H, W = HW
    cnt, c_min, c_max = aux
    if mode == "net":
        comp_in = g.concat([hr.up, warped.blend_hist, hr.depth, hr.motion, _inv_counter(g, cnt),
                            c_min, c_max, logits])
        dbg["dbg_comp_input"] = comp_in
        ci, co, dims = _real_input(composition, "composition", COMPOSITION_CHANNELS)
        _check_static_hw("composition", dims, (H, W))
        wgt = g._name("comp_w")
        g.inline(composition, "composition", {ci: comp_in}, {co: wgt})
        if rules_base:
            # the rules' 1/(1+n) corrected in the logit domain: with s = sigmoid(z),
            # s / (s + n (1 - s)) = 1/(1 + n exp(-z)); s = 0.5 (z = 0) gives the rule's
            # weight exactly (0.5 n, 0.5 (1 + n) and their quotient round as 1/(1+n))
            wgt = g.op("Div", wgt, g.add(wgt, g.mul(cnt, g.sub(g.const(1.0), wgt))))
        wgt = g.where(ghost, g.const(1.0), wgt)
        new_logits = logits
    else:
        wgt = _inv_counter(g, cnt)
        new_logits = g.op("Expand", g.const(0.0), g.i64([1, 6, H, W]))
    wgt = g.op("Max", wgt, hr.reactive, name="w")
    dbg["dbg_w"] = wgt
    return wgt, new_logits


def _stage9_blend(g, hdr, nits, wgt, up, blend_hist, aux, new_logits):
    """Stage 9: blend, the next history, decode."""
    cnt, c_min, c_max = aux
    out = g.add(g.mul(wgt, up), g.mul(g.sub(g.const(1.0), wgt), blend_hist))
    g.concat([out, cnt, c_min, c_max, new_logits], name="history_out")
    if hdr:
        _pq_decode(g, out, nits, name="output")
    else:
        g.op("Identity", out, name="output")


def initial_history(output_hw) -> np.ndarray:
    """A zero history; it is only ever read together with reset = 1."""
    H, W = output_hw
    return np.zeros((1, HISTORY_CHANNELS, H, W), np.float32)


def initial_prev(render_hw) -> np.ndarray:
    """A zero `prev` (mode "net"); only ever read together with reset = 1."""
    h, w = render_hw
    return np.zeros((1, PREV_CHANNELS, h, w), np.float32)


class OracleUpscaler:
    """Frame-by-frame runner of the oracle graph with the state carried between calls.

    `step` takes the contract's layout (h x w x 3 colour etc.), validates it, and returns
    the linear output H x W x 3 float32 (times `exposure`).  The first step, and any
    step after `reset()`, is a reset.  In mode "net" without models, the default seeded
    weights_tools networks are built.
    """

    def __init__(self, render_size, scale=2.0, mode="rule", classifier=None, composition=None,
                 *, cap=None, depth_threshold=DEPTH_THRESHOLD, depth_slope=DEPTH_SLOPE,
                 vis_margin=VIS_MARGIN, base="paper",
                 depth_inverted=True,
                 motion_scale=(1.0, 1.0), exposure=1.0, hdr=True, nits=PQ_NITS,
                 sanitize=False, debug=False, session_options=None, providers=None):
        import onnxruntime as ort

        self.render_size = (int(render_size[0]), int(render_size[1]))
        self.scale = float(scale)
        self.output_size = output_size(*self.render_size, self.scale)
        if mode == "net" and (classifier is None or composition is None):
            from .networks import build_classifier, build_composition
            classifier = classifier or build_classifier()
            composition = composition or build_composition()
        self.mode = mode
        self.depth_inverted = bool(depth_inverted)
        self.motion_scale = motion_scale
        self.exposure = float(exposure)
        self.hdr = hdr
        self.sanitize = sanitize
        self.debug_enabled = debug
        self.model = build_frame_graph(mode, self.render_size, self.scale, classifier,
                                       composition, cap, depth_threshold=depth_threshold,
                                       depth_slope=depth_slope, vis_margin=vis_margin,
                                       hdr=hdr, nits=nits, debug=debug, base=base)
        self.session = ort.InferenceSession(self.model.SerializeToString(),
                                            sess_options=session_options,
                                            providers=providers or ["CPUExecutionProvider"])
        self._outputs = [o.name for o in self.session.get_outputs()]
        self._history = self._prev = None
        self.debug = {}
        self.last_report = {}
        self.frame_index = 0

    @property
    def state(self) -> dict:
        """{"history": [1,16,H,W] float32 or None}, in mode "net" also "prev": [1,4,h,w]
        float32 or None (reference.md s4b); assignable (e.g. to replay). A net-mode state
        assigned without "prev" carries a zero one (the previous frame's measurements
        then see depth 0 and colour 0)."""
        if self.mode == "net":
            return {"history": self._history, "prev": self._prev}
        return {"history": self._history}

    @state.setter
    def state(self, value):
        hist = value.get("history") if isinstance(value, dict) else value
        prev = value.get("prev") if isinstance(value, dict) else None
        if hist is not None:
            hist = np.asarray(hist, np.float32)
            want = (1, HISTORY_CHANNELS) + self.output_size
            if hist.shape != want:
                raise ValueError(f"state history: expected shape {want}, got {hist.shape}")
        if prev is not None:
            if self.mode != "net":
                raise ValueError("state prev: only mode 'net' carries it")
            prev = np.asarray(prev, np.float32)
            want = (1, PREV_CHANNELS) + self.render_size
            if prev.shape != want:
                raise ValueError(f"state prev: expected shape {want}, got {prev.shape}")
        self._history, self._prev = hist, prev

    def reset(self):
        self._history = self._prev = None

    def step(self, color, depth, motion, jitter, reset=False, reactive=None,
             **gbuffers) -> np.ndarray:
        frame = validate_frame(color, depth, motion, jitter, reactive,
                               render_size=self.render_size, sanitize=self.sanitize,
                               depth_inverted=self.depth_inverted)
        self.last_report = frame["sanitized"]
        feed = to_internal(frame, depth_inverted=self.depth_inverted,
                           motion_scale=self.motion_scale, exposure=self.exposure)
        first = self._history is None
        feed["history"] = initial_history(self.output_size) if first else self._history
        feed["reset"] = np.array([1.0 if (reset or first) else 0.0], np.float32)
        if self.mode == "net":
            feed["prev"] = initial_prev(self.render_size) if self._prev is None else self._prev
        res = dict(zip(self._outputs, self.session.run(self._outputs, feed)))
        self._history = res.pop("history_out")
        if self.mode == "net":
            self._prev = res.pop("prev_out")
        out = res.pop("output")
        self.debug = res
        self.frame_index += 1
        if self.exposure != 1.0:
            out = out * np.float32(self.exposure)
        return np.ascontiguousarray(out[0].transpose(1, 2, 0))


class _AlwaysReset(OracleUpscaler):
    """jbicubic's twin: the rule-mode graph reset on every frame."""

    def step(self, color, depth, motion, jitter, reset=False, reactive=None, **gbuffers):
        return super().step(color, depth, motion, jitter, True, reactive)


def twin(method, render_size, scale=2.0, **kwargs):
    """The twin of a method of this room (clss.methods.twin): the frame graph in the
    method's mode; `kwargs` as OracleUpscaler's."""
    if method == "jbicubic":
        return _AlwaysReset(render_size, scale, "rule", **kwargs)
    return OracleUpscaler(render_size, scale, "net" if method == "clss" else "rule", **kwargs)
