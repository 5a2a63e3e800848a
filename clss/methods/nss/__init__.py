"""The NSS room (Arm Neural Super Sampling, 2025): the frame step (frame.py, nss.cl), its
network (networks.py), the upscaler (upscaler.py) and its whole-frame ONNX twin
(oracle.py). docs/methods/nss.md describes the method and its measured results."""
from .upscaler import SPECS

__all__ = ["SPECS"]
