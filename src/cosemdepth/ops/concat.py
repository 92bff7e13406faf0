"""A refiner's input: the channel concatenation of its blocks, written once into one buffer.

``torch.cat`` writes the blocks in their promoted dtype and layout, then the first convolution copies the result
again: into channels-last (oneDNN's layout) and, under autocast, into bfloat16. :func:`concat_into` writes every
block straight into one buffer of the dtype and memory format the convolution reads; its backward hands each block
its slice of the gradient in the block's own dtype (as ``torch.cat`` followed by autocast's cast would). The values
are the same as ``torch.cat`` then the cast.
"""

from __future__ import annotations

from typing import Sequence

import torch

_CL = torch.channels_last


def write_blocks(
    blocks: Sequence[torch.Tensor], dtype: torch.dtype, memory_format: torch.memory_format
) -> torch.Tensor:
    """``torch.cat(blocks, 1).to(dtype)`` written once into a new ``[B, C, H, W]`` buffer of ``memory_format``."""
    b, _, h, w = blocks[0].shape
    c = sum(t.shape[1] for t in blocks)
    out = torch.empty((b, c, h, w), dtype=dtype, device=blocks[0].device, memory_format=memory_format)
    k = 0
    for t in blocks:
        out[:, k : k + t.shape[1]].copy_(t)
        k += t.shape[1]
    return out


class _Concat(torch.autograd.Function):
    @staticmethod
    def forward(ctx, dtype, memory_format, *blocks):
        ctx.meta = [(t.shape[1], t.dtype) for t in blocks]
        return write_blocks(blocks, dtype, memory_format)

    @staticmethod
    def backward(ctx, grad):
        out, k = [None, None], 0
        for (c, dtype), need in zip(ctx.meta, ctx.needs_input_grad[2:]):
            out.append(grad[:, k : k + c].to(dtype) if need else None)
            k += c
        return tuple(out)


def _channels_last(t: torch.Tensor) -> bool:
    return t.shape[1] > 1 and t.is_contiguous(memory_format=_CL) and not t.is_contiguous()


def concat_into(blocks: Sequence[torch.Tensor]) -> torch.Tensor:
    """The channel concatenation of 4-D ``blocks`` as a convolution reads it: in the CPU autocast dtype when
    autocast is on (else the promoted dtype), channels-last when a block of several channels is (the model's
    layout; else contiguous). Plain ``torch.cat`` when tracing for export or off the CPU."""
    if blocks[0].device.type != "cpu" or torch.jit.is_tracing() or torch.onnx.is_in_onnx_export():
        return torch.cat(list(blocks), dim=1)
    if torch.is_autocast_enabled("cpu"):
        dtype = torch.get_autocast_dtype("cpu")
    else:
        dtype = blocks[0].dtype
        for t in blocks[1:]:
            dtype = torch.promote_types(dtype, t.dtype)
    fmt = _CL if any(_channels_last(t) for t in blocks) else torch.contiguous_format
    if torch.is_grad_enabled() and any(t.requires_grad for t in blocks):
        return _Concat.apply(dtype, fmt, *blocks)
    return write_blocks(blocks, dtype, fmt)
