"""The shader MLP room (seed 004): methods "mlp" and "mlp-nofeature" (upscaler.py), the
geometry, transform and weights written once (transform.py), the whole-frame ONNX twin
(oracle.py). Its torch twin and recipe: weights_tools/mlp_torch.py, mlp_train.py."""
from .upscaler import SPECS

__all__ = ["SPECS"]
