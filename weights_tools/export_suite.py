"""The exported-model suite (issue 49): small PyTorch versions of published SR, vision and
temporal architectures, random weights from fixed seeds, each exported with both of torch's
ONNX exporters, written with a manifest so that tests/test_exported_models.py (no torch)
runs every file through clss.Model and onnxruntime.

    python -m weights_tools export-suite --out tests/fixtures/exported   (make export-fixtures)

Exporters:
* ``torchscript``: ``torch.onnx.export(..., dynamo=False, opset_version=17)``;
* ``dynamo``: ``torch.onnx.export(..., dynamo=True)``, torch's default exporter, at its default
  opset, with the external data it writes (``NAME.onnx.data``) kept as written.

Both files get ``ir_version`` at most 10 (onnxruntime 1.32 runs no later). The conv SR
models (``bench: true`` in the manifest) are exported with dynamic height and width, so one
file serves the tests' odd sizes (``input_shapes=``) and bench/exported.py's 540x960; the
others have the fixed shapes of the manifest. Needs the [train] extra (torch, onnxscript).
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import dataclass, field

import numpy as np
import onnx
import torch
import torch.nn as nn
import torch.nn.functional as F

EXPORTERS = ("torchscript", "dynamo")
TORCHSCRIPT_OPSET = 17
MAX_IR_VERSION = 10        # onnxruntime 1.32 reads IR versions <= 10
MANIFEST = "manifest.json"


# --- the architectures ---------------------------------------------------------------------

class ESPCN(nn.Module):
    """Shi et al. 2016: conv 5x5 + tanh, conv 3x3 + tanh, conv 3x3 to 3 r^2, PixelShuffle."""

    def __init__(self, scale=2, c=3, f1=16, f2=8):
        super().__init__()
        self.conv1 = nn.Conv2d(c, f1, 5, padding=2)
        self.conv2 = nn.Conv2d(f1, f2, 3, padding=1)
        self.conv3 = nn.Conv2d(f2, c * scale * scale, 3, padding=1)
        self.shuffle = nn.PixelShuffle(scale)

    def forward(self, x):
        x = torch.tanh(self.conv1(x))
        x = torch.tanh(self.conv2(x))
        return self.shuffle(self.conv3(x))


class FSRCNN(nn.Module):
    """Dong et al. 2016 on the luma channel: feature extraction 5x5, shrinking 1x1, m mapping
    3x3 layers, expanding 1x1 (PReLU after each), deconvolution 9x9 stride 2."""

    def __init__(self, scale=2, d=16, s=8, m=2):
        super().__init__()
        layers = [nn.Conv2d(1, d, 5, padding=2), nn.PReLU(d), nn.Conv2d(d, s, 1), nn.PReLU(s)]
        for _ in range(m):
            layers += [nn.Conv2d(s, s, 3, padding=1), nn.PReLU(s)]
        layers += [nn.Conv2d(s, d, 1), nn.PReLU(d)]
        self.body = nn.Sequential(*layers)
        self.deconv = nn.ConvTranspose2d(d, 1, 9, stride=scale, padding=4, output_padding=scale - 1)
        for mod in self.body:      # PReLU slopes away from the 0.25 default
            if isinstance(mod, nn.PReLU):
                nn.init.uniform_(mod.weight, 0.05, 0.4)

    def forward(self, x):
        return self.deconv(self.body(x))


class MeanShift(nn.Conv2d):
    """EDSR's sub_mean / add_mean: a fixed 1x1 conv."""

    def __init__(self, sign, mean=(0.4488, 0.4371, 0.4040)):
        super().__init__(3, 3, 1)
        self.weight.data = torch.eye(3).view(3, 3, 1, 1)
        self.bias.data = sign * torch.tensor(mean)
        for p in self.parameters():
            p.requires_grad = False


class ResBlock(nn.Module):
    """EDSR's residual block: conv, ReLU, conv, scaled, plus the input (no BatchNorm)."""

    def __init__(self, n, res_scale=0.1):
        super().__init__()
        self.body = nn.Sequential(nn.Conv2d(n, n, 3, padding=1), nn.ReLU(True), nn.Conv2d(n, n, 3, padding=1))
        self.res_scale = res_scale

    def forward(self, x):
        return self.body(x) * self.res_scale + x


class EDSR(nn.Module):
    """Lim et al. 2017, small: mean shift, head conv, residual blocks, body conv + long skip,
    conv + PixelShuffle upsampler, tail conv, mean shift back."""

    def __init__(self, n=16, blocks=3, scale=2):
        super().__init__()
        self.sub_mean, self.add_mean = MeanShift(-1), MeanShift(1)
        self.head = nn.Conv2d(3, n, 3, padding=1)
        self.body = nn.Sequential(*[ResBlock(n) for _ in range(blocks)], nn.Conv2d(n, n, 3, padding=1))
        self.up = nn.Sequential(nn.Conv2d(n, n * scale * scale, 3, padding=1), nn.PixelShuffle(scale))
        self.tail = nn.Conv2d(n, 3, 3, padding=1)

    def forward(self, x):
        x = self.head(self.sub_mean(x))
        x = self.body(x) + x
        return self.add_mean(self.tail(self.up(x)))


