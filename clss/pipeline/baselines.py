"""The spatial baselines `clss demo` and `python -m weights_tools eval` compare the frame
step against: a plain bicubic of each render frame (what a spatial upscaler without
history gives) and a nearest-neighbour enlargement (how the input looks at output size)."""
from __future__ import annotations

import numpy as np


class Bicubic:
    """Plain bicubic (Keys a = -0.75, half-pixel centres) of one frame, on the device,
    in the PQ domain so that it rings like the pipeline's colour would."""

    def __init__(self, dev, out_hw):
        self.dev, self.out_hw = dev, out_hw

    def __call__(self, color):
        from ..ops.resize import resize
        from ..pipeline.contract import pq_decode, pq_encode
        x = self.dev.to_device(pq_encode(color).transpose(2, 0, 1)[None])
        y = resize(self.dev, "fp32", x, out_hw=self.out_hw, mode="cubic")
        return pq_decode(np.clip(y.get()[0].transpose(1, 2, 0), 0, 1))


def nearest(img, H, W):
    """Render-resolution image enlarged to H x W by nearest neighbour (any scale)."""
    h, w = img.shape[:2]
    iy = np.minimum(((np.arange(H) + 0.5) * h / H).astype(np.int64), h - 1)
    ix = np.minimum(((np.arange(W) + 0.5) * w / W).astype(np.int64), w - 1)
    return img[iy][:, ix]
