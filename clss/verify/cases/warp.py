"""Conformance cases of GridSample and the motion warp (clss/ops/warp.py, kernels/warp.cl):
ONNX twins and seeded cases, `cases(level)` for `clss verify` and the tests."""
from __future__ import annotations

import numpy as np
from onnx import helper

from ...ops.base import rng
from ...ops.warp import MODES, PADDINGS, _OPSET20_NAME, _mode, grid_sample, warp
from ...tolerance import DEFAULT_TOL, Tolerance
from ..case import Case
from ..twin import make_model, node_model, run_ort


def twin_grid_sample(x, grid, mode, padding, align_corners, cubic_channels=0, opset=16):
    """GridSample node (opset 16 names or opset 20 names); with cubic_channels, two
    GridSamples on channel slices + Concat."""
    name = (lambda m: m) if opset < 20 else (lambda m: _OPSET20_NAME[_canon(m)])
    c = x.shape[1]
    if not cubic_channels or _canon(mode) == "bicubic" or cubic_channels >= c:
        m = "bicubic" if cubic_channels >= c > 0 else mode
        return node_model("GridSample", {"x": x, "grid": grid}, opset=opset, mode=name(m),
                          padding_mode=padding, align_corners=int(align_corners))
    return make_model(_split_nodes("grid", mode, padding, align_corners, cubic_channels, name),
                      {"x": x, "grid": grid}, ["y0"],
                      initializers=_split_inits(c, cubic_channels), opset=opset)


def twin_warp(x, motion, mode, padding, motion_scale=(1.0, 1.0), scale=1.0, cubic_channels=0):
    """GridSample(align_corners=0) of base + Transpose(motion) * k: what ``warp`` computes."""
    n, c, hi, wi = x.shape
    ho, wo = motion.shape[2:]
    kx, ky = (float(s) * float(scale) for s in motion_scale)
    gx = (2.0 * np.arange(wo) + 1.0) / wo - 1.0
    gy = (2.0 * np.arange(ho) + 1.0) / ho - 1.0
    base = np.stack(np.broadcast_arrays(gx[None, :], gy[:, None]), -1)[None].astype(np.float32)
    k = np.array([2.0 * kx / wi, 2.0 * ky / hi], np.float32)
    nodes = [helper.make_node("Transpose", ["motion"], ["m_nhwc"], perm=[0, 2, 3, 1]),
             helper.make_node("Mul", ["m_nhwc", "k"], ["offset"]),
             helper.make_node("Add", ["base", "offset"], ["grid"])]
    inits = {"base": base, "k": k}
    if cubic_channels and _canon(mode) != "bicubic" and cubic_channels < c:
        nodes += _split_nodes("grid", mode, padding, False, cubic_channels, lambda m: m)
        inits.update(_split_inits(c, cubic_channels))
    else:
        m = "bicubic" if cubic_channels >= c > 0 else mode
        nodes.append(helper.make_node("GridSample", ["x", "grid"], ["y0"], mode=m, padding_mode=padding,
                                      align_corners=0))
    return make_model(nodes, {"x": x, "motion": motion}, ["y0"], initializers=inits, opset=16)


def _canon(mode):
    return MODES[_mode(mode)]


def _split_nodes(grid, mode, padding, align_corners, k, name):
    return [helper.make_node("Slice", ["x", "s0", "s1", "ax"], ["x_cubic"]),
            helper.make_node("Slice", ["x", "s1", "s2", "ax"], ["x_rest"]),
            helper.make_node("GridSample", ["x_cubic", grid], ["y_cubic"], mode=name("bicubic"),
                             padding_mode=padding, align_corners=int(align_corners)),
            helper.make_node("GridSample", ["x_rest", grid], ["y_rest"], mode=name(mode),
                             padding_mode=padding, align_corners=int(align_corners)),
            helper.make_node("Concat", ["y_cubic", "y_rest"], ["y0"], axis=1)]


def _split_inits(c, k):
    return {"s0": np.array([0], np.int64), "s1": np.array([k], np.int64),
            "s2": np.array([c], np.int64), "ax": np.array([1], np.int64)}


# --- cases ----------------------------------------------------------------------

def run_grid_sample(mode, padding, align_corners, cubic_channels=0):
    """Case.run: the grid goes up as float32 in every precision."""
    def run(dev, prec, inputs):
        x = dev.to_device(inputs["x"], prec)
        grid = dev.to_device(inputs["grid"].astype(np.float32), "fp32")
        return [dev.to_host(grid_sample(dev, prec, x, grid, mode, padding, align_corners,
                                        cubic_channels=cubic_channels))]
    return run


