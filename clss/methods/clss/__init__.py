"""The CLSS room (Guo et al. 2022, seed 002): the frame step on the device (frame.py,
frame.cl), its networks and shipped weights (upscaler.load_networks), its
whole-frame ONNX twin (oracle.py) and the written formulas (reference.md).

Three methods live here because they are one frame step in three settings:
  clss        net mode: the classifier and the per-pixel composition MLP (trained weights)
  clss-rules  rule mode: depth test, neighbourhood clamp, 1/(1+n) blend (TAAU-like)
  jbicubic    rule mode reset on every frame: the jitter-aware upsampled colour alone, the
              baseline a history has to beat (no history, no ghosts)
"""
from .upscaler import SPECS

__all__ = ["SPECS"]
