"""Conformance cases of Resize (and the legacy Upsample) (clss/ops/resize.py,
kernels/resize.cl): ONNX twins and seeded cases, `cases(level)` for `clss verify` and the
tests."""
from __future__ import annotations

import numpy as np

from ...ops.base import rng
from ...ops.resize import COORDS, MODES, NEAREST_MODES, POLICIES, _legacy, resize
from ..case import Case, host_call
from ..twin import node_model


def twin(x: np.ndarray, *, scales=None, sizes=None, roi=None, opset: int = 19, **attrs):
    """One Resize node with roi/scales/sizes as initializers (full rank, NCHW)."""
    consts = {}
    if roi is not None:
        consts["roi"] = np.asarray(roi, np.float32)
    if scales is not None:
        consts["scales"] = np.asarray(scales, np.float32)
    if sizes is not None:
        consts["sizes"] = np.asarray(sizes, np.int64)
    if opset < 11:
        return node_model("Resize", {"x": x, "scales": consts["scales"]}, opset=opset,
                          initializers=consts, **attrs)
    ins = {"x": x, "roi": consts.get("roi"), "scales": consts.get("scales"), "sizes": consts.get("sizes")}
    if ins["sizes"] is None:
        ins.pop("sizes")
    return node_model("Resize", ins, opset=opset, initializers=consts, **attrs)


def case(n, c, h, w, *, mode="linear", coord="half_pixel", nearest="round_prefer_floor", scales=None,
         sizes=None, cubic_a=-0.75, exclude=False, antialias=False, roi=None, extrap=0.0,
         policy="stretch", legacy=False, tag="") -> Case:
    """A Resize case over H, W: scales / sizes are (H, W) pairs; roi (h0, w0, h1, w1)."""
    g = rng("resize", n, c, h, w, mode, coord, nearest, scales, sizes, cubic_a, exclude, antialias, roi,
            policy, legacy)
    x = g.standard_normal((n, c, h, w)).astype(np.float32)
    full_sc = None if scales is None else [1, 1, *scales]
    full_sz = None if sizes is None else [n, c, *sizes]
    attrs = {}
    if legacy:
        model = twin(x, scales=full_sc, opset=10, mode=mode)
        run = host_call(lambda dev, p, x: _legacy(dev, p, {"mode": mode}, x, full_sc))
    else:
        attrs = dict(mode=mode, coordinate_transformation_mode=coord)
        if mode == "nearest":
            attrs["nearest_mode"] = nearest
        if mode == "cubic":
            attrs["cubic_coeff_a"] = cubic_a
        if exclude:
            attrs["exclude_outside"] = 1
        if antialias:
            attrs["antialias"] = 1
        if coord == "tf_crop_and_resize":
            attrs["extrapolation_value"] = extrap
        if policy != "stretch":
            attrs["keep_aspect_ratio_policy"] = policy
        full_roi = None if roi is None else [0, 0, roi[0], roi[1], 1, 1, roi[2], roi[3]]
        if policy != "stretch":  # the policy spans every listed axis: list H and W only
            attrs["axes"] = [2, 3]
            full_sz = list(sizes)
        model = twin(x, scales=full_sc, sizes=full_sz, roi=full_roi, **attrs)

        def fn(dev, p, x):
            return resize(dev, p, x, out_hw=sizes, scales=scales, mode=mode, coord=coord,
                          nearest_mode=nearest, cubic_a=cubic_a, exclude_outside=exclude,
                          antialias=antialias, roi=roi, extrapolation_value=extrap,
                          keep_aspect_ratio_policy=policy)
        run = host_call(fn)
    how = (f"s{scales[0]:g}x{scales[1]:g}" if scales is not None else f"to{sizes[0]}x{sizes[1]}")
    bits = [mode, "legacy" if legacy else coord]
    if mode == "nearest" and not legacy:
        bits.append(nearest)
    if mode == "cubic" and cubic_a != -0.75:
        bits.append(f"a{cubic_a:g}")
    bits += [b for b, on in (("exclude", exclude), ("antialias", antialias)) if on]
    if policy != "stretch":
        bits.append(policy)
    variant = f"{' '.join(bits)} {how} {n}x{c}x{h}x{w}{' ' + tag if tag else ''}"
    return Case("resize", variant, {"x": x}, model, run, exact=(mode == "nearest"))


