"""ops.normalize: grouped_l2_normalize's values by hand and its hand-written backward against finite differences and
autograd through the plain ops; DINL against float64 on extreme ranges, both memory formats, bfloat16 inputs."""

import pytest
import torch

from cosemdepth.ops.normalize import DINL_NORM_MIN, DINL_VAR_EPS, NORM_SQ_EPS, dinl, grouped_l2_normalize


def plain(x, groups, guard=True):
    b, c, h, w = x.shape
    g = x.reshape(b, groups, c // groups, h, w)
    sq = (g * g).sum(dim=2, keepdim=True)
    if guard:
        sq = sq.clamp_min(NORM_SQ_EPS)
    return (g / torch.sqrt(sq)).reshape(b, c, h, w)


def test_values_by_hand():
    x = torch.tensor([3.0, 4.0, 0.0, 2.0]).view(1, 4, 1, 1)
    y = grouped_l2_normalize(x, 2)
    torch.testing.assert_close(y.flatten(), torch.tensor([0.6, 0.8, 0.0, 1.0]))
    z = grouped_l2_normalize(torch.zeros(1, 2, 1, 1, requires_grad=True), 1)  # guarded all-zero group: 0, no NaN
    assert z.flatten().tolist() == [0.0, 0.0]


def test_backward_is_the_gradient():
    torch.manual_seed(0)
    x = torch.randn(2, 6, 3, 4, dtype=torch.float64, requires_grad=True)
    for groups in (1, 2, 3):
        assert torch.autograd.gradcheck(lambda t: grouped_l2_normalize(t, groups), (x,))
        assert torch.autograd.gradcheck(lambda t: grouped_l2_normalize(t, groups, guard=False), (x,))


def test_backward_matches_plain_ops_channels_last_and_guarded_zeros():
    torch.manual_seed(1)
    x = torch.randn(2, 8, 5, 6).contiguous(memory_format=torch.channels_last)
    x[0, :4, 1, 2] = 0.0  # one all-zero group: guarded, its gradient is dy / sqrt(eps) there as in the plain ops
    g = torch.randn(2, 8, 5, 6)
    grads = []
    for fn in (grouped_l2_normalize, plain):
        xi = x.clone().requires_grad_()
        y = fn(xi, 2)
        y.backward(g)
        grads.append((y.detach(), xi.grad))
    assert torch.equal(grads[0][0], grads[1][0])  # the same forward ops
    assert grads[0][1][0, :4, 1, 2].abs().max() > 1e10  # the guarded group's gradient, 1 / sqrt(eps) scale
    torch.testing.assert_close(grads[0][1], grads[1][1], rtol=1e-5, atol=1e-5)


# --- DINL -------------------------------------------------------------------------------------------------------


def dinl_float64(x, weight, bias):
    """Design 4.2 in float64 with torch's own ops (the hand check): ``z = (x - mean) / (var + 1e-12)``, ``n = z /
    max(|z|, 1e-6)`` with ``|z|`` the L2 norm over the channels, ``weight * n + bias``."""
    x = x.double()
    d = x - x.mean(dim=(2, 3), keepdim=True)
    z = d / ((d * d).mean(dim=(2, 3), keepdim=True) + DINL_VAR_EPS)
    n = z / torch.linalg.vector_norm(z, dim=1, keepdim=True).clamp_min(DINL_NORM_MIN)
    return n * weight.double().view(1, -1, 1, 1) + bias.double().view(1, -1, 1, 1)


def extreme_dinl_input():
    """``[2, 6, 9, 11]`` float32 whose channels' variances span 1e-14 to 1e8 (``1 / (var + 1e-12)`` from 1e12 to
    1e-8, so ``|z|`` from about 1e-4 to 1e6 at once), one channel constant (``z = 0``), and pixels where every
    channel is at its mean (``|z| = 0`` < the 1e-6 floor)."""
    g = torch.Generator().manual_seed(11)
    scales = torch.tensor([1e-7, 1e-3, 1.0, 1e4, 0.0, 3e-2]).view(1, 6, 1, 1)
    x = torch.randn(2, 6, 9, 11, generator=g, dtype=torch.float64) * scales + torch.tensor(
        [0.0, -2e-3, 0.0, 1e4, 3.0, 0.05]
    ).view(1, 6, 1, 1)
    x = x.float()
    x[:, :, 4, 5] = x.double().mean(dim=(2, 3))[:, :].float()  # at the mean in every channel (up to rounding)
    return x


@pytest.mark.parametrize("fmt", [torch.contiguous_format, torch.channels_last], ids=["nchw", "channels_last"])
def test_dinl_equals_float64_on_extreme_ranges_forward_and_backward(fmt):
    x0 = extreme_dinl_input()
    w = torch.tensor([1.0, -2.0, 0.5, 3.0, 1.5, -1.0])
    b = torch.tensor([0.1, 0.0, -1.0, 2.0, 0.3, 0.0])
    gy = torch.randn(x0.shape, generator=torch.Generator().manual_seed(12))
    # the hand check: float64 values and gradients; the ranges are as claimed
    x64 = x0.double().requires_grad_()
    w64, b64 = w.double().requires_grad_(), b.double().requires_grad_()
    want = dinl_float64(x64, w64, b64)
    want_gx, want_gw, want_gb = torch.autograd.grad((want * gy.double()).sum(), (x64, w64, b64))
    d = x0.double() - x0.double().mean(dim=(2, 3), keepdim=True)
    z = d / ((d * d).mean(dim=(2, 3), keepdim=True) + DINL_VAR_EPS)
    zabs = z.abs()[z != 0]
    assert zabs.max() > 1e5 and zabs.min() < 1e-6  # twelve orders of magnitude in one map
    x = x0.contiguous(memory_format=fmt).requires_grad_()
    wp, bp = w.clone().requires_grad_(), b.clone().requires_grad_()
    y = dinl(x, wp, bp)
    gx, gw, gb = torch.autograd.grad((y * gy).sum(), (x, wp, bp))
    with torch.no_grad():  # the inference path (no autograd) gives the same values
        assert torch.equal(dinl(x0.contiguous(memory_format=fmt), w, b), y.detach())
    assert y.dtype == torch.float32 and torch.isfinite(y).all() and torch.isfinite(gx).all()
    torch.testing.assert_close(y.double(), want.detach(), rtol=0, atol=1e-5)
    torch.testing.assert_close(gw.double(), want_gw, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(gb.double(), want_gb, rtol=1e-6, atol=1e-6)
    # dx spans the channels' scales (1 / var): each channel against its own size
    for c in range(x0.shape[1]):
        err = (gx[:, c].double() - want_gx[:, c]).norm() / want_gx[:, c].norm().clamp_min(1e-300)
        assert err < 1e-4 or want_gx[:, c].abs().max() < 1e-300, (c, float(err))


def test_dinl_bfloat16_input_is_computed_in_float32():
    """A bfloat16 map (autocast's convolution output) is normalised in float32 (the parameters' dtype): the values
    and gradients of the bfloat16 values read exactly, against float64."""
    x0 = extreme_dinl_input()[:, 1:4] * 0 + torch.randn(2, 3, 9, 11, generator=torch.Generator().manual_seed(4))
    xb = x0.to(torch.bfloat16)
    w, b = torch.tensor([1.0, -2.0, 0.5]), torch.tensor([0.1, 0.0, -1.0])
    for fmt in (torch.contiguous_format, torch.channels_last):
        x = xb.contiguous(memory_format=fmt).requires_grad_()
        y = dinl(x, w, b)
        assert y.dtype == torch.float32
        torch.testing.assert_close(y.double(), dinl_float64(xb, w, b), rtol=0, atol=2e-6)
        (gx,) = torch.autograd.grad(y.sum() + (y * y).sum(), (x,))
        assert gx.dtype == torch.bfloat16
        x64 = xb.double().requires_grad_()
        y64 = dinl_float64(x64, w, b)
        (want,) = torch.autograd.grad(y64.sum() + (y64 * y64).sum(), (x64,))
        torch.testing.assert_close(gx.double(), want, rtol=1e-2, atol=1e-2 * float(want.abs().max()))
