"""The CLSS frame step: the contract (contract.py), the OpenCL pipeline (upscaler.py,
frame.py, kernels/frame.cl) and its ONNX oracle (oracle.py); formulas in reference.md."""
from .contract import FrameInputError, jitter_sequence, output_size, validate_frame

# The upscaler (pyopencl) and the oracle (onnx) load on first use: the contract alone is
# what the sample scene and clss.io need, and importing it must not pull the device in.
_LAZY = {"Upscaler": "upscaler", "load_networks": "upscaler",
         "OracleUpscaler": "oracle", "build_frame_graph": "oracle"}


def __getattr__(name):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["Upscaler", "OracleUpscaler", "build_frame_graph", "FrameInputError", "validate_frame",
           "jitter_sequence", "output_size", "load_networks"]
