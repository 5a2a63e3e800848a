"""Build the CLSS networks as ONNX with seeded weights; fp16, safetensors, torch import."""
from .networks import (CLASSIFIER_INPUTS, COMPOSITION_INPUTS, CLASSIFIER_CHANNELS,
                       COMPOSITION_CHANNELS, LOGITS, DEFAULT_WIDTHS, DEFAULT_MLP_HIDDEN,
                       build_classifier, build_composition, channel_slices, count_flops,
                       count_params, frame_flops)
from .weights import (TORCH_NAME_MAP, WeightsError, apply_weights, import_torch_state_dict,
                      load_weights, model_weights, save_weights, to_fp16, torch_to_onnx_name)
