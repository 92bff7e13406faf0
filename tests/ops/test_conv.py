"""ops.conv.conv_lrelu: the fused convolution + LeakyReLU gives the plain ops' outputs and gradients."""

import pytest
import torch
import torch.nn.functional as F

import cosemdepth.ops.conv as conv_ops
from cosemdepth.ops.conv import conv_lrelu
from cosemdepth.ops.padding import Conv2dSame

SLOPE = 0.1


def plain(x, conv):
    return F.leaky_relu(conv(x), SLOPE)


def grads(fn, x, conv, g):
    x = x.detach().clone().requires_grad_()
    conv.zero_grad(set_to_none=True)
    y = fn(x, conv)
    y.backward(g)
    return y.detach(), x.grad, conv.weight.grad.clone(), conv.bias.grad.clone()


@pytest.mark.parametrize("stride,size", [(1, 9), (2, 10), (2, 9)])
@pytest.mark.parametrize("channels_last", [False, True])
def test_fused_equals_plain_fp32(stride, size, channels_last):
    torch.manual_seed(0)
    conv = Conv2dSame(5, 7, 3, stride=stride)
    x = torch.randn(2, 5, size, size + 1)
    if channels_last:
        conv = conv.to(memory_format=torch.channels_last)
        x = x.contiguous(memory_format=torch.channels_last)
    out_h = -(-size // stride)
    g = torch.randn(2, 7, out_h, -(-(size + 1) // stride))
    ref = grads(plain, x, conv, g)
    got = grads(lambda x, c: conv_lrelu(x, c, SLOPE), x, conv, g)
    if conv_ops._FUSED:  # this build has oneDNN's fused kernel: the fused form ran
        assert "ConvLReLU" in conv_lrelu(x.requires_grad_(), conv, SLOPE).grad_fn.name()
    assert (ref[0] < 0).any() and (ref[0] > 0).any()  # both branches of the activation are exercised
    for r, o in zip(ref, got):
        assert o.shape == r.shape
        torch.testing.assert_close(o, r, rtol=1e-5, atol=1e-6)


def test_backward_uses_the_activation_slope():
    """Hand-computed: a 1x1 map through a 3x3 kernel of ones sees only the centre tap."""
    conv = Conv2dSame(1, 1, 3)
    with torch.no_grad():
        conv.weight.fill_(1.0)
        conv.bias.fill_(0.0)
    for value, slope_grad in ((2.0, 1.0), (-2.0, SLOPE)):
        x = torch.full((1, 1, 1, 1), value, requires_grad=True)
        conv.zero_grad(set_to_none=True)
        y = conv_lrelu(x, conv, SLOPE)
        assert y.item() == pytest.approx(value if value > 0 else SLOPE * value)
        y.sum().backward()
        assert x.grad.item() == pytest.approx(slope_grad)
        assert conv.weight.grad[0, 0, 1, 1].item() == pytest.approx(slope_grad * value)
        assert conv.bias.grad.item() == pytest.approx(slope_grad)


def test_bf16_autocast_keeps_fp32_master_weights(bf16_cpu):
    torch.manual_seed(1)
    conv = Conv2dSame(8, 8, 3)
    x = torch.randn(1, 8, 12, 12)
    g = torch.randn(1, 8, 12, 12)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        ref_y = plain(x, conv)
    ref_y.float().backward(g.to(ref_y.dtype).float())
    ref = conv.weight.grad.clone()
    conv.zero_grad(set_to_none=True)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        y = conv_lrelu(x, conv, SLOPE)
    assert y.dtype == ref_y.dtype == torch.bfloat16
    y.float().backward(g.to(y.dtype).float())
    assert conv.weight.grad.dtype == torch.float32
    torch.testing.assert_close(y.float(), ref_y.float(), rtol=2e-2, atol=2e-2)
    torch.testing.assert_close(conv.weight.grad, ref, rtol=2e-2, atol=5e-2)


def test_plain_ops_when_fusion_is_off(monkeypatch):
    monkeypatch.setattr(conv_ops, "_FUSED", False)
    conv = Conv2dSame(3, 4, 3)
    x = torch.randn(1, 3, 6, 6, requires_grad=True)
    y = conv_lrelu(x, conv, SLOPE)
    assert y.grad_fn.name().startswith("LeakyRelu")
    torch.testing.assert_close(y, plain(x, conv))
