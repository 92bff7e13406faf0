"""TensorFlow "same" padding (design 3.5).

For a 3x3 convolution with stride 1 the padding is 1 on every side (PyTorch ``padding=1``). For stride 2 TF pads
``pad_total = max((ceil(n / s) - 1) * s + k - n, 0)`` split as ``floor(pad_total / 2)`` before and the rest after:
0 before and 1 after for an even size, 1 and 1 for an odd size.
"""

from __future__ import annotations

import math

import torch
import torch.nn as nn
import torch.nn.functional as F


def same_padding(n: int, kernel: int = 3, stride: int = 1, dilation: int = 1) -> tuple[int, int]:
    """(pad_before, pad_after) of TF "same" padding along one axis of size ``n``."""
    k = (kernel - 1) * dilation + 1
    total = max((math.ceil(n / stride) - 1) * stride + k - n, 0)
    return total // 2, total - total // 2


class Conv2dSame(nn.Conv2d):
    """``nn.Conv2d`` with TF "same" padding, including TF's asymmetric padding for stride 2.

    The weight layout is PyTorch's ``[C_out, C_in, kH, kW]``; a TF kernel ``[kH, kW, C_in, C_out]`` converts with
    ``permute(3, 2, 0, 1)``.
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int = 3, stride: int = 1, bias: bool = True):
        self.symmetric = stride == 1 and kernel_size % 2 == 1
        super().__init__(
            in_channels,
            out_channels,
            kernel_size,
            stride=stride,
            padding=kernel_size // 2 if self.symmetric else 0,
            bias=bias,
        )

    def prepad(self, x: torch.Tensor) -> torch.Tensor:
        """``x`` padded as TF pads it where the convolution's own (symmetric) padding cannot."""
        if not self.symmetric:
            k, s = self.kernel_size[0], self.stride[0]
            top, bottom = same_padding(x.shape[-2], k, s)
            left, right = same_padding(x.shape[-1], k, s)
            x = F.pad(x, (left, right, top, bottom))
        return x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return super().forward(self.prepad(x))