def run_warp(mode, padding, motion_scale=(1.0, 1.0), scale=1.0, cubic_channels=0):
    def run(dev, prec, inputs):
        x = dev.to_device(inputs["x"], prec)
        m = dev.to_device(inputs["motion"], prec)
        return [dev.to_host(warp(dev, prec, x, m, motion_scale=motion_scale, scale=scale, mode=mode,
                                 padding=padding, cubic_channels=cubic_channels))]
    return run


def random_grid(g: np.random.Generator, n, ho, wo, reach=1.3) -> np.ndarray:
    """Normalised positions up to ``reach`` (> 1 goes off-image), plus exact hits on the
    borders and on the half-pixel ties that nearest mode must round to even."""
    grid = g.uniform(-reach, reach, (n, ho, wo, 2)).astype(np.float32)
    flat = grid.reshape(-1)
    special = np.array([-1, 1, 0, -reach, reach], np.float32)
    pick = g.random(flat.shape) < 0.1
    flat[pick] = g.choice(special, int(pick.sum()))
    return grid


def _tol_coords(x, motion, twin, k, hi, wi):
    """Positions of a few pixels in float32 carry rounding of ~2^-24 of their magnitude,
    in the kernel (pixels) and in the twin (normalised grid |g| <= 1 + 2|m|k/W, then
    scaled by W/2): about 2^-23 (|g| + 1) max(H, W) pixels between the two. The output
    differs by that times the data's slope (~2 max|x| per axis); as a bound relative to
    max|ref| it is added to the default atol, and grows where most samples fall off-image."""
    gmax = 1.0 + 2.0 * float(np.abs(motion).max(initial=0.0)) * max(abs(k[0]) / wi, abs(k[1]) / hi)
    err_px = 2.0 ** -23 * (gmax + 1.0) * max(hi, wi)
    ref = run_ort(twin, {"x": x, "motion": motion})[0]
    scale = max(float(np.abs(ref).max(initial=0.0)), 1e-30)
    extra = 4.0 * err_px * float(np.abs(x).max(initial=0.0)) / scale
    return {p: Tolerance(t.atol + extra, t.rtol) for p, t in DEFAULT_TOL.items()}


def grid_case(n, c, hi, wi, ho, wo, mode, padding, align_corners, *, opset=16, reach=1.3,
              cubic_channels=0, ties=False):
    g = rng("grid_sample", n, c, hi, wi, ho, wo, mode, padding, align_corners, reach, cubic_channels, ties)
    x = g.standard_normal((n, c, hi, wi)).astype(np.float32)
    grid = random_grid(g, n, ho, wo, reach)
    if ties:
        # Positions exactly on half-pixel ties (and integer pixels) in pixel-index space.
        steps = g.integers(-4, 2 * max(hi, wi) + 4, (n, ho, wo, 2)) / 2.0
        size = np.array([wi, hi], np.float64)
        grid = (steps / (size - 1) * 2 - 1 if align_corners and min(hi, wi) > 1
                else (2 * steps + 1) / size - 1).astype(np.float32)
    name = "+".join(filter(None, [f"cubic{cubic_channels}" if cubic_channels else "", mode]))
    variant = (f"{name} {padding} ac{int(align_corners)}{' ties' if ties else ''} "
               f"{n}x{c}x{hi}x{wi}->{ho}x{wo}{' opset20' if opset >= 20 else ''}")
    return Case("grid_sample", variant, {"x": x, "grid": grid},
                twin_grid_sample(x, grid, mode, padding, align_corners, cubic_channels, opset),
                run_grid_sample(mode, padding, align_corners, cubic_channels),
                exact=(mode == "nearest" and not cubic_channels), no_round=("grid",))


def motion_case(n, c, hi, wi, ho, wo, mode, padding, *, reach=3.0, motion_scale=(1.0, 1.0),
                scale=1.0, cubic_channels=0):
    g = rng("warp", n, c, hi, wi, ho, wo, mode, padding, reach, motion_scale, scale, cubic_channels)
    x = g.standard_normal((n, c, hi, wi)).astype(np.float32)
    motion = g.uniform(-reach, reach, (n, 2, ho, wo)).astype(np.float16).astype(np.float32)
    if _canon(mode) == "nearest" and not cubic_channels:
        motion = _away_from_ties(motion, hi, wi, ho, wo, motion_scale, scale)
    name = "+".join(filter(None, [f"cubic{cubic_channels}" if cubic_channels else "", mode]))
    variant = (f"{name} {padding} {n}x{c}x{hi}x{wi}->{ho}x{wo} ms{tuple(motion_scale)} s{scale}")
    twin = twin_warp(x, motion, mode, padding, motion_scale, scale, cubic_channels)
    k = (motion_scale[0] * scale, motion_scale[1] * scale)
    return Case("warp", variant, {"x": x, "motion": motion}, twin,
                run_warp(mode, padding, motion_scale, scale, cubic_channels),
                exact=(_canon(mode) == "nearest" and not cubic_channels),
                tol=_tol_coords(x, motion, twin, k, hi, wi))