def cases(level: str = "quick") -> list[Case]:
    # Each define value at least once, on shapes small enough for oclgrind.
    tiny = [
        case(1, 3, 5, 7, mode="nearest", scales=(2, 2)),
        case(1, 5, 7, 6, mode="nearest", coord="asymmetric", nearest="round_prefer_ceil", sizes=(4, 3)),
        case(1, 1, 4, 5, mode="nearest", coord="align_corners", nearest="floor", sizes=(9, 11)),
        case(1, 2, 6, 5, mode="nearest", coord="pytorch_half_pixel", nearest="ceil", scales=(1.5, 0.6)),
        case(1, 2, 5, 6, mode="nearest", coord="tf_crop_and_resize", sizes=(7, 4), roi=(0.2, -0.1, 0.9, 1.3),
             extrap=2.5),
        case(1, 3, 4, 6, mode="nearest", scales=(2, 0.5), legacy=True),
        case(1, 3, 5, 7, mode="linear", scales=(2, 3)),
        case(1, 2, 7, 6, mode="linear", coord="half_pixel_symmetric", scales=(0.6, 1.5)),
        case(1, 5, 4, 5, mode="linear", coord="align_corners", sizes=(7, 9)),
        case(1, 1, 5, 4, mode="linear", coord="tf_crop_and_resize", sizes=(6, 5), roi=(0.1, 0.4, 1.2, 0.7),
             extrap=-1.0),
        case(1, 3, 5, 7, mode="cubic", scales=(2, 1.5)),
        case(1, 2, 6, 6, mode="cubic", coord="asymmetric", cubic_a=-0.5, exclude=True, scales=(0.6, 1.5)),
        case(1, 2, 8, 7, mode="linear", antialias=True, scales=(0.5, 0.6)),
        case(1, 2, 8, 7, mode="cubic", antialias=True, exclude=True, sizes=(3, 5)),
    ]
    if level == "tiny":
        return tiny
    quick = [
        case(2, 5, 7, 13, mode="nearest", scales=(2, 2)),
        case(1, 3, 31, 27, mode="linear", scales=(2, 2)),
        case(1, 23, 16, 20, mode="linear", sizes=(8, 10)),
        case(1, 3, 13, 7, mode="cubic", scales=(2, 2)),
        case(1, 5, 16, 16, mode="linear", antialias=True, scales=(0.5, 0.5)),
    ]
    if level == "quick":
        return quick
    full = tiny + quick
    # Shapes x scales x modes on the default half_pixel transform.
    shapes = [(1, 1, 1, 1), (1, 3, 7, 13), (1, 5, 31, 27), (2, 23, 7, 13), (1, 1, 13, 7)]
    for (n, c, h, w), sc in zip(shapes * 3, [(2, 2), (1.5, 1.5), (3, 3), (4, 4), (0.5, 0.5), (0.6, 0.6),
                                             (3, 1.5), (0.6, 2), (2, 0.5), (4, 0.6), (1, 2), (1.5, 4),
                                             (2, 3), (0.5, 1), (3, 3)]):
        for mode in MODES:
            full.append(case(n, c, h, w, mode=mode, scales=sc))
    for (n, c, h, w), sz in [((1, 3, 7, 13), (14, 26)), ((1, 5, 31, 27), (19, 11)), ((2, 23, 7, 13), (10, 20)),
                             ((1, 1, 1, 1), (3, 2)), ((1, 3, 13, 7), (1, 1))]:
        for mode in MODES:
            full.append(case(n, c, h, w, mode=mode, sizes=sz))
    # Every coordinate transform x mode, up and down.
    for coord in COORDS:
        for mode in MODES:
            for sc, sz in (((1.5, 2.5), None), (None, (4, 6)), ((0.6, 0.5), None)):
                roi = (0.1, -0.2, 0.8, 1.1) if coord == "tf_crop_and_resize" else None
                full.append(case(1, 3, 7, 9, mode=mode, coord=coord, scales=sc, sizes=sz, roi=roi, extrap=0.5))
    for nm in NEAREST_MODES[:4]:
        for coord in ("half_pixel", "asymmetric", "align_corners"):
            full.append(case(1, 3, 7, 13, mode="nearest", coord=coord, nearest=nm, scales=(1.5, 3)))
            full.append(case(1, 3, 7, 13, mode="nearest", coord=coord, nearest=nm, sizes=(5, 8)))
    for a, excl in ((-0.5, True), (-0.75, True), (-0.5, False)):
        for sc in ((2, 1.5), (0.6, 0.5)):
            full.append(case(1, 5, 9, 11, mode="cubic", cubic_a=a, exclude=excl, scales=sc))
    for mode in ("linear", "cubic"):
        for sc, excl in (((0.5, 0.6), False), ((0.3, 0.25), False), ((0.6, 2), True)):
            full.append(case(1, 3, 17, 19, mode=mode, antialias=True, exclude=excl, scales=sc))
    for policy in POLICIES[1:]:
        for sz in ((5, 20), (14, 6)):
            full.append(case(1, 3, 7, 13, mode="nearest", sizes=sz, policy=policy))
            full.append(case(1, 3, 7, 13, mode="linear", sizes=sz, policy=policy))
    for mode in ("nearest", "linear"):
        for sc in ((2, 3), (1.5, 2.5), (0.5, 0.6)):
            full.append(case(1, 3, 7, 13, mode=mode, scales=sc, legacy=True))
    return full
