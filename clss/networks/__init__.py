"""What every method's networks share: their weights as safetensors files (weights.py:
save, load with checks, apply to an ONNX graph, fp16; a method's file of weights plus its
config). The networks themselves are their methods' (clss/methods/<name>/networks.py).
Training and conversion tools (weights_tools) build on these; the runtime never imports
the tools."""
from .weights import (WeightsError, apply_weights, load_weights, model_weights, save_weights,
                      to_fp16)

__all__ = ["WeightsError", "apply_weights", "load_weights", "model_weights", "save_weights",
           "to_fp16"]
