"""The shader MLP room (seed 004): methods "mlp" and "mlp-nofeature" (upscaler.py), the
geometry, transform and weights written once (transform.py), the whole-frame ONNX twin
(oracle.py). Its torch twin and recipe: weights_tools/methods/mlp/ (twin.py, recipe.py)."""
from .upscaler import SPECS

__all__ = ["SPECS"]
