"""What every method shares: the frame contract (contract.py: conventions, validation,
jitter, PQ, G-buffers), the method description and the base of every upscaler
(method.py). The methods themselves are rooms under clss/methods/."""
from .contract import FrameInputError, jitter_sequence, output_size, validate_frame

__all__ = ["FrameInputError", "validate_frame", "jitter_sequence", "output_size"]
