"""The tools above the runtime: data generation (scenegen, blender/), evaluation, and each
method's training, one folder per method (methods/<name>/: its torch twin and recipe) on
one loop (trainloop). The CLSS networks themselves (ONNX graphs with seeded weights, torch
name import) live in the CLSS room (clss.methods.clss.networks) and the safetensors I/O in
clss.networks; both are re-exported here for the tools' users."""
from clss.networks import (WeightsError, apply_weights, load_weights, model_weights, save_weights,
                           to_fp16)
from clss.methods.clss.networks import (CLASSIFIER_CHANNELS, CLASSIFIER_INPUTS,
                                        COMPOSITION_CHANNELS, COMPOSITION_INPUTS,
                                        DEFAULT_MLP_HIDDEN, DEFAULT_WIDTHS, LOGITS,
                                        TORCH_NAME_MAP, build_classifier, build_composition,
                                        channel_slices, count_flops, count_params, frame_flops,
                                        import_torch_state_dict, torch_to_onnx_name)
