"""Building blocks shared by the encoder and both decoders."""

from __future__ import annotations

import math

import torch
import torch.nn as nn
import torch.nn.functional as F

from ..ops.conv import conv_lrelu
from ..ops.padding import Conv2dSame

#: LeakyReLU slope used everywhere in the original (encoder, refiners, SNCV).
NEGATIVE_SLOPE = 0.1

#: Keras HeNormal draws from a normal truncated at 2 std, rescaled by this constant to keep the variance 2 / fan_in.
_TRUNCATED_NORMAL_STD = 0.87962566103423978


def lrelu(x: torch.Tensor) -> torch.Tensor:
    return F.leaky_relu(x, NEGATIVE_SLOPE)


def he_normal_(conv: nn.Conv2d) -> None:
    """Keras ``HeNormal`` kernel init (truncated normal, std sqrt(2 / fan_in) / 0.8796...) and zero bias."""
    fan_in = conv.in_channels * conv.kernel_size[0] * conv.kernel_size[1]
    std = math.sqrt(2.0 / fan_in) / _TRUNCATED_NORMAL_STD
    nn.init.trunc_normal_(conv.weight, mean=0.0, std=std, a=-2 * std, b=2 * std)
    if conv.bias is not None:
        nn.init.zeros_(conv.bias)


def conv3x3(in_channels: int, out_channels: int, stride: int = 1) -> Conv2dSame:
    conv = Conv2dSame(in_channels, out_channels, 3, stride=stride)
    he_normal_(conv)
    return conv


class Refiner(nn.Module):
    """The seven-convolution estimator stack of both decoders (design 5.5.6 and 6.1).

    ``in -> 128 -> 128 -> 96 -> 64 -> 32 -> 16 -> out``, 3x3 "same" convolutions, LeakyReLU(0.1) after all but the last.
    Parameters: ``1152 C_in + 336,848 + 145 C_out``.
    """

    HIDDEN = (128, 128, 96, 64, 32, 16)

    def __init__(self, in_channels: int, out_channels: int):
        super().__init__()
        chans = (in_channels, *self.HIDDEN, out_channels)
        self.convs = nn.ModuleList(conv3x3(chans[k], chans[k + 1]) for k in range(len(chans) - 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        last = len(self.convs) - 1
        for k, conv in enumerate(self.convs):
            x = conv_lrelu(x, conv, NEGATIVE_SLOPE) if k < last else conv(x)
        return x
