"""The two CLSS networks the runtime runs: their ONNX graphs with seeded init and
input channel layouts (graphs.py), and their weights in safetensors files (weights.py).
Training and conversion tools (weights_tools) build on these; the runtime never imports
the tools."""
from .graphs import (CLASSIFIER_CHANNELS, CLASSIFIER_INPUTS, COMPOSITION_CHANNELS,
                     COMPOSITION_INPUTS, DEFAULT_MLP_HIDDEN, DEFAULT_WIDTHS, LOGITS,
                     build_classifier, build_composition, channel_slices, count_flops,
                     count_params, frame_flops, pad16)
from .weights import (TORCH_NAME_MAP, WeightsError, apply_weights, import_torch_state_dict,
                      load_weights, model_weights, save_weights, to_fp16, torch_to_onnx_name)

__all__ = ["CLASSIFIER_CHANNELS", "CLASSIFIER_INPUTS", "COMPOSITION_CHANNELS", "COMPOSITION_INPUTS",
           "DEFAULT_MLP_HIDDEN", "DEFAULT_WIDTHS", "LOGITS", "build_classifier", "build_composition",
           "channel_slices", "count_flops", "count_params", "frame_flops", "pad16",
           "TORCH_NAME_MAP", "WeightsError", "apply_weights", "import_torch_state_dict",
           "load_weights", "model_weights", "save_weights", "to_fp16", "torch_to_onnx_name"]
