"""Shared feature-pyramid encoder with DINL (design 4)."""

from __future__ import annotations

import torch
import torch.nn as nn

from ..ops.conv import conv_lrelu
from ..ops.normalize import dinl
from .layers import NEGATIVE_SLOPE, conv3x3, lrelu


def _spatial_mean(x: torch.Tensor) -> torch.Tensor:
    return x.mean(dim=(2, 3), keepdim=True)


class DINL(nn.Module):
    """Domain-invariant normalisation layer exactly as the original codes it (design 4.2).

    Per image and channel: ``z = (x - mean) / (variance + 1e-12)`` (the variance, not the std), then L2
    normalisation across channels per pixel (``max(sum z^2, 1e-12)``), then an affine ``gamma * n + beta``.

    ``spatial_mean`` computes the per-image, per-channel means (``[B,C,H,W] -> [B,C,1,1]``); the default is PyTorch's
    ``mean`` (pairwise summation), computed by :func:`cosemdepth.ops.normalize.dinl` (few passes, hand-written
    backward). ``export --check`` swaps in a sequential float32 summation to measure how much the summation order of
    these long reductions (H x W terms) moves the outputs; then the plain ops below run.
    """

    def __init__(self, channels: int):
        super().__init__()
        self.weight = nn.Parameter(torch.ones(channels))
        self.bias = nn.Parameter(torch.zeros(channels))
        self.spatial_mean = _spatial_mean

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.spatial_mean is _spatial_mean:  # the same sums in few passes, with a hand-written backward
            return dinl(x, self.weight, self.bias)
        mean = self.spatial_mean(x)
        centred = x - mean
        var = self.spatial_mean(centred * centred)
        z = centred / (var + 1e-12)
        n = z / torch.sqrt((z * z).sum(dim=1, keepdim=True).clamp_min(1e-12))
        return n * self.weight.view(1, -1, 1, 1) + self.bias.view(1, -1, 1, 1)


class Encoder(nn.Module):
    """L levels of ``conv3x3 s1 -> (DINL at level 1) -> LReLU -> conv3x3 s2 -> LReLU``.

    Args:
        channels: output channels per level, e.g. ``(16, 32, 64, 96, 128)``.
        dinl: use DINL after the first convolution of level 1.
    Input ``[B, 3, H, W]``; output: list (finest first) of ``[B, C_l, ceil(H / 2^l), ceil(W / 2^l)]``.
    """

    def __init__(self, channels: tuple[int, ...], dinl: bool = True):
        super().__init__()
        ins = (3, *channels[:-1])
        self.conv_s1 = nn.ModuleList(conv3x3(i, o) for i, o in zip(ins, channels))
        self.conv_s2 = nn.ModuleList(conv3x3(o, o, stride=2) for o in channels)
        self.dinl = DINL(channels[0]) if dinl else None

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        feats = []
        for k, (c1, c2) in enumerate(zip(self.conv_s1, self.conv_s2)):
            if k == 0 and self.dinl is not None:
                x = lrelu(self.dinl(c1(x)))
            else:
                x = conv_lrelu(x, c1, NEGATIVE_SLOPE)
            x = conv_lrelu(x, c2, NEGATIVE_SLOPE)
            feats.append(x)
        return feats
