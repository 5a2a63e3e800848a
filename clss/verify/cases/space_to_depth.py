"""Conformance cases of SpaceToDepth / DepthToSpace (clss/ops/space_to_depth.py,
kernels/space_to_depth.cl): ONNX twins and seeded cases, `cases(level)` for `clss verify`
and the tests."""
from __future__ import annotations

import numpy as np
from onnx import helper

from ...ops.base import rng
from ...ops.space_to_depth import MODES, depth_to_space, space_to_depth
from ..case import Case, host_call
from ..twin import make_model, node_model


def twin(direction: str, x: np.ndarray, block: int, mode: str):
    """ONNX twin. SpaceToDepth has no CRD mode in ONNX: its twin is the
    PixelUnshuffle pattern Reshape -> Transpose -> Reshape."""
    if direction == "d2s":
        return node_model("DepthToSpace", {"x": x}, blocksize=block, mode=mode)
    if mode == "DCR":
        return node_model("SpaceToDepth", {"x": x}, blocksize=block)
    n, c, hh, ww = x.shape
    h, w = hh // block, ww // block
    shape1 = np.array([n, c, h, block, w, block], np.int64)
    shape2 = np.array([n, c * block * block, h, w], np.int64)
    nodes = [helper.make_node("Reshape", ["x", "s1"], ["t1"]),
             helper.make_node("Transpose", ["t1"], ["t2"], perm=[0, 1, 3, 5, 2, 4]),
             helper.make_node("Reshape", ["t2", "s2"], ["y0"])]
    return make_model(nodes, {"x": x}, ["y0"], initializers={"s1": shape1, "s2": shape2})


def cases(level: str = "quick") -> list[Case]:
    shapes = [(1, 3, 2, 2, 2), (1, 23, 8, 12, 2), (2, 5, 7, 13, 3)]
    if level == "tiny":
        shapes = [shapes[0], shapes[2]]
    elif level == "full":
        shapes += [(1, 1, 1, 1, 1), (1, 7, 31, 27, 1), (2, 6, 10, 14, 4), (1, 17, 62, 54, 2)]
    out = []
    for n, c, h, w, b in shapes:
        for mode in MODES:
            g = rng("s2d", n, c, h, w, b, mode)
            x = g.standard_normal((n, c, h * b, w * b)).astype(np.float32)
            out.append(Case("space_to_depth", f"{mode} b{b} {n}x{c}x{h * b}x{w * b}", {"x": x},
                            twin("s2d", x, b, mode),
                            host_call(lambda dev, p, x, b=b, m=mode: space_to_depth(dev, p, x, b, m)),
                            exact=True))
            y = g.standard_normal((n, c * b * b, h, w)).astype(np.float32)
            out.append(Case("depth_to_space", f"{mode} b{b} {n}x{c * b * b}x{h}x{w}", {"x": y},
                            twin("d2s", y, b, mode),
                            host_call(lambda dev, p, x, b=b, m=mode: depth_to_space(dev, p, x, b, m)),
                            exact=True))
    return out
