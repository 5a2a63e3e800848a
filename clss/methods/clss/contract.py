"""The CLSS frame step's own contract: its constants, once, for the OpenCL path (frame.py,
upscaler.py), the ONNX oracle (oracle.py) and the torch twin (weights_tools/methods/clss/twin.py).
What every method shares (the input contract, the PQ transfer, the jitter) is
clss.pipeline.contract."""
from __future__ import annotations

import numpy as np

# The history clip (reference.md s9): the warped history is pulled towards the current
# upsampled colour `up` along the segment up -> history until it lies inside the clamp
# box widened by this on every side (PQ code values: 2 steps of 10-bit PQ, invisible), all
# three channels by the same fraction t. The widening keeps t continuous (a channel whose
# difference d to `up` is below eps cannot limit it) and bounds how much the shared t
# amplifies rounding: the limiting channel sets t = lim / d for all three, so the others
# move by d_other / d times an error in lim. With an unwidened box and a 1e-6 cut-off,
# the vector and scalar exp2/log2 of the PQ encode (last-bit differences) came out of the
# net-mode clip 1.3e-4 apart (4e-5 without the clip); widened by 2/1023, 4e-5 again.
RULE_CLIP_EPS = 2.0 / 1023.0
# The clamp box (reference.md s9) is the 3x3 neighbourhood's min/max narrowed to its mean
# +- CLIP_GAMMA standard deviations (variance clipping, Salvi 2016): thin bright features
# widen a min/max box so far that it keeps their ghosts. Rule mode, cap 4, mean over the
# 2 Blender validation and 16 held-out generated sequences (PSNR / tPSNR, dB): min/max
# 25.87 / 24.09, gamma 0.75 26.11 / 24.14, 1.0 26.07 / 24.18, 1.25 26.01 / 24.16. 1.25
# keeps a static textured scene converging (tests/test_method_clss_oracle.py: +2 dB in 8
# frames; 0.75 and 1.0 clip too much of a right history there).
CLIP_GAMMA = 1.25


# Auto-reactive (reference.md s4, issue 23): where the dilated motion of the 3x3 render
# neighbourhood diverges (sum over x and y of the largest difference to the centre, render
# pixels), the surfaces there move apart (parallax, a moving edge, sub-pixel foliage over
# sky) and a warped history mixes them; the blend weight is raised to at least
# clip((divergence - AUTO_REACTIVE_LO) * AUTO_REACTIVE_SLOPE, 0, AUTO_REACTIVE_MAX), as the
# caller's reactive mask would (FSR2 derives a reactive mask and kills locks on motion
# divergence alike). Measured in rule mode (PSNR dB, foliage / 8 held-out / interior):
# none 25.32 / 25.62 / 27.28; (lo, slope, max) = (0.5, 1, 1) 25.43 / 25.66 / 27.60;
# (0.1, 4, 1) 26.03 / 25.46 / 27.69; (0.1, 4, 0.5) 25.78 / 25.75 / 27.56;
# (0.05, 8, 0.5) 26.15 / 25.69 / 27.64.
AUTO_REACTIVE_LO = 0.05
AUTO_REACTIVE_SLOPE = 8.0
AUTO_REACTIVE_MAX = 0.5

# The modes of the frame step (methods "clss-rules" and "clss").
MODES = ("rule", "net")
HISTORY_CHANNELS = 16
# Channel slices of the history tensor.
H_COLOR, H_COUNTER, H_MIN, H_MAX, H_LOGITS = (slice(0, 3), slice(3, 4), slice(4, 7),
                                               slice(7, 10), slice(10, 16))
DEFAULT_CAP = {"rule": 4, "net": 32}
# Relative view-depth jump that rejects history in rule mode.  Grazing surfaces and the
# horizon jump by several % per pixel; on clss.demo.scene (136x240 -> 272x480, cap 4) 0.05
# rejected 8 % of pixels (33.06 dB), 0.1 6 % (33.23 dB), 0.2 4 % (33.30 dB).
DEPTH_THRESHOLD = 0.1
# The depth test's tolerance grows with the local depth slope: it compares dd less
# DEPTH_SLOPE x the smaller one-sided relative depth step (x plus y, render res) with
# DEPTH_THRESHOLD (reference.md s4). A grazing floor steps steadily on both sides and its
# reprojection error passes; a silhouette is flat on one side and stays tested. Issue 23,
# rules, torch twin: validation 26.11 dB at 0, 26.26 / 26.27 / 26.29 / 26.31 at 1 / 2 / 4 /
# 8, held-out 0-7 25.69 -> 25.92 at 4, Blender foliage and interior -0.01; a plain
# threshold of 0.3 scores as 4 but leaves a smear at the demo sphere's silhouette.
DEPTH_SLOPE = 4.0
# Net mode's visibility decision: the classifier rejects the history where its visibility
# logit leads the larger of the other two by at least this margin (reference.md s7). 0 is
# the paper's argmax; the classifier is trained for balanced accuracy, which makes its
# argmax find 80 % of the disocclusions at the price of rejecting 7 % of the pixels
# without ghosting, each of them restarting its accumulation (issue 23: -0.8 dB on the
# held-out set); the margin, picked on the validation set, trades recall for that.
VIS_MARGIN = 2.0


def ghost_classes(logits, vis_margin=VIS_MARGIN):
    """The ghosting classes (0 visibility, 1 shading, 2 none) as net mode decides them from
    the ghosting logits [3, ...] (numpy): visibility where logit 0 leads the larger of the
    other two by at least vis_margin (reference.md s7, in its order), else the larger of
    shading and none. For views and reports; the frame step decides on the device."""
    lg = np.asarray(logits, np.float32)
    lead = lg[0] - np.maximum(lg[1], lg[2])
    return np.where(lead >= np.float32(vis_margin), 0, 1 + np.argmax(lg[1:3], 0))
SCATTER_WEIGHT_THRESHOLD = 0.01
DEPTH_EPS = 1e-6
# The classifier's four measurements (reference.md s4b: previous-depth difference, colour
# change, depth edge, colour spread) enter as m / (|m| + k): the label-relevant sizes (a 1 %
# depth jump, a 0.002-0.03 PQ colour change) become O(1) without the outliers (an
# off-screen 1, a full-range edge) dwarfing them, which a linear input scale could not do.
MEASURE_KNEES = (0.05, 0.02, 0.1, 0.02)
# Dilation neighbour order (dx, dy), FSR2's: the centre first, so that on equal depths
# (flat areas) a pixel keeps its own motion; the first maximum in this order wins.
DILATE_OFFSETS = ((0, 0), (1, 0), (0, 1), (0, -1), (-1, 0), (-1, 1), (1, 1), (-1, -1), (1, -1))
