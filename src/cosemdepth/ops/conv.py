"""A convolution followed by LeakyReLU as one oneDNN primitive, for training and the reference forward.

On the CPU, ``F.leaky_relu(conv(x))`` runs the convolution, writes its output, then reads it again for the
activation, and autograd keeps both maps (the convolution's output for LeakyReLU's backward, the activation for the
next convolution's). :func:`conv_lrelu` runs both in oneDNN's convolution with a LeakyReLU post-op
(``torch.ops.mkldnn._convolution_pointwise``, the kernel of the fast inference engine) and keeps only the activation:
LeakyReLU with a positive slope keeps the sign, so its backward reads the mask from the output
(``leaky_relu_backward(..., self_is_result=True)``), then ``aten.convolution_backward`` gives the input, weight and
bias gradients as autograd's own convolution node would. In float32 the outputs and gradients are the same numbers as
the plain ops (same kernels, the activation applied to the same float32 values).

Under CPU autocast the input, weight and bias are cast to the autocast dtype first (as autocast casts a convolution's
arguments), so bf16 training keeps float32 master weights. Elsewhere (CUDA, no oneDNN, tracing for export, other
dtypes, dilation or groups) the plain ops run.
"""

from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F


def has_mkldnn_pointwise() -> bool:
    """Whether this PyTorch build has oneDNN's fused convolution + post-op kernel (``_convolution_pointwise``)."""
    try:
        return torch.backends.mkldnn.is_available() and hasattr(torch.ops.mkldnn, "_convolution_pointwise")
    except (AttributeError, RuntimeError):  # pragma: no cover - exotic builds
        return False


_FUSED = has_mkldnn_pointwise()


class _ConvLReLU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x, weight, bias, stride: int, padding: int, slope: float):
        y = torch.ops.mkldnn._convolution_pointwise(
            x, weight, bias, [padding] * 2, [stride] * 2, [1, 1], 1, "leaky_relu", [slope], ""
        )
        ctx.save_for_backward(x, weight, y)
        ctx.conf = (stride, padding, slope, bias is not None)
        return y

    @staticmethod
    def backward(ctx, grad):
        x, weight, y = ctx.saved_tensors
        stride, padding, slope, has_bias = ctx.conf
        gz = torch.ops.aten.leaky_relu_backward(grad, y, slope, True)
        mask = [ctx.needs_input_grad[0], ctx.needs_input_grad[1], has_bias and ctx.needs_input_grad[2]]
        gx, gw, gb = torch.ops.aten.convolution_backward(
            gz,
            x,
            weight,
            [weight.shape[0]] if has_bias else None,
            [stride] * 2,
            [padding] * 2,
            [1, 1],
            False,
            [0, 0],
            1,
            mask,
        )
        return gx, gw, gb, None, None, None


def _use_fused(x: torch.Tensor, conv: nn.Conv2d) -> bool:
    return (
        _FUSED
        and x.device.type == "cpu"
        and torch.backends.mkldnn.enabled  # oneDNN switched off (torch.backends.mkldnn.flags): PyTorch's kernels
        and conv.groups == 1
        and conv.dilation == (1, 1)
        and conv.stride[0] == conv.stride[1]
        and conv.padding[0] == conv.padding[1]
        and conv.padding_mode == "zeros"
        and not torch.jit.is_tracing()
        and not torch.jit.is_scripting()
        and not torch.onnx.is_in_onnx_export()
    )


def conv_lrelu(x: torch.Tensor, conv: nn.Conv2d, slope: float) -> torch.Tensor:
    """``F.leaky_relu(conv(x), slope)``, fused on the CPU (see the module doc); ``conv`` may pad ``x`` itself first
    (``prepad``, as :class:`~cosemdepth.ops.padding.Conv2dSame` for TF's asymmetric stride-2 padding)."""
    if not _use_fused(x, conv):
        return F.leaky_relu(conv(x), slope)
    prepad = getattr(conv, "prepad", None)
    if prepad is not None:
        x = prepad(x)
    weight, bias = conv.weight, conv.bias
    if torch.is_autocast_enabled("cpu"):
        dtype = torch.get_autocast_dtype("cpu")
        x, weight = x.to(dtype), weight.to(dtype)
        bias = None if bias is None else bias.to(dtype)
    if x.dtype not in (torch.float32, torch.bfloat16) or weight.dtype != x.dtype:
        return F.leaky_relu(F.conv2d(x, weight, bias, conv.stride, conv.padding), slope)
    return _ConvLReLU.apply(x, weight, bias, conv.stride[0], conv.padding[0], slope)
