"""The NSRR room (Xiao et al. 2020): the frame step (frame.py, nsrr.cl), its
networks (networks.py), the upscaler (upscaler.py) and its whole-frame ONNX twin
(oracle.py). docs/methods/nsrr.md describes the method and its measured results."""
from .upscaler import SPECS

__all__ = ["SPECS"]
