"""Linear HDR to display values: the tone mapping of every PNG clss writes and of the image
metrics (clss.metrics compares tone-mapped values)."""
from __future__ import annotations

import numpy as np


def tonemap(linear, exposure=1.0):
    """Linear HDR -> display values in [0, 1], float32: colour times `exposure`, the
    ACES filmic curve as fitted by K. Narkowicz (2015), then the sRGB OETF. Used for
    PNGs and for the image metrics. NaN and negative values become 0."""
    x = np.nan_to_num(np.asarray(linear, np.float32) * np.float32(exposure), nan=0.0,
                      posinf=1e4, neginf=0.0)
    x = np.maximum(x, 0)
    y = np.clip((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0, 1)
    return np.where(y <= 0.0031308, 12.92 * y,
                    1.055 * np.power(y, 1 / 2.4) - 0.055).astype(np.float32)


def to_uint8(linear_rgb, exposure=1.0):
    return (tonemap(linear_rgb, exposure) * 255 + 0.5).astype(np.uint8)
