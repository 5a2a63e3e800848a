"""The NSRD room (Li et al. 2024): the frame step (frame.py, nsrd.cl), its network
(networks.py), the upscaler (upscaler.py) and its whole-frame ONNX twin (oracle.py).
docs/methods/nsrd.md describes the method and its measured results."""
from .upscaler import SPECS

__all__ = ["SPECS"]
