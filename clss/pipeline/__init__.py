"""The CLSS frame step: the contract (contract.py), the OpenCL pipeline (upscaler.py,
frame.py, kernels/frame.cl) and its ONNX oracle (oracle.py); formulas in reference.md."""
from .contract import FrameInputError, jitter_sequence, output_size, validate_frame
from .oracle import OracleUpscaler, build_frame_graph
from .upscaler import Upscaler, load_networks

__all__ = ["Upscaler", "OracleUpscaler", "build_frame_graph", "FrameInputError", "validate_frame",
           "jitter_sequence", "output_size", "load_networks"]
