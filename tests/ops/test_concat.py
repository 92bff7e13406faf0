"""ops.concat.concat_into: torch.cat's values in the convolution's dtype and layout, gradients per block."""

import torch

from cosemdepth.ops.concat import concat_into

CL = torch.channels_last


def blocks(requires_grad=True):
    torch.manual_seed(0)
    a = torch.randn(2, 3, 4, 5).contiguous(memory_format=CL)
    b = torch.randn(2, 1, 4, 5)
    c = torch.randn(2, 6, 4, 5)  # NCHW, like a cost volume
    return [t.requires_grad_(requires_grad) for t in (a, b, c)]


def test_values_layout_and_gradients_fp32():
    xs = blocks()
    y = concat_into(xs)
    assert torch.equal(y, torch.cat(xs, 1))
    assert y.is_contiguous(memory_format=CL) and y.dtype == torch.float32
    g = torch.arange(y.numel(), dtype=torch.float32).view(y.shape)
    y.backward(g)
    assert (
        torch.equal(xs[0].grad, g[:, :3]) and torch.equal(xs[1].grad, g[:, 3:4]) and torch.equal(xs[2].grad, g[:, 4:])
    )


def test_contiguous_when_no_block_is_channels_last():
    xs = [t.detach().contiguous() for t in blocks(False)]
    y = concat_into(xs)
    assert y.is_contiguous() and torch.equal(y, torch.cat(xs, 1))


def test_autocast_writes_bfloat16_and_returns_each_blocks_dtype():
    xs = blocks()
    xs[1] = xs[1].detach().to(torch.bfloat16).requires_grad_()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        y = concat_into(xs)
    assert y.dtype == torch.bfloat16
    assert torch.equal(y, torch.cat([t.float() for t in xs], 1).to(torch.bfloat16))
    y.float().sum().backward()
    assert [t.grad.dtype for t in xs] == [torch.float32, torch.bfloat16, torch.float32]
    assert all(bool((t.grad == 1).all()) for t in xs)


def test_without_grad_no_graph():
    xs = blocks(False)
    y = concat_into(xs)
    assert y.grad_fn is None and torch.equal(y, torch.cat(xs, 1))