class ChannelAttention(nn.Module):
    """RCAN's CA layer: AdaptiveAvgPool2d(1) -> 1x1 conv -> ReLU -> 1x1 conv -> Sigmoid -> Mul."""

    def __init__(self, n, reduction=4):
        super().__init__()
        self.pool = nn.AdaptiveAvgPool2d(1)
        self.du = nn.Sequential(nn.Conv2d(n, n // reduction, 1), nn.ReLU(True),
                                nn.Conv2d(n // reduction, n, 1), nn.Sigmoid())

    def forward(self, x):
        return x * self.du(self.pool(x))


class RCAB(nn.Module):
    def __init__(self, n, reduction=4):
        super().__init__()
        self.body = nn.Sequential(nn.Conv2d(n, n, 3, padding=1), nn.ReLU(True),
                                  nn.Conv2d(n, n, 3, padding=1), ChannelAttention(n, reduction))

    def forward(self, x):
        return self.body(x) + x


class RCAN(nn.Module):
    """Zhang et al. 2018, small: one residual group of RCABs (channel attention), group conv
    + skip, long skip, conv + PixelShuffle upsampler, tail conv."""

    def __init__(self, n=16, blocks=2, scale=2):
        super().__init__()
        self.head = nn.Conv2d(3, n, 3, padding=1)
        self.group = nn.Sequential(*[RCAB(n) for _ in range(blocks)], nn.Conv2d(n, n, 3, padding=1))
        self.body_conv = nn.Conv2d(n, n, 3, padding=1)
        self.up = nn.Sequential(nn.Conv2d(n, n * scale * scale, 3, padding=1), nn.PixelShuffle(scale))
        self.tail = nn.Conv2d(n, 3, 3, padding=1)

    def forward(self, x):
        x = self.head(x)
        r = self.group(x) + x
        x = self.body_conv(r) + x
        return self.tail(self.up(x))


def _randomise_bn(model):
    """Eval-mode BatchNorm with running statistics and affine parameters away from 0 / 1."""
    for m in model.modules():
        if isinstance(m, nn.BatchNorm2d):
            with torch.no_grad():
                m.running_mean.uniform_(-0.2, 0.2)
                m.running_var.uniform_(0.5, 2.0)
                m.weight.uniform_(0.7, 1.3)
                m.bias.uniform_(-0.1, 0.1)


def _conv_bn_relu(cin, cout):
    return [nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(True)]


class UNetBN(nn.Module):
    """Ronneberger et al. 2015 with BatchNorm (eval mode), two levels: (conv-BN-ReLU) x2,
    MaxPool 2x2, a ConvTranspose 2x2 up on the deep level and a bilinear nn.Upsample + 1x1
    conv on the shallow one, skip concatenations, 1x1 output conv."""

    def __init__(self, c=8):
        super().__init__()
        self.enc1 = nn.Sequential(*_conv_bn_relu(3, c), *_conv_bn_relu(c, c))
        self.enc2 = nn.Sequential(*_conv_bn_relu(c, 2 * c), *_conv_bn_relu(2 * c, 2 * c))
        self.mid = nn.Sequential(*_conv_bn_relu(2 * c, 4 * c), *_conv_bn_relu(4 * c, 4 * c))
        self.pool = nn.MaxPool2d(2)
        self.up2 = nn.ConvTranspose2d(4 * c, 2 * c, 2, stride=2)
        self.dec2 = nn.Sequential(*_conv_bn_relu(4 * c, 2 * c), *_conv_bn_relu(2 * c, 2 * c))
        self.up1 = nn.Sequential(nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False),
                                 nn.Conv2d(2 * c, c, 1))
        self.dec1 = nn.Sequential(*_conv_bn_relu(2 * c, c), *_conv_bn_relu(c, c))
        self.out = nn.Conv2d(c, 3, 1)
        _randomise_bn(self)

    def forward(self, x):
        e1 = self.enc1(x)
        e2 = self.enc2(self.pool(e1))
        m = self.mid(self.pool(e2))
        d2 = self.dec2(torch.cat([self.up2(m), e2], 1))
        d1 = self.dec1(torch.cat([self.up1(d2), e1], 1))
        return self.out(d1)


class SqueezeExcite(nn.Module):
    """MobileNetV3's SE: AdaptiveAvgPool2d(1) -> 1x1 conv -> ReLU -> 1x1 conv -> Hardsigmoid -> Mul."""

    def __init__(self, c, squeeze):
        super().__init__()
        self.pool = nn.AdaptiveAvgPool2d(1)
        self.fc1, self.fc2 = nn.Conv2d(c, squeeze, 1), nn.Conv2d(squeeze, c, 1)
        self.relu, self.gate = nn.ReLU(True), nn.Hardsigmoid()

    def forward(self, x):
        return x * self.gate(self.fc2(self.relu(self.fc1(self.pool(x)))))


class InvertedResidual(nn.Module):
    """MobileNetV3's bneck: 1x1 expand, depthwise kxk, optional SE, 1x1 project (BN after
    each), residual where the shape allows."""

    def __init__(self, cin, exp, cout, k, stride, se, act):
        super().__init__()
        layers = [nn.Conv2d(cin, exp, 1, bias=False), nn.BatchNorm2d(exp), act(),
                  nn.Conv2d(exp, exp, k, stride, k // 2, groups=exp, bias=False), nn.BatchNorm2d(exp), act()]
        if se:
            layers.append(SqueezeExcite(exp, _make_divisible(exp // 4)))
        layers += [nn.Conv2d(exp, cout, 1, bias=False), nn.BatchNorm2d(cout)]
        self.block = nn.Sequential(*layers)
        self.residual = stride == 1 and cin == cout

    def forward(self, x):
        y = self.block(x)
        return y + x if self.residual else y


def _make_divisible(v, divisor=8):
    return max(divisor, int(v + divisor / 2) // divisor * divisor)


class MobileNetV3(nn.Module):
    """Howard et al. 2019, small: stem conv s2 + Hardswish, three bnecks (depthwise, SE with
    Hardsigmoid, Hardswish / ReLU), 1x1 head conv, and the classifier (pool, Linear,
    Hardswish, Linear). Outputs the head features and the logits."""

    def __init__(self, classes=10):
        super().__init__()
        self.stem = nn.Sequential(nn.Conv2d(3, 16, 3, 2, 1, bias=False), nn.BatchNorm2d(16), nn.Hardswish())
        self.blocks = nn.Sequential(
            InvertedResidual(16, 32, 16, 3, 1, True, nn.Hardswish),
            InvertedResidual(16, 48, 24, 5, 2, False, nn.ReLU),
            InvertedResidual(24, 48, 24, 5, 1, True, nn.Hardswish))
        self.head = nn.Sequential(nn.Conv2d(24, 32, 1, bias=False), nn.BatchNorm2d(32), nn.Hardswish())
        self.pool = nn.AdaptiveAvgPool2d(1)
        self.classifier = nn.Sequential(nn.Linear(32, 48), nn.Hardswish(), nn.Dropout(0.2), nn.Linear(48, classes))
        _randomise_bn(self)

    def forward(self, x):
        f = self.head(self.blocks(self.stem(x)))
        return f, self.classifier(torch.flatten(self.pool(f), 1))


def window_partition(x, ws):
    b, h, w, c = x.shape
    x = x.view(b, h // ws, ws, w // ws, ws, c)
    return x.permute(0, 1, 3, 2, 4, 5).contiguous().view(-1, ws, ws, c)


def window_reverse(windows, ws, h, w):
    b = int(windows.shape[0] / (h * w / ws / ws))
    x = windows.view(b, h // ws, w // ws, ws, ws, -1)
    return x.permute(0, 1, 3, 2, 4, 5).contiguous().view(b, h, w, -1)


class WindowAttention(nn.Module):
    """Swin's W-MSA: qkv Linear, Q K^T (two activations) scaled, relative position bias,
    the shifted-window mask, softmax, @ V, projection."""

    def __init__(self, dim, ws, heads):
        super().__init__()
        self.ws, self.heads, self.scale = ws, heads, (dim // heads) ** -0.5
        self.relative_position_bias_table = nn.Parameter(torch.randn((2 * ws - 1) ** 2, heads) * 0.5)
        coords = torch.stack(torch.meshgrid(torch.arange(ws), torch.arange(ws), indexing="ij")).flatten(1)
        rel = (coords[:, :, None] - coords[:, None, :]).permute(1, 2, 0).contiguous()
        rel[:, :, 0] += ws - 1
        rel[:, :, 1] += ws - 1
        rel[:, :, 0] *= 2 * ws - 1
        self.register_buffer("relative_position_index", rel.sum(-1), persistent=False)
        self.qkv = nn.Linear(dim, dim * 3)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x, mask=None):
        b, n, c = x.shape
        qkv = self.qkv(x).reshape(b, n, 3, self.heads, c // self.heads).permute(2, 0, 3, 1, 4)
        q, k, v = qkv[0], qkv[1], qkv[2]
        attn = (q * self.scale) @ k.transpose(-2, -1)
        bias = self.relative_position_bias_table[self.relative_position_index.view(-1)].view(n, n, -1)
        attn = attn + bias.permute(2, 0, 1).contiguous().unsqueeze(0)
        if mask is not None:
            nw = mask.shape[0]
            attn = attn.view(b // nw, nw, self.heads, n, n) + mask.unsqueeze(1).unsqueeze(0)
            attn = attn.view(-1, self.heads, n, n)
        attn = attn.softmax(dim=-1)
        x = (attn @ v).transpose(1, 2).reshape(b, n, c)
        return self.proj(x)


class SwinBlock(nn.Module):
    """Swin Transformer block: LayerNorm, (shifted) window attention via torch.roll and window
    partition / reverse, residual; LayerNorm, GELU MLP, residual."""

    def __init__(self, dim, size, ws, heads, shift, mlp_ratio=2.0):
        super().__init__()
        self.size, self.ws, self.shift = size, ws, shift
        self.norm1, self.norm2 = nn.LayerNorm(dim), nn.LayerNorm(dim)
        self.attn = WindowAttention(dim, ws, heads)
        hidden = int(dim * mlp_ratio)
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(), nn.Linear(hidden, dim))
        mask = self._mask(size) if shift else None
        self.register_buffer("attn_mask", mask, persistent=False)
        with torch.no_grad():     # LayerNorm affine away from 1 / 0
            for nrm in (self.norm1, self.norm2):
                nrm.weight.uniform_(0.7, 1.3)
                nrm.bias.uniform_(-0.1, 0.1)

    def _mask(self, size):
        h, w = size
        img = torch.zeros((1, h, w, 1))
        cnt = 0
        spans = (slice(0, -self.ws), slice(-self.ws, -self.shift), slice(-self.shift, None))
        for hs in spans:
            for wsl in spans:
                img[:, hs, wsl, :] = cnt
                cnt += 1
        mw = window_partition(img, self.ws).view(-1, self.ws * self.ws)
        mask = mw.unsqueeze(1) - mw.unsqueeze(2)
        return mask.masked_fill(mask != 0, -100.0).masked_fill(mask == 0, 0.0)

    def forward(self, x):
        h, w = self.size
        b, _, c = x.shape
        shortcut = x
        x = self.norm1(x).view(b, h, w, c)
        if self.shift:
            x = torch.roll(x, shifts=(-self.shift, -self.shift), dims=(1, 2))
        win = window_partition(x, self.ws).view(-1, self.ws * self.ws, c)
        win = self.attn(win, self.attn_mask).view(-1, self.ws, self.ws, c)
        x = window_reverse(win, self.ws, h, w)
        if self.shift:
            x = torch.roll(x, shifts=(self.shift, self.shift), dims=(1, 2))
        x = shortcut + x.view(b, h * w, c)
        return x + self.mlp(self.norm2(x))


class SwinIR(nn.Module):
    """Liang et al. 2021, small (image restoration, 1x): reflect-pad to a multiple of the
    window, conv_first, patch embed (flatten, transpose, LayerNorm), a regular and a shifted
    Swin block, LayerNorm, patch unembed, conv_after_body + skip, conv_last + input, crop."""

    def __init__(self, size, dim=16, ws=4, heads=2):
        super().__init__()
        self.ws = ws
        self.h, self.w = size
        hp, wp = -(-self.h // ws) * ws, -(-self.w // ws) * ws
        self.pad = (0, wp - self.w, 0, hp - self.h)
        self.conv_first = nn.Conv2d(3, dim, 3, padding=1)
        self.patch_norm = nn.LayerNorm(dim)
        self.blocks = nn.ModuleList([SwinBlock(dim, (hp, wp), ws, heads, 0),
                                     SwinBlock(dim, (hp, wp), ws, heads, ws // 2)])
        self.norm = nn.LayerNorm(dim)
        self.conv_after_body = nn.Conv2d(dim, dim, 3, padding=1)
        self.conv_last = nn.Conv2d(dim, 3, 3, padding=1)
        self.padded = (hp, wp)

    def forward(self, x):
        xp = F.pad(x, self.pad, mode="reflect")
        f = self.conv_first(xp)
        b, c, hp, wp = f.shape
        t = self.patch_norm(f.flatten(2).transpose(1, 2))
        for blk in self.blocks:
            t = blk(t)
        t = self.norm(t).transpose(1, 2).view(b, c, hp, wp)
        f = self.conv_after_body(t) + f
        y = self.conv_last(f) + xp
        return y[:, :, :self.h, :self.w]


def flow_warp(x, flow):
    """BasicVSR's flow_warp: a pixel grid plus the flow (N, H, W, 2), normalised to [-1, 1]
    (align_corners=True), then bilinear grid_sample with zero padding."""
    _, _, h, w = x.shape
    gy, gx = torch.meshgrid(torch.arange(0, h, dtype=x.dtype), torch.arange(0, w, dtype=x.dtype), indexing="ij")
    grid = torch.stack((gx, gy), 2)
    v = grid + flow
    vx = 2.0 * v[:, :, :, 0] / max(w - 1, 1) - 1.0
    vy = 2.0 * v[:, :, :, 1] / max(h - 1, 1) - 1.0
    return F.grid_sample(x, torch.stack((vx, vy), dim=3), mode="bilinear", padding_mode="zeros", align_corners=True)


class BasicVSRStep(nn.Module):
    """One propagation step of Chan et al. 2021's BasicVSR: warp the propagated features by
    the flow, concatenate with the LR frame, ResidualBlocksWithInputConv (conv + LeakyReLU,
    residual blocks), then the upsampler (conv + PixelShuffle, LeakyReLU, conv) on top of
    the bilinearly upsized frame. Outputs the frame and the features to propagate."""

    def __init__(self, n=16, blocks=2, scale=2):
        super().__init__()
        self.scale = scale
        self.input_conv = nn.Sequential(nn.Conv2d(3 + n, n, 3, padding=1), nn.LeakyReLU(0.1, True))
        self.blocks = nn.Sequential(*[ResBlock(n, 1.0) for _ in range(blocks)])
        self.up = nn.Sequential(nn.Conv2d(n, n * scale * scale, 3, padding=1), nn.PixelShuffle(scale),
                                nn.LeakyReLU(0.1, True), nn.Conv2d(n, 3, 3, padding=1))

    def forward(self, lr, feat, flow):
        feat = flow_warp(feat, flow.permute(0, 2, 3, 1))
        feat = self.blocks(self.input_conv(torch.cat([lr, feat], 1)))
        base = F.interpolate(lr, scale_factor=self.scale, mode="bilinear", align_corners=False)
        return self.up(feat) + base, feat


class ConvLSTMCell(nn.Module):
    """Shi et al. 2015: conv of cat(x, h) into 4 gates (chunk), sigmoid i f o, tanh g,
    c' = f c + i g, h' = o tanh(c')."""

    def __init__(self, cin=3, hidden=8, k=3):
        super().__init__()
        self.conv = nn.Conv2d(cin + hidden, 4 * hidden, k, padding=k // 2)

    def forward(self, x, h, c):
        i, f, o, g = torch.chunk(self.conv(torch.cat([x, h], 1)), 4, dim=1)
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
        return torch.sigmoid(o) * torch.tanh(c), c


class RDB(nn.Module):
    """ESRGAN's residual dense block: 5 convs with dense concatenation, LeakyReLU 0.2,
    scaled by 0.2 plus the input."""

    def __init__(self, nf, gc):
        super().__init__()
        self.convs = nn.ModuleList([nn.Conv2d(nf + i * gc, gc if i < 4 else nf, 3, padding=1) for i in range(5)])
        self.lrelu = nn.LeakyReLU(0.2, True)

    def forward(self, x):
        feats = [x]
        for i, conv in enumerate(self.convs):
            y = conv(torch.cat(feats, 1))
            if i < 4:
                feats.append(self.lrelu(y))
        return y * 0.2 + x


class RRDB(nn.Module):
    def __init__(self, nf, gc):
        super().__init__()
        self.rdbs = nn.Sequential(RDB(nf, gc), RDB(nf, gc), RDB(nf, gc))

    def forward(self, x):
        return self.rdbs(x) * 0.2 + x


class RealESRGAN(nn.Module):
    """Wang et al. 2021's RRDBNet at x2: pixel_unshuffle(2), conv_first, an RRDB, conv_body +
    skip, two nearest 2x interpolations each with conv + LeakyReLU, conv_hr, conv_last."""

    def __init__(self, nf=12, gc=6):
        super().__init__()
        self.conv_first = nn.Conv2d(12, nf, 3, padding=1)
        self.body = RRDB(nf, gc)
        self.conv_body = nn.Conv2d(nf, nf, 3, padding=1)
        self.conv_up1 = nn.Conv2d(nf, nf, 3, padding=1)
        self.conv_up2 = nn.Conv2d(nf, nf, 3, padding=1)
        self.conv_hr = nn.Conv2d(nf, nf, 3, padding=1)
        self.conv_last = nn.Conv2d(nf, 3, 3, padding=1)
        self.lrelu = nn.LeakyReLU(0.2, True)

    def forward(self, x):
        f = self.conv_first(F.pixel_unshuffle(x, 2))
        f = f + self.conv_body(self.body(f))
        f = self.lrelu(self.conv_up1(F.interpolate(f, scale_factor=2.0, mode="nearest")))
        f = self.lrelu(self.conv_up2(F.interpolate(f, scale_factor=2.0, mode="nearest")))
        return self.conv_last(self.lrelu(self.conv_hr(f)))


class NormBlocks(nn.Module):
    """Normalisation layers of style-transfer and diffusion-style blocks: conv, InstanceNorm2d
    (affine), ReLU; conv, GroupNorm(4 groups), SiLU; conv, plus the input."""

    def __init__(self, n=16):
        super().__init__()
        self.conv1 = nn.Conv2d(3, n, 3, padding=1)
        self.inorm = nn.InstanceNorm2d(n, affine=True)
        self.conv2 = nn.Conv2d(n, n, 3, padding=1)
        self.gnorm = nn.GroupNorm(4, n)
        self.conv3 = nn.Conv2d(n, 3, 3, padding=1)
        with torch.no_grad():
            for nrm in (self.inorm, self.gnorm):
                nrm.weight.uniform_(0.7, 1.3)
                nrm.bias.uniform_(-0.1, 0.1)

    def forward(self, x):
        y = F.relu(self.inorm(self.conv1(x)))
        y = F.silu(self.gnorm(self.conv2(y)))
        return self.conv3(y) + x


class LayerNorm2d(nn.Module):
    """ConvNeXt's channels-first LayerNorm, written out: mean, (x - u)^2 mean, sqrt (the
    exporters keep it as ReduceMean, Sub, Pow, Add, Sqrt, Div)."""

    def __init__(self, c, eps=1e-6):
        super().__init__()
        self.weight = nn.Parameter(torch.empty(c).uniform_(0.7, 1.3))
        self.bias = nn.Parameter(torch.empty(c).uniform_(-0.1, 0.1))
        self.eps = eps

    def forward(self, x):
        u = x.mean(1, keepdim=True)
        s = (x - u).pow(2).mean(1, keepdim=True)
        x = (x - u) / torch.sqrt(s + self.eps)
        return self.weight[:, None, None] * x + self.bias[:, None, None]


class ConvNeXtBlock(nn.Module):
    """Liu et al. 2022: depthwise 7x7, permute to channels-last, LayerNorm, Linear 4x, GELU,
    Linear, layer scale, permute back, residual."""

    def __init__(self, c):
        super().__init__()
        self.dwconv = nn.Conv2d(c, c, 7, padding=3, groups=c)
        self.norm = nn.LayerNorm(c, eps=1e-6)
        self.pwconv1, self.act, self.pwconv2 = nn.Linear(c, 4 * c), nn.GELU(), nn.Linear(4 * c, c)
        self.gamma = nn.Parameter(torch.empty(c).uniform_(0.3, 1.0))

    def forward(self, x):
        y = self.dwconv(x).permute(0, 2, 3, 1)
        y = self.pwconv2(self.act(self.pwconv1(self.norm(y))))
        return x + (self.gamma * y).permute(0, 3, 1, 2)


class ConvNeXt(nn.Module):
    """ConvNeXt, small: stem conv 2x2 stride 2 + LayerNorm2d, a block, downsampling
    (LayerNorm2d, conv 2x2 stride 2), a block, global mean over H and W, LayerNorm, Linear.
    Outputs the features and the logits."""

    def __init__(self, dims=(16, 24), classes=10):
        super().__init__()
        self.stem = nn.Sequential(nn.Conv2d(3, dims[0], 2, stride=2), LayerNorm2d(dims[0]))
        self.stage1 = ConvNeXtBlock(dims[0])
        self.down = nn.Sequential(LayerNorm2d(dims[0]), nn.Conv2d(dims[0], dims[1], 2, stride=2))
        self.stage2 = ConvNeXtBlock(dims[1])
        self.norm = nn.LayerNorm(dims[1], eps=1e-6)
        self.head = nn.Linear(dims[1], classes)

    def forward(self, x):
        f = self.stage2(self.down(self.stage1(self.stem(x))))
        return f, self.head(self.norm(f.mean([-2, -1])))


class MobileNetV2(nn.Module):
    """Sandler et al. 2018, small: conv s2 + BN + ReLU6 (Clip), inverted residuals with
    ReLU6 (expand 1x1, depthwise 3x3, linear project 1x1), residual, 1x1 head + ReLU6."""

    def __init__(self):
        super().__init__()

        def block(cin, exp, cout, stride):
            return InvertedResidual(cin, exp, cout, 3, stride, False, nn.ReLU6)
        self.stem = nn.Sequential(nn.Conv2d(3, 16, 3, 2, 1, bias=False), nn.BatchNorm2d(16), nn.ReLU6(True))
        self.blocks = nn.Sequential(block(16, 48, 16, 1), block(16, 48, 24, 2), block(24, 72, 24, 1))
        self.head = nn.Sequential(nn.Conv2d(24, 32, 1, bias=False), nn.BatchNorm2d(32), nn.ReLU6(True))
        _randomise_bn(self)

    def forward(self, x):
        return self.head(self.blocks(self.stem(x)))


class UpPad(nn.Module):
    """milesial/Pytorch-UNet's Up: bilinear 2x, pad to the skip's size (the pads computed
    from the two shapes), concatenate, double conv."""

    def __init__(self, cin, cskip, cout):
        super().__init__()
        self.up = nn.Upsample(scale_factor=2, mode="bilinear", align_corners=True)
        self.conv = nn.Sequential(*_conv_bn_relu(cin + cskip, cout), *_conv_bn_relu(cout, cout))

    def forward(self, x1, x2):
        x1 = self.up(x1)
        dy, dx = x2.size()[2] - x1.size()[2], x2.size()[3] - x1.size()[3]
        x1 = F.pad(x1, [dx // 2, dx - dx // 2, dy // 2, dy - dy // 2])
        return self.conv(torch.cat([x2, x1], 1))


class UNetPad(nn.Module):
    """The U-Net of milesial/Pytorch-UNet, small and for any size: the decoder pads each
    upsized map to its skip's odd size, the pads computed from the shapes at run time
    (exported with dynamic height and width: Shape, Sub, Div, Concat into Pad)."""

    def __init__(self, c=8):
        super().__init__()
        self.inc = nn.Sequential(*_conv_bn_relu(3, c), *_conv_bn_relu(c, c))
        self.down1 = nn.Sequential(nn.MaxPool2d(2), *_conv_bn_relu(c, 2 * c), *_conv_bn_relu(2 * c, 2 * c))
        self.down2 = nn.Sequential(nn.MaxPool2d(2), *_conv_bn_relu(2 * c, 2 * c), *_conv_bn_relu(2 * c, 2 * c))
        self.up1 = UpPad(2 * c, 2 * c, c)
        self.up2 = UpPad(c, c, c)
        self.outc = nn.Conv2d(c, 2, 1)
        _randomise_bn(self)

    def forward(self, x):
        x1 = self.inc(x)
        x2 = self.down1(x1)
        x3 = self.down2(x2)
        return self.outc(self.up2(self.up1(x3, x2), x1))


# --- the suite -----------------------------------------------------------------------------

@dataclass
class Input:
    name: str
    shape: tuple
    low: float = 0.0          # the test's seeded inputs: uniform [low, high), or normal(0, std)
    high: float = 1.0
    std: float = 0.0          # > 0: normal

    def sample(self, rng):
        if self.std > 0:
            return rng.normal(0.0, self.std, self.shape).astype(np.float32)
        return rng.uniform(self.low, self.high, self.shape).astype(np.float32)


@dataclass
class Arch:
    name: str
    make: object              # () -> nn.Module
    inputs: list
    outputs: list
    seed: int
    about: str
    dynamic_hw: bool = False  # height and width dynamic (the conv SR models: bench/exported.py)
    hw_multiple: int = 1      # dynamic height and width must be multiples of this
    tags: list = field(default_factory=list)


SR_SIZE = (1, 3, 23, 37)      # odd sizes: every conv SR model runs at them


def architectures() -> list[Arch]:
    h, w = SR_SIZE[2:]
    return [
        Arch("espcn", ESPCN, [Input("x", SR_SIZE)], ["y"], 1,
             "ESPCN x2: conv + tanh, PixelShuffle", dynamic_hw=True, tags=["conv-sr"]),
        Arch("fsrcnn", FSRCNN, [Input("x", (1, 1, h, w))], ["y"], 2,
             "FSRCNN x2 (luma): PReLU, ConvTranspose 9x9 stride 2", dynamic_hw=True, tags=["conv-sr"]),
        Arch("edsr", EDSR, [Input("x", SR_SIZE)], ["y"], 3,
             "EDSR x2: mean shift, 3 residual blocks (x0.1), conv + PixelShuffle", dynamic_hw=True,
             tags=["conv-sr"]),
        Arch("rcan", RCAN, [Input("x", SR_SIZE)], ["y"], 4,
             "RCAN x2: residual group of 2 RCABs with channel attention (AdaptiveAvgPool2d(1), "
             "1x1 conv, ReLU, 1x1 conv, Sigmoid, Mul)", dynamic_hw=True, tags=["conv-sr"]),
        Arch("realesrgan", RealESRGAN, [Input("x", (1, 3, 26, 38))], ["y"], 5,
             "Real-ESRGAN x2 (RRDBNet): pixel_unshuffle, an RRDB of 3 dense blocks, nearest 2x "
             "upsizing twice", dynamic_hw=True, hw_multiple=2, tags=["conv-sr"]),
        Arch("unet_bn", UNetBN, [Input("x", (1, 3, 28, 44))], ["y"], 6,
             "U-Net, 2 levels, BatchNorm (eval): MaxPool, ConvTranspose and bilinear Upsample, "
             "skip concat"),
        Arch("mobilenetv3", MobileNetV3, [Input("x", SR_SIZE)], ["features", "logits"], 7,
             "MobileNetV3 blocks: depthwise convs, Hardswish, squeeze-excite with Hardsigmoid, "
             "Linear classifier"),
        Arch("swinir", lambda: SwinIR((h, w)), [Input("x", SR_SIZE)], ["y"], 8,
             "SwinIR block pair: reflect pad to the window, LayerNorm, window attention (Q K^T, "
             "relative position bias, shifted-window mask via torch.roll), softmax, GELU MLP"),
        Arch("basicvsr", BasicVSRStep,
             [Input("lr", SR_SIZE), Input("feat", (1, 16, h, w), std=0.5),
              Input("flow", (1, 2, h, w), low=-3.0, high=3.0)], ["y", "feat_out"], 9,
             "BasicVSR propagation step: flow_warp (grid from the flow, grid_sample), residual "
             "blocks, PixelShuffle upsampler over bilinear upsizing"),
        Arch("convlstm", ConvLSTMCell,
             [Input("x", SR_SIZE), Input("h", (1, 8, h, w), std=0.5), Input("c", (1, 8, h, w), std=0.5)],
             ["h_out", "c_out"], 10, "ConvLSTM cell: conv of cat(x, h), chunk into 4 gates"),
        Arch("norms", NormBlocks, [Input("x", SR_SIZE)], ["y"], 11,
             "InstanceNorm2d (affine) + ReLU, GroupNorm(4) + SiLU, residual"),
        Arch("convnext", ConvNeXt, [Input("x", SR_SIZE)], ["features", "logits"], 12,
             "ConvNeXt: channels-first LayerNorm written out (mean, pow, sqrt), depthwise 7x7, "
             "channels-last LayerNorm, GELU MLP, layer scale, mean over H and W"),
        Arch("mobilenetv2", MobileNetV2, [Input("x", SR_SIZE)], ["y"], 13,
             "MobileNetV2 blocks: ReLU6 (Clip), depthwise convs, linear bottleneck, BatchNorm"),
        Arch("unet_pad", UNetPad, [Input("x", SR_SIZE)], ["y"], 14,
             "U-Net for any size (milesial): bilinear 2x, pads to the skip's odd size computed "
             "from the shapes, dynamic height and width", dynamic_hw=True, tags=["shape-computed"]),
    ]


def _dims(arch):
    """Each input's symbolic axes: {axis: name} (height and width of the 4-D image-sized
    inputs when the architecture exports them dynamic)."""
    if not arch.dynamic_hw:
        return {i.name: {} for i in arch.inputs}
    return {i.name: ({2: "height", 3: "width"} if len(i.shape) == 4 else {}) for i in arch.inputs}


def _export(arch, exporter, path):
    torch.manual_seed(arch.seed)
    model = arch.make().eval()
    rng = np.random.default_rng(arch.seed)
    args = tuple(torch.from_numpy(i.sample(rng)) for i in arch.inputs)
    names = [i.name for i in arch.inputs]
    dims = _dims(arch)
    with torch.no_grad():
        if exporter == "torchscript":
            torch.onnx.export(model, args, path, dynamo=False, opset_version=TORCHSCRIPT_OPSET,
                              input_names=names, output_names=arch.outputs,
                              dynamic_axes={k: v for k, v in dims.items() if v} or None)
        else:
            from torch.export import Dim
            shapes = None
            if arch.dynamic_hw:
                m = arch.hw_multiple
                hd = Dim("height_q") * m if m > 1 else Dim("height", min=8)
                wd = Dim("width_q") * m if m > 1 else Dim("width", min=8)
                shapes = {k: ({2: hd, 3: wd} if v else None) for k, v in dims.items()}
            torch.onnx.export(model, args, path, dynamo=True, input_names=names,
                              output_names=arch.outputs, dynamic_shapes=shapes, verbose=False)
    m = onnx.load(path, load_external_data=False)
    if m.ir_version > MAX_IR_VERSION:
        m.ir_version = MAX_IR_VERSION
    onnx.save(m, path)       # the external data, if any, stays where the exporter wrote it
    return model, args


def _sha256(path):
    with open(path, "rb") as fh:
        return hashlib.sha256(fh.read()).hexdigest()


def _entry(arch, exporter, out, stem):
    m = onnx.load(os.path.join(out, stem + ".onnx"), load_external_data=False)
    files = sorted(f for f in os.listdir(out) if f == stem + ".onnx" or f.startswith(stem + ".onnx."))

    def dims(v):
        return [d.dim_param or d.dim_value for d in v.type.tensor_type.shape.dim]
    declared = {v.name: dims(v) for v in m.graph.input}
    missing = [i.name for i in arch.inputs if i.name not in declared]
    if missing:
        raise ValueError(f"{stem}: the export lost inputs {missing} (has {sorted(declared)})")
    return {
        "name": stem, "arch": arch.name, "exporter": exporter, "about": arch.about,
        "file": stem + ".onnx", "files": {f: {"bytes": os.path.getsize(os.path.join(out, f)),
                                             "sha256": _sha256(os.path.join(out, f))} for f in files},
        "opset": next(o.version for o in m.opset_import if o.domain in ("", "ai.onnx")),
        "ir_version": m.ir_version,
        "inputs": [{"name": i.name, "shape": list(i.shape), "declared": declared[i.name],
                    **({"std": i.std} if i.std > 0 else {"low": i.low, "high": i.high})}
                   for i in arch.inputs],
        "outputs": [{"name": v.name, "declared": dims(v)} for v in m.graph.output],
        "dynamic_hw": arch.dynamic_hw, "hw_multiple": arch.hw_multiple, "tags": list(arch.tags),
        "seed": arch.seed,
    }


def export_suite(out, names=None, exporters=EXPORTERS, log=print):
    """Export every architecture (or those named) with every exporter into a fresh OUT
    (written next to it, then moved into place) with its manifest. Returns the manifest."""
    try:
        import onnxscript  # noqa: F401  (the dynamo exporter's)
    except ModuleNotFoundError:
        if "dynamo" in exporters:
            raise ValueError("the dynamo exporter needs onnxscript (pip install -e '.[train]')") from None
    archs = [a for a in architectures() if names is None or a.name in names]
    unknown = set(names or ()) - {a.name for a in archs}
    if unknown:
        raise ValueError(f"unknown architectures {sorted(unknown)}; known: "
                         + ", ".join(a.name for a in architectures()))
    out = os.path.normpath(out)
    tmp = out + ".partial"
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)
    entries = []
    import logging
    import warnings
    logging.getLogger("torch.onnx").setLevel(logging.ERROR)    # "torchvision is not installed"
    for arch in archs:
        for exporter in exporters:
            stem = f"{arch.name}_{exporter}"
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                _export(arch, exporter, os.path.join(tmp, stem + ".onnx"))
            e = _entry(arch, exporter, tmp, stem)
            entries.append(e)
            log(f"{stem:28s} opset {e['opset']:2d}  ir {e['ir_version']:2d}  "
                + "  ".join(f"{f} {v['bytes'] / 1024:.1f} KiB" for f, v in e["files"].items()))
    manifest = {"about": "exported-model fixtures (weights_tools/export_suite.py; make export-fixtures)",
                "torch": torch.__version__, "onnx": onnx.__version__,
                "torchscript_opset": TORCHSCRIPT_OPSET, "max_ir_version": MAX_IR_VERSION,
                "models": entries}
    with open(os.path.join(tmp, MANIFEST), "w") as fh:
        json.dump(manifest, fh, indent=1)
        fh.write("\n")
    shutil.rmtree(out, ignore_errors=True)
    os.replace(tmp, out)
    return manifest


def add_parser(sub):
    p = sub.add_parser("export-suite", help="export the exported-model suite (small PyTorch SR, vision "
                       "and temporal architectures, both torch exporters) with its manifest")
    p.add_argument("--out", required=True, help="directory to (re)write: every file in it is replaced")
    p.add_argument("--arch", help="comma-separated architectures (default all: "
                   + ", ".join(a.name for a in architectures()) + ")")
    p.add_argument("--exporters", default=",".join(EXPORTERS), help="comma-separated: torchscript,dynamo")
    p.set_defaults(fn=cmd_export_suite)


def cmd_export_suite(args):
    exporters = tuple(e for e in args.exporters.split(",") if e)
    bad = [e for e in exporters if e not in EXPORTERS]
    if bad:
        raise ValueError(f"unknown exporters {bad}; known: {', '.join(EXPORTERS)}")
    names = args.arch.split(",") if args.arch else None
    m = export_suite(args.out, names, exporters)
    total = sum(v["bytes"] for e in m["models"] for v in e["files"].values())
    print(f"wrote {len(m['models'])} models ({total / 1024:.0f} KiB) and {MANIFEST} to {args.out}")
    return 0

