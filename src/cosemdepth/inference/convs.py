"""Pre-packed 3x3 convolutions for inference: channels-last weights, a chosen dtype and the LeakyReLU fused in.

On CPU the convolution and its activation run as one oneDNN primitive (``torch.ops.mkldnn._convolution_pointwise``,
the kernel torch.compile's CPU backend uses), with the weight reordered once per input shape into oneDNN's blocked
layout. Elsewhere (CUDA, or a PyTorch build without oneDNN) it is ``F.conv2d`` followed by an in-place LeakyReLU.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ..models.layers import NEGATIVE_SLOPE
from ..ops.conv import has_mkldnn_pointwise
from ..ops.padding import Conv2dSame, same_padding

_CL = torch.channels_last


HAS_MKLDNN_POINTWISE = has_mkldnn_pointwise()


class PackedConv:
    """A frozen copy of one :class:`Conv2dSame` (TF "same" padding) for inference.

    Args:
        conv: the source convolution (its parameters are copied, not referenced).
        dtype: compute dtype of this convolution (float32, bfloat16 or float16); the input is cast to it.
        device: where the copy lives.
        act: apply LeakyReLU(0.1) to the output.
        use_mkldnn: use the fused oneDNN kernel on CPU when available (default: when available).
    Call with ``x [B, C_in, H, W]`` (any memory format; channels-last avoids a copy); returns
    ``[B, C_out, H', W']`` channels-last in ``dtype``.
    """

    def __init__(
        self,
        conv: Conv2dSame,
        dtype: torch.dtype,
        device: torch.device,
        act: bool,
        use_mkldnn: bool | None = None,
    ):
        self.weight = conv.weight.detach().to(device=device, dtype=dtype).contiguous(memory_format=_CL)
        self.bias = None if conv.bias is None else conv.bias.detach().to(device=device, dtype=dtype).contiguous()
        self.kernel = conv.kernel_size[0]
        self.stride = conv.stride[0]
        self.symmetric = conv.symmetric
        self.act = act
        self.dtype = dtype
        self.device = torch.device(device)
        supported = dtype in (torch.float32, torch.bfloat16)
        if use_mkldnn is None:  # by default where built in and not switched off (torch.backends.mkldnn.flags)
            use_mkldnn = HAS_MKLDNN_POINTWISE and torch.backends.mkldnn.enabled
        self.use_mkldnn = use_mkldnn and supported
        self._packed: dict[tuple[int, ...], torch.Tensor] = {}

    def _pad(self, x: torch.Tensor) -> tuple[torch.Tensor, int]:
        if self.symmetric:
            return x, self.kernel // 2
        top, bottom = same_padding(x.shape[-2], self.kernel, self.stride)
        left, right = same_padding(x.shape[-1], self.kernel, self.stride)
        if top == bottom and left == right and top == left:
            return x, top
        return F.pad(x, (left, right, top, bottom)), 0

    def _packed_weight(self, shape: tuple[int, ...], padding: int) -> torch.Tensor:
        key = (*shape, padding)
        w = self._packed.get(key)
        if w is None:
            try:
                w = torch._C._nn.mkldnn_reorder_conv2d_weight(
                    self.weight.to_mkldnn(), [padding] * 2, [self.stride] * 2, [1, 1], 1, list(shape)
                )
            except (RuntimeError, AttributeError, NotImplementedError):
                w = self.weight
            self._packed[key] = w
        return w

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        if x.dtype != self.dtype:
            x = x.to(self.dtype)
        x = x.contiguous(memory_format=_CL)
        x, padding = self._pad(x)
        if self.use_mkldnn and x.device.type == "cpu":
            w = self._packed_weight(tuple(x.shape), padding)
            attr, scalars = ("leaky_relu", [NEGATIVE_SLOPE]) if self.act else ("none", [])
            return torch.ops.mkldnn._convolution_pointwise(
                x, w, self.bias, [padding] * 2, [self.stride] * 2, [1, 1], 1, attr, scalars, ""
            )
        y = F.conv2d(x, self.weight, self.bias, stride=self.stride, padding=padding)
        return F.leaky_relu_(y, NEGATIVE_SLOPE) if self.act else y
