"""The bicubic room: the plain bicubic baseline (upscaler.py) and its whole-frame ONNX twin
(oracle.py)."""
from .upscaler import SPECS

__all__ = ["SPECS"]
