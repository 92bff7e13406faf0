"""ops.normalize.grouped_l2_normalize: values by hand, and its hand-written backward against finite differences and
autograd through the plain ops."""

import torch

from cosemdepth.ops.normalize import NORM_SQ_EPS, grouped_l2_normalize


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
