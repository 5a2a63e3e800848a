"""`Frame`: one frame of a sequence, as `read_sequence` gives it and the built-in scene
(clss.demo.scene) renders it."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..pipeline.contract import GBUFFERS


@dataclass
class Frame:
    """One rendered frame; ``reference`` is None when no reference was rendered.
    ``gbuffers``: the optional inputs of clss.pipeline.contract.GBUFFERS the frame
    carries, {name: float32 array} (albedo, normal: h x w x 3; albedo_hr, normal_hr:
    H x W x 3; depth_hr: H x W); empty when none. ``frame["albedo"]`` reads one of them
    (None when absent), so code that indexes frames by key reaches them too."""
    index: int
    color: np.ndarray            # h x w x 3 float32, linear HDR
    depth: np.ndarray            # h x w float32, reversed-Z
    motion: np.ndarray           # h x w x 2 float32, render pixels, prev = p + motion
    jitter: tuple                # (jx, jy) in render pixels
    reset: bool = False
    reference: np.ndarray | None = None   # H x W x 3 float32
    meta: dict = field(default_factory=dict)
    gbuffers: dict = field(default_factory=dict)

    def __getitem__(self, key):
        if key in GBUFFERS:
            return self.gbuffers.get(key)
        return getattr(self, key)
