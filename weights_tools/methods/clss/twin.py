"""The CLSS frame step in PyTorch: a differentiable twin of clss.Upscaler for training.

Every stage follows clss/methods/clss/reference.md (section numbers below) in the evaluation
order of the oracle graph (clss/methods/clss/oracle.py), so that what is trained is what
clss runs; tests/test_torch_twin.py checks it against clss.Upscaler frame by frame.

Tensors are NCHW float32 with a batch dimension B (patches); the state between frames
is the 16-channel history [B,16,H,W] (PQ colour 3, counter 1, colour min 3, max 3,
logits 6), explicit as in the oracle.  Runs on CUDA when the tensors are there, else CPU.

What carries gradients: the networks' parameters, through the classifier input (warped
history colour, warped logits), the composition input and the blend, and through the
history into later frames (recurrent training).  Stages 1-4 (dilation, FSR2 depth
reconstruction, depth difference, jitter-aware upsampling) depend on the inputs only
and run without autograd: the depth reconstruction is a scatter-max
(`scatter_reduce(..., "amax")`), which is exact but not differentiable, and nothing
upstream of it is learned.  The integer decisions (argmax reject, counter reset,
validity) are piecewise constant, as in the engine.

Networks: `Classifier` and `Composition` are torch modules named as
clss.networks.TORCH_NAME_MAP expects, so their parameters load from and export
to the safetensors names of clss.networks (`cls.<layer>.*`, `comp.<layer>.*`):
`networks_from_tensors`, `tensors_from_networks`.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from clss.pipeline.contract import PQ_NITS, output_size, to_internal, validate_frame
from clss.methods.clss.contract import (AUTO_REACTIVE_LO, AUTO_REACTIVE_MAX, AUTO_REACTIVE_SLOPE,
                                        CLIP_GAMMA, DEFAULT_CAP, DEPTH_EPS, DEPTH_SLOPE,
                                        DEPTH_THRESHOLD, DILATE_OFFSETS, HISTORY_CHANNELS,
                                        MEASURE_KNEES, MODES, VIS_MARGIN, RULE_CLIP_EPS,
                                        SCATTER_WEIGHT_THRESHOLD)

from clss.methods.clss.networks import pad16 as _pad16
from clss.methods.clss.networks import (BASES, CLASSIFIER_CHANNELS, COMPOSITION_CHANNELS,
                                        DEFAULT_MLP_HIDDEN, DEFAULT_WIDTHS, LOGITS,
                                        build_classifier, build_composition)
from clss.networks import WeightsError, model_weights
from clss.methods.clss.networks import base_of, torch_to_onnx_name

from weights_tools.trainloop import pq_decode, pq_encode  # noqa: F401 (also this module's API)

# Net mode's blend: "net" = the composition network (inference), "rule" = w = 1/(1+counter)
# without a clamp, the paper's rule-based composition for training the classifier (s3.4).
BLENDS = ("net", "rule")


def clip_towards(hist, up, lo, hi):
    """The history clip (reference.md s9): up + t (hist - up) with one t in [0, 1] for the
    three channels, the largest that keeps every channel inside [lo - eps, hi + eps]."""
    d = hist - up
    lim = torch.where(d > 0, (hi + RULE_CLIP_EPS) - up, (lo - RULE_CLIP_EPS) - up)
    nz = d != 0
    tc = torch.where(nz, lim / torch.where(nz, d, torch.ones_like(d)), torch.ones_like(d))
    t = torch.clamp(tc, min=0.0).amin(1, keepdim=True).clamp(max=1.0)
    return up + t * d


def pick_device(device=None) -> torch.device:
    """CUDA when present (or the device asked for), else CPU."""
    if device is not None:
        return torch.device(device)
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


# ---- the networks ---------------------------------------------------------------------

def space_to_depth(x, block=2):
    """ONNX SpaceToDepth (DCR order: channel = (by*B + bx)*C + c); torch's
    pixel_unshuffle is CRD (c*B*B + by*B + bx), which would scramble the stem's weights."""
    n, c, h, w = x.shape
    x = x.reshape(n, c, h // block, block, w // block, block)
    return x.permute(0, 3, 5, 1, 2, 4).reshape(n, c * block * block, h // block, w // block)


class Bottleneck(nn.Module):
    """conv1 1x1 c->c/2, ReLU, conv2 3x3, ReLU, conv3 1x1 -> c, + input, ReLU."""

    def __init__(self, c):
        super().__init__()
        mid = max(c // 2, 1)
        self.conv1 = nn.Conv2d(c, mid, 1)
        self.conv2 = nn.Conv2d(mid, mid, 3, padding=1)
        self.conv3 = nn.Conv2d(mid, c, 1)

    def forward(self, x):
        y = F.relu(self.conv2(F.relu(self.conv1(x))))
        return F.relu(x + self.conv3(y))


# ---- the input basis of training (folded away at export) -------------------------------
#
# The networks' inputs differ in scale by orders of magnitude (depth has a median of 0.013,
# motion of 3 output pixels, the colour differences that tell ghosting from aliasing are
# 0.002-0.03 in PQ), and Adam's steps are the same size for every weight, so in a few
# hundred steps the small inputs cannot matter (issue 23). Training therefore sees
# z = A (x - s): colour relative to the current colour and amplified, depth and motion
# brought to about unit size. The first layer acts linearly on its inputs, so the trained
# weights fold back into the runtime's basis exactly (`fold_basis`), and the ONNX graphs,
# kernels and shipped files do not change.

def _basis(inputs, diff_scale=30.0):
    """(A [C, C], s [C]) for an input layout (clss.networks CLASSIFIER_INPUTS or
    COMPOSITION_INPUTS): colours other than the current one as their difference to it x
    diff_scale, the current colour centred, depth x 10, motion / 4, the counter term
    centred, the depth difference x 10, logits / 4."""
    names = []
    for name, n in inputs:
        names += [(name, k) for k in range(n)]
    C = len(names)
    A, sh = np.zeros((C, C), np.float64), np.zeros(C, np.float64)
    up = {k: i for i, (n, k) in enumerate(names) if n == "bicubic_color"}
    for i, (name, k) in enumerate(names):
        if name == "bicubic_color":
            A[i, i], sh[i] = 2.0, 0.5
        elif name in ("warped_color", "color_min", "color_max"):
            # both shifted by the current colour's 0.5, so the row is exactly
            # diff_scale (x - up): without it each carried a constant +15
            A[i, i], A[i, up[k]], sh[i] = diff_scale, -diff_scale, 0.5
        elif name == "depth":
            A[i, i] = 10.0
        elif name == "motion":
            A[i, i] = 0.25
        elif name == "inv_counter":
            A[i, i], sh[i] = 2.0, 0.5
        elif name == "depth_difference":
            A[i, i] = 10.0
        elif name == "prev_depth_difference":   # already in (-1, 1) (MEASURE_KNEES)
            A[i, i] = 2.0
        elif name in ("color_change", "depth_edge", "color_spread"):   # [0, 1)
            A[i, i], sh[i] = 2.0, 0.5
        else:                                    # logits
            A[i, i] = 0.25
    return A, sh


class InputBasis(nn.Module):
    """z = A (x - s) over the channels of an N x C x H x W input (fixed, not trained)."""

    def __init__(self, inputs):
        super().__init__()
        A, sh = _basis(inputs)
        self.register_buffer("A", torch.tensor(A, dtype=torch.float32))
        self.register_buffer("s", torch.tensor(sh, dtype=torch.float32))

    def forward(self, x):
        return torch.einsum("oc,nchw->nohw", self.A, x - self.s.view(1, -1, 1, 1))


def _fold(conv, A, s, groups=1):
    """(weight, bias) in the raw input basis of a 1x1 conv trained on z = A (x - s),
    whose input channels are `groups` blocks of C (SpaceToDepth's DCR order)."""
    W = conv.weight.detach().double()[:, :, 0, 0]
    b = conv.bias.detach().double()
    C = A.shape[0]
    Wr = torch.zeros_like(W)
    for g in range(groups):
        Wg = W[:, g * C:(g + 1) * C]
        Wr[:, g * C:(g + 1) * C] = Wg @ A
        b = b - Wg @ (A @ s)
    return Wr.float().view_as(conv.weight), b.float()


def _unfold(conv, A, s, groups=1):
    """The inverse of _fold: raw-basis weights -> weights on z (to start training from
    shipped weights with the basis on)."""
    W = conv.weight.detach().double()[:, :, 0, 0]
    b = conv.bias.detach().double()
    C = A.shape[0]
    Ainv = torch.linalg.inv(A)
    Wz = torch.zeros_like(W)
    for g in range(groups):
        Wg = W[:, g * C:(g + 1) * C]
        Wz[:, g * C:(g + 1) * C] = Wg @ Ainv
        b = b + Wg @ s
    return Wz.float().view_as(conv.weight), b.float()


class Classifier(nn.Module):
    """clss.networks.build_classifier as a torch module (same graph)."""

    def __init__(self, widths=DEFAULT_WIDTHS, in_channels=CLASSIFIER_CHANNELS):
        super().__init__()
        c = tuple(int(v) for v in widths)
        self.basis = None                   # an InputBasis while training with one
        self.stem = nn.Conv2d(4 * in_channels, c[0], 1)
        self.enc = nn.ModuleList(Bottleneck(ci) for ci in c)
        self.down = nn.ModuleList(nn.Conv2d(c[i], c[i + 1], 3, stride=2, padding=1)
                                  for i in range(3))
        self.dec = nn.Sequential(nn.Conv2d(sum(c), c[0], 1), nn.ReLU(),
                                 nn.Conv2d(c[0], c[0], 3, padding=1), nn.ReLU(),
                                 nn.Conv2d(c[0], len(LOGITS), 1))

    def forward(self, x):
        """x [B,23,H,W], H and W multiples of 16 -> logits [B,6,H/2,W/2]."""
        if self.basis is not None:
            x = self.basis(x)
        f = self.enc[0](F.relu(self.stem(space_to_depth(x))))
        feats = [f]
        for down, enc in zip(self.down, self.enc[1:]):
            f = enc(F.relu(down(f)))
            feats.append(f)
        # ONNX Resize linear half_pixel with scales 2^i == torch bilinear, align_corners=False.
        ups = [feats[0]] + [F.interpolate(f, scale_factor=2.0 ** i, mode="bilinear",
                                          align_corners=False)
                            for i, f in enumerate(feats[1:], 1)]
        return self.dec(torch.cat(ups, 1))


class Composition(nn.Module):
    """The per-pixel two-layer MLP as 1x1 convolutions (named mlp.0 / mlp.2) -> w."""

    def __init__(self, hidden=DEFAULT_MLP_HIDDEN, in_channels=COMPOSITION_CHANNELS):
        super().__init__()
        self.basis = None                   # an InputBasis while training with one
        self.mlp = nn.Sequential(nn.Conv2d(in_channels, int(hidden), 1), nn.ReLU(),
                                 nn.Conv2d(int(hidden), 1, 1))

    def logit(self, x):
        """The MLP's output before the sigmoid, z (the rules' base corrects with it)."""
        if self.basis is not None:
            x = self.basis(x)
        return self.mlp(x)

    def forward(self, x):
        return torch.sigmoid(self.logit(x))


def use_basis(classifier, composition):
    """Train both networks on the input basis (module doc above); the function they
    compute does not change (their first layers are re-expressed on z)."""
    from clss.methods.clss.networks import CLASSIFIER_INPUTS, COMPOSITION_INPUTS
    for net, inputs, first, groups in ((classifier, CLASSIFIER_INPUTS, "stem", 4),
                                       (composition, COMPOSITION_INPUTS, "mlp.0", 1)):
        if net.basis is not None:
            continue
        basis = InputBasis(inputs).to(next(net.parameters()).device)
        conv = net.get_submodule(first)
        w, b = _unfold(conv, basis.A.double(), basis.s.double(), groups)
        with torch.no_grad():
            conv.weight.copy_(w)
            conv.bias.copy_(b)
        net.basis = basis


def fold_basis(classifier, composition):
    """Undo use_basis: the first layers back on the raw inputs (what the runtime feeds)."""
    for net, first, groups in ((classifier, "stem", 4), (composition, "mlp.0", 1)):
        if net.basis is None:
            continue
        conv = net.get_submodule(first)
        w, b = _fold(conv, net.basis.A.double(), net.basis.s.double(), groups)
        with torch.no_grad():
            conv.weight.copy_(w)
            conv.bias.copy_(b)
        net.basis = None


def _onnx_names(module, prefix):
    """{torch parameter name: safetensors/ONNX initializer name} of one network."""
    names = {}
    for k in module.state_dict():
        o = torch_to_onnx_name(f"{prefix}.{k}")
        if o is None:
            raise WeightsError(f"{prefix}.{k}: no ONNX name in weights.TORCH_NAME_MAP")
        names[k] = o
    return names


def _widths_from(tensors):
    return tuple(int(tensors[f"cls.{n}.weight"].shape[0])
                 for n in ("stem", "down1", "down2", "down3"))


def networks_from_tensors(tensors=None, seed=0):
    """(Classifier, Composition) holding `tensors` (name -> array, the safetensors names;
    None: the seeded init of clss.networks, identical to the ONNX graphs')."""
    if tensors is None:
        tensors = {**model_weights(build_classifier(seed=seed)),
                   **model_weights(build_composition(seed=seed))}
    cls = Classifier(_widths_from(tensors))
    comp = Composition(int(tensors["comp.fc1.weight"].shape[0]))
    for net, prefix in ((cls, "classifier"), (comp, "composition")):
        sd = net.state_dict()
        for k, o in _onnx_names(net, prefix).items():
            if o not in tensors:
                raise WeightsError(f"weights: no tensor {o} (for {prefix}.{k})")
            a = torch.tensor(np.asarray(tensors[o], np.float32))
            if a.numel() != sd[k].numel():
                raise WeightsError(f"{o}: shape {tuple(a.shape)} does not fit "
                                   f"{prefix}.{k} {tuple(sd[k].shape)}")
            sd[k] = a.reshape(sd[k].shape)
        net.load_state_dict(sd)
    return cls, comp


def tensors_from_networks(classifier, composition) -> dict:
    """name -> float32 numpy in the ONNX shapes (what weights.save_weights writes and
    clss.Upscaler(weights=...) loads)."""
    import copy
    if classifier.basis is not None or composition.basis is not None:
        classifier, composition = copy.deepcopy(classifier), copy.deepcopy(composition)
        fold_basis(classifier, composition)
    out = {}
    for net, prefix in ((classifier, "classifier"), (composition, "composition")):
        sd = net.state_dict()
        for k, o in _onnx_names(net, prefix).items():
            out[o] = sd[k].detach().float().cpu().numpy().copy()
    return out


# ---- the frame step -------------------------------------------------------------------

def _normalised(u, n):
    """GridSample align_corners=0 coordinate of the index coordinate u: (2u+1)/n - 1."""
    return (u * 2.0 + 1.0) / float(n) - 1.0


def _sample(x, grid, cubic):
    # Bicubic is Keys a = -0.75 in torch as in ONNX; border padding clamps each tap.
    return F.grid_sample(x, grid, mode="bicubic" if cubic else "bilinear",
                         padding_mode="border", align_corners=False)


class FrameStep(nn.Module):
    """One CLSS frame step for a fixed render size (reference.md s1-s9).

    mode "rule" or "net"; in net mode `classifier` and `composition` are the torch
    networks (`composition` may be None with blend="rule").  `cap`: counter cap (4 rule,
    32 net by default).  Call with internal-convention tensors (contract.to_internal):
    color [B,3,h,w] linear, depth [B,1,h,w] reversed-Z, motion [B,2,h,w] render pixels,
    jitter [B,2], reset [B] bool, history [B,16,H,W] (read only where not reset),
    reactive [B,1,h,w] or None.

    clip: pull the warped history into the current frame's clamp box before the blend
    (s9, both modes at run time); the classifier's training turns it off (the paper's
    rule-based composition has no clamp, so ghosting stays visible to learn from).

    reject_hook (studies, not the runtime): f(reject [B,1,H,W] bool, ctx) -> reject, where
    ctx holds up, hist (warped), hist_clipped (None without clip), valid, logits, dd_hr,
    depth_hr, counter (warped), measure_hr, clamp_min / clamp_max (None without clip);
    it replaces the history decision (visibility_oracle.py beside this file).

    base (net; clss.methods.clss.networks.BASES): "paper", or "rules": the rule's decision
    (the depth test alone) and cap (4), and the composition corrects the rule weight in the
    logit domain, w = sigmoid(z - ln n) (= 1/(1 + n exp(-z)), the kernel's form), so
    that a composition whose last layer is zero makes the rule mode's step (reference.md s9).

    Training extras (net mode): blend="rule" makes the paper's rule-based composition
    (w = 1/(1+counter), no clamp) instead of the composition network; `rule_color`
    [B,3,H,W] (PQ) is a second colour history made by that rule blend, which then feeds
    the classifier while the composition network makes the output (composition training,
    paper s3.4: "image composition twice").
    """

    def __init__(self, mode, render_size, scale=2.0, classifier=None, composition=None,
                 cap=None, *, depth_threshold=DEPTH_THRESHOLD, hdr=True, nits=PQ_NITS,
                 blend="net", clip=True, vis_margin=VIS_MARGIN, reject_hook=None,
                 depth_slope=DEPTH_SLOPE, base="paper"):
        super().__init__()
        if base not in BASES:
            raise ValueError(f"base: expected one of {', '.join(BASES)}, got {base!r}")
        self.rules_base = mode == "net" and base == "rules"
        self.reject_hook = reject_hook
        if mode not in MODES:
            raise ValueError(f"mode: expected one of {MODES}, got {mode!r}")
        if blend not in BLENDS:
            raise ValueError(f"blend: expected one of {BLENDS}, got {blend!r}")
        if mode == "net" and (classifier is None or (composition is None and blend == "net")):
            raise ValueError("mode 'net' needs a classifier and (unless blend='rule') a composition")
        self.mode, self.blend = mode, blend
        self.clip = bool(clip)
        self.h, self.w = int(render_size[0]), int(render_size[1])
        self.H, self.W = output_size(self.h, self.w, scale)
        self.cap = float(DEFAULT_CAP["rule" if self.rules_base else mode] if cap is None else cap)
        self.depth_threshold = float(depth_threshold)
        self.depth_slope = float(depth_slope)
        self.vis_margin = float(vis_margin)
        self.hdr, self.nits = bool(hdr), float(nits)
        self.classifier, self.composition = classifier, composition
        h, w, H, W = self.h, self.w, self.H, self.W
        # s5: output pixel centres in render index coordinates, float64 rounded to float32.
        bx = ((np.arange(W, dtype=np.float64) + 0.5) * w / W - 0.5).astype(np.float32)
        by = ((np.arange(H, dtype=np.float64) + 0.5) * h / H - 0.5).astype(np.float32)
        self.register_buffer("bx", torch.from_numpy(bx), persistent=False)
        self.register_buffer("by", torch.from_numpy(by), persistent=False)
        ar = lambda n: torch.arange(n, dtype=torch.float32)  # noqa: E731
        self.register_buffer("jj", ar(w).view(1, 1, 1, w), persistent=False)
        self.register_buffer("ii", ar(h).view(1, 1, h, 1), persistent=False)
        self.register_buffer("JJ", ar(W).view(1, 1, 1, W), persistent=False)
        self.register_buffer("II", ar(H).view(1, 1, H, 1), persistent=False)
        # s4b: the render pixel that holds output pixel (I, J)'s centre, in integers
        self.register_buffer("ri", torch.from_numpy((2 * np.arange(H) + 1) * h // (2 * H)),
                             persistent=False)
        self.register_buffer("rj", torch.from_numpy((2 * np.arange(W) + 1) * w // (2 * W)),
                             persistent=False)
        self.register_buffer("motion_ratio", torch.tensor([W / w, H / h], dtype=torch.float32)
                             .view(1, 2, 1, 1), persistent=False)

    def initial_history(self, batch=1):
        return torch.zeros(batch, HISTORY_CHANNELS, self.H, self.W, device=self.bx.device)

    # -- stages 1-4: inputs only, no autograd ---------------------------------------------
    @torch.no_grad()
    def prepare(self, color, depth, motion, jitter, reactive, prev=None, reset=None):
        B, h, w = color.shape[0], self.h, self.w
        X = pq_encode(color, self.nits) if self.hdr else torch.clamp(color, 0.0, 1.0)

        # s2 dilate: the first neighbour (FSR2 order, centre first) with the largest depth.
        pd = F.pad(depth, (1, 1, 1, 1), value=-1.0)
        pm = F.pad(motion, (1, 1, 1, 1), value=0.0)
        d9 = torch.cat([pd[:, :, 1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                        for dx, dy in DILATE_OFFSETS], 1)
        m9 = torch.stack([pm[:, :, 1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                          for dx, dy in DILATE_OFFSETS], 1)                  # [B,9,2,h,w]
        nearest = d9.argmax(1, keepdim=True)           # first maximum, as ONNX ArgMax
        d_dil = d9.gather(1, nearest)
        m_dil = m9.gather(1, nearest.unsqueeze(2).expand(B, 1, 2, h, w)).squeeze(1)

        # s3 reconstruct the previous depth: scatter-max into h*w + 1 slots (the last
        # takes refused taps), exactly the oracle's ScatterElements(reduction="max").
        ux, uy = self.jj + m_dil[:, 0:1], self.ii + m_dil[:, 1:2]
        x0, y0 = torch.floor(ux), torch.floor(uy)
        fx, fy = ux - x0, uy - y0
        wx, wy = (1.0 - fx, fx), (1.0 - fy, fy)
        taps, sidx = [], []
        for a, b in ((0, 0), (1, 0), (0, 1), (1, 1)):
            wk = wx[a] * wy[b]
            xk, yk = (x0 + float(a) if a else x0), (y0 + float(b) if b else y0)
            on = (xk >= 0) & (xk <= w - 1) & (yk >= 0) & (yk <= h - 1)
            lin = (torch.clamp(yk, 0, h - 1).long() * w + torch.clamp(xk, 0, w - 1).long())
            sidx.append(torch.where(on & (wk > SCATTER_WEIGHT_THRESHOLD), lin, h * w))
            taps.append((wk, on, lin))
        idx = torch.cat(sidx, 1).reshape(B, -1)
        recon = torch.zeros(B, h * w + 1, device=color.device).scatter_reduce(
            1, idx, d_dil.reshape(B, 1, -1).expand(B, 4, -1).reshape(B, -1), "amax")

        # s4 depth difference: bilinear read of the reconstruction, taps summed in order.
        rs = None
        for wk, on, lin in taps:
            v = recon.gather(1, lin.reshape(B, -1)).reshape(B, 1, h, w) * on.float() * wk
            rs = v if rs is None else rs + v
        dd = torch.clamp((rs - d_dil) / torch.clamp(rs, min=DEPTH_EPS), -1.0, 1.0)
        # s4 the depth test's own difference: dd less DEPTH_SLOPE x the local relative
        # depth step (the smaller one-sided step, x plus y), so that a grazing floor,
        # whose depth steps steadily, passes and a silhouette, flat on one side, does not
        pdr = F.pad(d_dil, (1, 1, 1, 1), mode="replicate")
        sx = torch.minimum((pdr[:, :, 1:-1, 2:] - d_dil).abs(), (d_dil - pdr[:, :, 1:-1, :-2]).abs())
        sy = torch.minimum((pdr[:, :, 2:, 1:-1] - d_dil).abs(), (d_dil - pdr[:, :, :-2, 1:-1]).abs())
        dd_test = dd - self.depth_slope * ((sx + sy) / torch.clamp(d_dil, min=DEPTH_EPS))

        # s5 jitter-aware sampling at output pixel centres.
        jx, jy = jitter[:, 0:1], jitter[:, 1:2]
        gx = _normalised(torch.clamp(self.bx - jx, 0.0, float(w - 1)), w)     # [B,W]
        gy = _normalised(torch.clamp(self.by - jy, 0.0, float(h - 1)), h)     # [B,H]
        grid = torch.stack([gx[:, None, :].expand(B, self.H, self.W),
                            gy[:, :, None].expand(B, self.H, self.W)], -1)
        up = torch.clamp(_sample(X, grid, True), 0.0, 1.0)
        if reactive is None:
            reactive = torch.zeros_like(depth)
        # auto-reactive (contract.AUTO_REACTIVE_*): the 3x3 divergence of the dilated
        # motion raises the blend weight, as the kernel's depth_diff and the oracle do
        pm = F.pad(m_dil, (1, 1, 1, 1), mode="replicate")
        div = torch.zeros_like(depth)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                n = pm[:, :, 1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                div = torch.maximum(div, (n[:, 0:1] - m_dil[:, 0:1]).abs()
                                    + (n[:, 1:2] - m_dil[:, 1:2]).abs())
        auto = torch.clamp((div - AUTO_REACTIVE_LO) * AUTO_REACTIVE_SLOPE, 0.0,
                           AUTO_REACTIVE_MAX)
        reactive = torch.maximum(reactive, auto)
        lr = [d_dil, m_dil, dd, reactive, dd_test]
        # s4b: the measurements at the render pixel holding each output pixel centre
        meas = torch.cat(self.measurements(X, depth, motion, prev, reset), 1)
        measure_hr = meas.index_select(2, self.ri).index_select(3, self.rj)
        if self.clip:
            # s9 clamp box: 3x3 render-res min/max (max_pool pads with -inf) narrowed to
            # mean +- CLIP_GAMMA std of the in-bounds neighbours, the moments taken of the
            # differences to the centre pixel in the kernel's order (as the oracle).
            px = F.pad(X, (1, 1, 1, 1), mode="replicate")
            on = F.pad(torch.ones_like(X[:1, :1]), (1, 1, 1, 1))
            s1 = s2 = cnt = 0.0
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    m = on[:, :, 1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                    d = (px[:, :, 1 + dy:1 + dy + h, 1 + dx:1 + dx + w] - X) * m
                    s1, s2, cnt = s1 + d, s2 + d * d, cnt + m
            md = s1 / cnt
            gsd = CLIP_GAMMA * torch.sqrt(torch.clamp(s2 / cnt - md * md, min=0.0))
            lr += [torch.maximum(-F.max_pool2d(-X, 3, 1, 1), X + md - gsd),
                   torch.minimum(F.max_pool2d(X, 3, 1, 1), X + md + gsd)]
        aux = _sample(torch.cat(lr, 1), grid, False)
        return {"up": up, "depth_hr": aux[:, 0:1], "motion_hr": aux[:, 1:3] * self.motion_ratio,
                "dd_hr": aux[:, 3:4], "reactive_hr": aux[:, 4:5], "dd_test_hr": aux[:, 5:6],
                "measure_hr": measure_hr,
                "clamp_min": aux[:, 6:9] if self.clip else None,
                "clamp_max": aux[:, 9:12] if self.clip else None,
                "depth_diff": dd, "recon": recon[:, :h * w].reshape(B, 1, h, w),
                "prev": torch.cat([X, depth], 1)}

    def measurements(self, X, d, m, prev, reset):
        """reference.md s4b, render res: [prev depth difference, colour change, depth edge,
        colour spread], each [B,1,h,w], of the pixel's own (not dilated) depth d and motion
        m: dilation gives a thin strip revealed behind a moving edge the edge's depth and
        motion, which hid most of the disocclusions (recall 8 % against 48 % undilated at a
        10 % jump). `prev` [B,4,h,w] is the previous frame's encoded colour and depth
        (None, or `reset`: the first two are 0), read at the nearest pixel to p + motion;
        off screen both are 1."""
        B, h, w = X.shape[0], self.h, self.w
        if prev is None:
            tdd = cc = torch.zeros_like(d)
        else:
            qx = torch.floor((self.jj + m[:, 0:1]) + 0.5)
            qy = torch.floor((self.ii + m[:, 1:2]) + 0.5)
            on = (qx >= 0) & (qx <= w - 1) & (qy >= 0) & (qy <= h - 1)
            lin = (torch.clamp(qy, 0, h - 1) * w + torch.clamp(qx, 0, w - 1)).long()
            pv = prev.reshape(B, 4, h * w).gather(2, lin.reshape(B, 1, -1).expand(B, 4, -1))
            pv = pv.reshape(B, 4, h, w)
            pd = pv[:, 3:4]
            one = torch.ones((), device=X.device)
            tdd = torch.where(on, torch.clamp((pd - d) / torch.clamp(pd, min=DEPTH_EPS), -1.0, 1.0),
                              one)
            cc = torch.where(on, (X - pv[:, 0:3]).abs().amax(1, keepdim=True), one)
            if reset is not None:
                keep = ~torch.as_tensor(reset, device=X.device).reshape(-1, 1, 1, 1).bool()
                tdd, cc = tdd * keep, cc * keep
        # 3x3 ranges over the in-bounds neighbours (edge replication adds none)
        pd3 = F.pad(d, (1, 1, 1, 1), mode="replicate")
        dmax = F.max_pool2d(pd3, 3, 1)
        dmin = -F.max_pool2d(-pd3, 3, 1)
        edge = (dmax - dmin) / torch.clamp(dmax, min=DEPTH_EPS)
        px = F.pad(X, (1, 1, 1, 1), mode="replicate")
        spread = (F.max_pool2d(px, 3, 1) + F.max_pool2d(-px, 3, 1)).amax(1, keepdim=True)
        return [m / (m.abs() + k) for m, k in zip((tdd, cc, edge, spread), MEASURE_KNEES)]

    # -- stages 5-9 ------------------------------------------------------------------------
    def forward(self, color, depth, motion, jitter, reset, history, reactive=None,
                rule_color=None, prev=None):
        """-> dict: output [B,3,H,W] linear, out (PQ), history [B,16,H,W], prev [B,4,h,w]
        (the render-res state, fed back as `prev`), w, counter, ghost, valid, logits
        (net), up, blend_hist (the warped history as blended: clipped when `clip`), and
        rule_color when it was given."""
        p = self.prepare(color, depth, motion, jitter, reactive, prev, reset)
        up, motion_hr = p["up"], p["motion_hr"]
        B, H, W = up.shape[0], self.H, self.W

        # s6 warp the history; invalid pixels re-initialised.
        with torch.no_grad():
            su, sv = self.JJ + motion_hr[:, 0:1], self.II + motion_hr[:, 1:2]
            off = (su < -0.5) | (su > W - 0.5) | (sv < -0.5) | (sv > H - 0.5)
            reset = torch.as_tensor(reset, device=up.device).reshape(-1, 1, 1, 1).bool()
            valid = ~off & ~reset
            grid_w = torch.cat([_normalised(torch.clamp(su, 0.0, float(W - 1)), W),
                                _normalised(torch.clamp(sv, 0.0, float(H - 1)), H)],
                               1).permute(0, 2, 3, 1)
        hist_c = torch.clamp(_sample(history[:, 0:3], grid_w, True), 0.0, 1.0)
        hist_o = _sample(history[:, 3:HISTORY_CHANNELS], grid_w, False)
        zero = torch.zeros((), device=up.device)
        w_col = torch.where(valid, hist_c, up)
        w_cnt = torch.where(valid, hist_o[:, 0:1], zero)
        w_min = torch.where(valid, hist_o[:, 1:4], up)
        w_max = torch.where(valid, hist_o[:, 4:7], up)
        w_log = torch.where(valid, hist_o[:, 7:13], zero)
        cls_col = w_col
        if rule_color is not None:
            cls_col = torch.where(valid, torch.clamp(_sample(rule_color, grid_w, True), 0.0, 1.0),
                                  up)

        # s7 classification.
        logits = None
        if self.mode == "net":
            x = torch.cat([up, cls_col, p["depth_hr"], motion_hr, 1.0 / (1.0 + w_cnt), w_min,
                           w_max, p["dd_hr"], w_log, p["measure_hr"]], 1)
            H16, W16 = _pad16(H), _pad16(W)
            if (H16, W16) != (H, W):
                x = F.pad(x, (0, W16 - W, 0, H16 - H), mode="replicate")
            half = self.classifier(x.contiguous(memory_format=torch.channels_last))
            logits = F.interpolate(half, scale_factor=2.0, mode="bilinear",
                                   align_corners=False)[:, :, :H, :W]
            # the rule's depth test is a floor under the classifier (reference.md section 7)
            # visibility leads by vis_margin (0: argmax, first index on ties), with the
            # rule's depth test as a floor (reference.md section 7)
            lead = logits[:, 0:1] - torch.maximum(logits[:, 1:2], logits[:, 2:3])
            reject = (lead >= self.vis_margin) | (p["dd_test_hr"] > self.depth_threshold)
            if self.rules_base:     # the rules' base: the rule's decision
                reject = p["dd_test_hr"] > self.depth_threshold
        else:
            reject = p["dd_test_hr"] > self.depth_threshold
        # s9's history as the blend uses it: clipped into the clamp box (both modes)
        blend_hist = w_col
        if self.clip:
            blend_hist = clip_towards(w_col, up, p["clamp_min"], p["clamp_max"])
        if self.reject_hook is not None:
            # studies only (visibility_oracle.py beside this file): replace the decision
            clamp = blend_hist if self.clip else None
            reject = self.reject_hook(reject, {"up": up, "hist": w_col, "hist_clipped": clamp,
                                               "valid": valid, "logits": logits,
                                               "dd_hr": p["dd_hr"], "depth_hr": p["depth_hr"],
                                               "counter": w_cnt, "measure_hr": p["measure_hr"],
                                               "clamp_min": p["clamp_min"],
                                               "clamp_max": p["clamp_max"]})
        ghost = reject | ~valid

        # s8 auxiliary buffers.
        cnt = torch.where(ghost, zero, torch.clamp(w_cnt + 1.0, max=self.cap))
        c_min = torch.where(ghost, up, torch.minimum(w_min, up))
        c_max = torch.where(ghost, up, torch.maximum(w_max, up))
        inv_cnt = 1.0 / (1.0 + cnt)

        # s9 blend weight and blend.
        react = p["reactive_hr"]
        res = {}
        if self.mode == "net":
            if rule_color is not None or self.blend == "rule":
                w_rule = torch.maximum(inv_cnt, react)
                rule_out = w_rule * up + (1.0 - w_rule) * cls_col
                res["rule_color"] = rule_out
            if self.blend == "net":
                comp_in = torch.cat([up, blend_hist, p["depth_hr"], motion_hr, inv_cnt, c_min,
                                     c_max, logits], 1)
                comp_in = comp_in.contiguous(memory_format=torch.channels_last)
                if self.rules_base:
                    # the rules' 1/(1+n) corrected in the logit domain; n >= 1 off the
                    # ghosts (the clamp keeps the ghosts' gradient finite)
                    z = self.composition.logit(comp_in)
                    w0 = torch.sigmoid(z - torch.log(torch.clamp(cnt, min=1.0)))
                else:
                    w0 = self.composition(comp_in)
                # a ghost drops its history (reference.md s9)
                w0 = torch.where(ghost, torch.ones((), device=up.device), w0)
            else:
                w0 = inv_cnt
            new_logits = logits
        else:
            w0 = inv_cnt
            new_logits = torch.zeros(B, len(LOGITS), H, W, device=up.device)
        wgt = torch.maximum(w0, react)
        out = wgt * up + (1.0 - wgt) * blend_hist
        history_out = torch.cat([out, cnt, c_min, c_max, new_logits], 1)
        output = pq_decode(out, self.nits) if self.hdr else out
        res.update(output=output, out=out, history=history_out, prev=p["prev"], w=wgt, counter=cnt,
                   ghost=ghost, valid=valid, logits=logits, up=up, depth_diff=p["depth_diff"],
                   blend_hist=blend_hist)
        return res


class TorchUpscaler:
    """Frame-by-frame runner of `FrameStep` with clss.Upscaler's calling convention
    (contract layout in, H x W x 3 float32 linear out, state carried, first frame and
    `reset=True` start afresh).  For parity tests and evaluation; batch 1.

    weights: None (the seeded untrained init), a dict of tensors, or a .safetensors path.
    base: the blend's base (FrameStep; None: the config stored with a weights file,
    "paper" for a file without one and for a dict).
    """

    def __init__(self, scale=2.0, mode="net", weights=None, cap=None, *, device=None,
                 depth_threshold=DEPTH_THRESHOLD, hdr=True, nits=PQ_NITS,
                 depth_inverted=True, motion_scale=(1.0, 1.0), exposure=1.0, clip=True,
                 vis_margin=VIS_MARGIN, reject_hook=None, depth_slope=DEPTH_SLOPE, base=None):
        self.scale, self.mode = float(scale), {"rules": "rule"}.get(mode, mode)
        self.device = pick_device(device)
        self.kw = dict(cap=cap, depth_threshold=depth_threshold, hdr=hdr, nits=nits, clip=clip,
                       vis_margin=vis_margin, reject_hook=reject_hook, depth_slope=depth_slope)
        self.contract = dict(depth_inverted=depth_inverted, motion_scale=motion_scale,
                             exposure=exposure)
        self.nets = (None, None)
        if self.mode == "net":
            cfg = {}
            if isinstance(weights, (str, bytes)) or hasattr(weights, "__fspath__"):
                from clss.methods.clss.networks import read_config
                from clss.networks import load_weights
                cfg = read_config(weights)
                weights = load_weights(weights)
            self.kw["base"] = base_of({"base": base} if base is not None else cfg)
            self.nets = tuple(n.to(self.device).eval() for n in networks_from_tensors(weights))
        self.step_fn = None
        self.history = self.prev = None
        self.last = {}

    def reset(self):
        self.history = self.prev = None

    @torch.no_grad()
    def step(self, color, depth, motion, jitter, reset=False, reactive=None, **gbuffers):
        """One frame (clss.Upscaler's step; G-buffers, which CLSS does not use, ignored)."""
        frame = validate_frame(color, depth, motion, jitter, reactive,
                               depth_inverted=self.contract["depth_inverted"])
        feed = to_internal(frame, **self.contract)
        h, w = feed["depth"].shape[2:]
        if self.step_fn is None or (self.step_fn.h, self.step_fn.w) != (h, w):
            self.step_fn = FrameStep(self.mode, (h, w), self.scale, *self.nets,
                                     **self.kw).to(self.device)
            self.history = self.prev = None
        t = {k: torch.from_numpy(v).to(self.device) for k, v in feed.items()}
        first = self.history is None
        hist = self.step_fn.initial_history() if first else self.history
        r = self.step_fn(t["color"], t["depth"], t["motion"], t["jitter"].view(1, 2),
                         torch.tensor([bool(reset or first)]), hist, t["reactive"],
                         prev=None if first else self.prev)
        self.history, self.prev = r["history"], r["prev"]
        self.last = r
        out = r["output"][0].permute(1, 2, 0).cpu().numpy()
        e = self.contract["exposure"]
        return out * np.float32(e) if e != 1.0 else out

    @property
    def state(self):
        return {"history": None if self.history is None else self.history.cpu().numpy()}