def _away_from_ties(motion, hi, wi, ho, wo, motion_scale, scale):
    """Nudge motions whose source lands within 1e-3 pixel of a rounding tie: there the
    twin's normalised grid and the kernel's pixel arithmetic may round apart."""
    m = motion.astype(np.float64)
    for axis, (size_in, size_out, ms) in enumerate(((wi, wo, motion_scale[0]), (hi, ho, motion_scale[1]))):
        idx = np.arange(size_out)
        base = (idx + 0.5) * size_in / size_out - 0.5
        base = base[None, :] if axis == 0 else base[:, None]
        src = base + m[:, axis] * ms * scale
        frac = src - np.floor(src)
        near = np.abs(frac - 0.5) < 1e-3
        m[:, axis] = np.where(near, m[:, axis] + 0.125 / (ms * scale), m[:, axis])
    return m.astype(np.float16).astype(np.float32)


def cases(level: str = "quick") -> list[Case]:
    out = []
    if level == "tiny":
        # Every build variant and both align_corners once, < 2000 output elements each (oclgrind).
        for mode in MODES:
            for padding in PADDINGS:
                for ac in (0, 1):
                    out.append(grid_case(1, 2, 5, 7, 3, 4, mode, padding, ac, reach=1.4))
        out.append(grid_case(1, 1, 1, 1, 3, 4, "bicubic", "reflection", 1, reach=2.0))
        out.append(motion_case(1, 5, 5, 7, 5, 7, "bilinear", "border", cubic_channels=3))
        out.append(motion_case(2, 2, 4, 6, 8, 12, "bicubic", "zeros", scale=2.0))
        return out
    # quick: every mode and padding once, alternating align_corners and opset spellings,
    # plus the pipeline's forms.
    for i, mode in enumerate(MODES):
        for j, padding in enumerate(PADDINGS):
            ac = (i + j) % 2
            out.append(grid_case(2, 3, 7, 13, 9, 11, mode, padding, ac, opset=16 + 4 * ((i + j) % 2)))
    out.append(motion_case(1, 16, 17, 23, 17, 23, "bilinear", "border", cubic_channels=3))
    out.append(motion_case(1, 3, 9, 12, 18, 24, "bicubic", "zeros", scale=2.0))
    out.append(motion_case(1, 2, 7, 13, 7, 13, "nearest", "border"))
    if level != "full":
        return out
    # full: odd shapes, channel counts 1-23, batch 2, both align_corners and opset
    # spellings for every variant, grids far off-image, rounding ties, the motion warp's
    # unit conversions. The launch grid (output size x batch x channel blocks) is kept to
    # 13x7x2 and 27x31x2: PoCL compiles every variant again per work-group size it meets.
    for mode in MODES:
        for padding in PADDINGS:
            for ac in (0, 1):
                out.append(grid_case(2, 5, 31, 27, 13, 7, mode, padding, ac, reach=2.5))
                out.append(grid_case(1, 23, 7, 13, 13, 7, mode, padding, ac, reach=1.05, opset=20))
                out.append(grid_case(2, 1, 1, 1, 13, 7, mode, padding, ac, reach=3.0))
                if mode == "nearest":
                    out.append(grid_case(2, 3, 7, 13, 13, 7, mode, padding, ac, ties=True))
    for c in (1, 3, 5, 16, 23):
        out.append(grid_case(2 if c <= 16 else 1, c, 11, 9, 13, 7, "bicubic", "border", 0))
    out.append(grid_case(2, 16, 13, 17, 13, 7, "bilinear", "zeros", 0, cubic_channels=3))
    out.append(grid_case(1, 23, 9, 9, 13, 7, "nearest", "reflection", 1, cubic_channels=3, opset=20))
    for mode in MODES:
        for padding in PADDINGS:
            out.append(motion_case(2, 3, 31, 27, 31, 27, mode, padding, reach=5.0))
    out.append(motion_case(2, 16, 31, 27, 31, 27, "bilinear", "border", cubic_channels=3, reach=6.0))
    out.append(motion_case(1, 23, 16, 14, 31, 27, "bilinear", "zeros", cubic_channels=3))
    out.append(motion_case(2, 5, 31, 27, 31, 27, "bicubic", "border", scale=2.0))
    out.append(motion_case(2, 3, 12, 16, 31, 27, "bilinear", "zeros", motion_scale=(16.0, 12.0), reach=0.2))
    out.append(motion_case(2, 3, 31, 27, 31, 27, "bicubic", "border", motion_scale=(-1.0, -1.0)))
    out.append(motion_case(2, 1, 1, 1, 31, 27, "bicubic", "zeros", reach=0.7))
    out.append(motion_case(1, 23, 9, 7, 31, 27, "nearest", "zeros", reach=4.0))
    return out
