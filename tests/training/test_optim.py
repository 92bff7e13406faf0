"""The training optimizer: Keras 2's Adam update (the original's), checked against the formula by hand."""

import copy
import math

import pytest
import torch

from cosemdepth.errors import ConfigError
from cosemdepth.training.config import TrainConfig
from cosemdepth.training.optim import KerasAdam, make_optimizer


def _run(opt_cls, grads, **kw):
    p = torch.nn.Parameter(torch.tensor([1.0], dtype=torch.float64))
    opt = opt_cls([p], **kw)
    out = []
    for g in grads:
        p.grad = torch.tensor([g], dtype=torch.float64)
        opt.step()
        out.append(float(p.detach()))
    return out


def test_first_step_by_hand():
    # g = 0.5, lr 0.1, betas 0.9/0.999, eps 0.01 (large, so that where it enters shows):
    # m = 0.05, v = 0.00025, sqrt(v) = 0.0158114; Keras: alpha = 0.1 * sqrt(0.001) / 0.1 = 0.0316228,
    # step = 0.0316228 * 0.05 / (0.0158114 + 0.01) = 0.0612574.
    # PyTorch: 0.1 / 0.1 * 0.05 / (0.0158114 / 0.0316228 + 0.01) = 0.05 / 0.51 = 0.0980392.
    kw = dict(lr=0.1, betas=(0.9, 0.999), eps=0.01)
    assert _run(KerasAdam, [0.5], **kw)[0] == pytest.approx(1.0 - 0.0612574, abs=2e-7)
    assert _run(torch.optim.Adam, [0.5], **kw)[0] == pytest.approx(1.0 - 0.0980392, abs=2e-7)


def test_matches_keras2_formula_over_steps():
    grads = [0.5, -0.25, 1e-6, 3.0, -2e-7, 0.0, 0.125]
    lr, b1, b2, eps = 1e-3, 0.9, 0.999, 1e-7
    p, m, v, want = 1.0, 0.0, 0.0, []
    for t, g in enumerate(grads, start=1):  # tf_keras/optimizers/adam.py update_step, written out
        m = m + (g - m) * (1 - b1)
        v = v + (g * g - v) * (1 - b2)
        alpha = lr * math.sqrt(1 - b2**t) / (1 - b1**t)
        p = p - m * alpha / (math.sqrt(v) + eps)
        want.append(p)
    got = _run(KerasAdam, grads, lr=lr, betas=(b1, b2), eps=eps)
    assert got == pytest.approx(want, rel=0, abs=1e-12)


def test_tiny_gradients_are_damped_like_keras():
    # A gradient of 1e-7 at step 1: Keras moves lr * sqrt(.001) * 1e-8 / (sqrt(1e-17) + 1e-7) / 0.1 ~= 0.031 lr,
    # PyTorch nearly lr * 0.97 (its eps is 32x smaller in the same units).
    lr = 1e-4
    k = 1.0 - _run(KerasAdam, [1e-7], lr=lr, eps=1e-7)[0]
    t = 1.0 - _run(torch.optim.Adam, [1e-7], lr=lr, eps=1e-7)[0]
    sq = math.sqrt(1e-3)
    assert k == pytest.approx(lr * sq * 1e-7 / (1e-7 * sq + 1e-7), rel=1e-6)
    assert t == pytest.approx(lr * 1e-7 / (1e-7 + 1e-7), rel=1e-6)
    assert t > 10 * k


def test_large_gradients_agree_with_torch():
    # with |g| >> eps both forms give lr * sign(g) at step 1
    a = _run(KerasAdam, [2.0, 1.0, -3.0], lr=1e-3)
    b = _run(torch.optim.Adam, [2.0, 1.0, -3.0], lr=1e-3, eps=1e-7)
    assert a == pytest.approx(b, rel=0, abs=1e-8)  # they differ by ~3e-9 through eps only
    assert a[0] == pytest.approx(1.0 - 1e-3 * (1 - 1e-7 / math.sqrt(0.004)), abs=1e-12)


def test_weight_decay_adds_to_the_gradient():
    # wd 0.5 on p = 1 with g = 0: effective g = 0.5 -> same as g = 0.5 without decay at step 1
    assert _run(KerasAdam, [0.0], lr=0.1, eps=0.01, weight_decay=0.5)[0] == pytest.approx(
        _run(KerasAdam, [0.5], lr=0.1, eps=0.01)[0], abs=1e-12
    )


def test_state_dict_resumes_with_torch_adam_names():
    p = torch.nn.Parameter(torch.ones(3))
    opt = KerasAdam([p], lr=0.1)
    p.grad = torch.tensor([1.0, -2.0, 3.0])
    opt.step()
    sd = opt.state_dict()
    assert set(sd["state"][0]) == {"step", "exp_avg", "exp_avg_sq"}
    assert float(sd["state"][0]["step"]) == 1.0
    assert torch.allclose(sd["state"][0]["exp_avg"], torch.tensor([0.1, -0.2, 0.3]))
    other = torch.optim.Adam([torch.nn.Parameter(torch.ones(3))], lr=0.1)
    other.load_state_dict(sd)  # and back
    again = KerasAdam([torch.nn.Parameter(torch.ones(3))], lr=0.1)
    again.load_state_dict(other.state_dict())
    assert torch.equal(again.state_dict()["state"][0]["exp_avg_sq"], sd["state"][0]["exp_avg_sq"])


def test_config_default_and_choice():
    assert TrainConfig().optimizer == "adam_keras"
    p = [torch.nn.Parameter(torch.ones(1))]
    assert isinstance(make_optimizer("adam_keras", p, 1e-4, (0.9, 0.999), 1e-7), KerasAdam)
    assert type(make_optimizer("adam_torch", p, 1e-4, (0.9, 0.999), 1e-7)) is torch.optim.Adam
    with pytest.raises(ConfigError, match="train.optimizer"):
        TrainConfig(optimizer="sgd")
    with pytest.raises(ValueError):
        KerasAdam(p, lr=-1.0)


def _keras_by_hand(p, grads, lr, b1, b2, eps, wd):
    """Keras 2's update of one scalar written out in Python floats; ``None`` in ``grads``: no update that step."""
    m = v = 0.0
    t = 0
    for g in grads:
        if g is None:
            continue
        g = g + wd * p
        t += 1
        m = m + (g - m) * (1 - b1)
        v = v + (g * g - v) * (1 - b2)
        p = p - m * lr * math.sqrt(1 - b2**t) / (1 - b1**t) / (math.sqrt(v) + eps)
    return p


def test_multi_tensor_update_equals_the_formula_per_parameter():
    """The default (foreach) update over several parameters of different shapes, one of them without a gradient
    at some steps (so the parameters' step counts differ), with weight decay: each element as the formula."""
    lr, b1, b2, eps, wd = 1e-2, 0.8, 0.99, 1e-3, 0.05
    f64 = torch.float64
    start = [
        torch.tensor([[1.0, -2.0], [0.5, 3.0]], dtype=f64),
        torch.tensor([0.25, -1.5], dtype=f64),
        torch.tensor([4.0], dtype=f64),
    ]
    params = [torch.nn.Parameter(s.clone()) for s in start]
    grads = [  # step -> per-parameter gradient (None: no gradient this step)
        [torch.tensor([[0.5, -0.1], [2.0, 0.0]]), torch.tensor([1e-4, -3.0]), torch.tensor([0.7])],
        [torch.tensor([[-0.2, 0.3], [1.0, 5.0]]), None, torch.tensor([-0.1])],
        [torch.tensor([[0.0, 0.0], [-1.0, 0.25]]), torch.tensor([2.0, 0.5]), None],
        [torch.tensor([[1.5, -0.5], [0.1, -2.0]]), torch.tensor([-0.3, 0.0]), torch.tensor([0.2])],
    ]
    opt = KerasAdam(params, lr=lr, betas=(b1, b2), eps=eps, weight_decay=wd)
    assert opt.param_groups[0]["foreach"] is True
    for step in grads:
        for p, g in zip(params, step):
            p.grad = None if g is None else g.to(torch.float64)
        opt.step()
    for i, (p, s) in enumerate(zip(params, start)):
        for j in range(s.numel()):
            seq = [None if step[i] is None else float(step[i].reshape(-1)[j]) for step in grads]
            want = _keras_by_hand(float(s.reshape(-1)[j]), seq, lr, b1, b2, eps, wd)
            assert float(p.detach().reshape(-1)[j]) == pytest.approx(want, rel=0, abs=1e-12), (i, j)
    assert [float(opt.state[p]["step"]) for p in params] == [4.0, 3.0, 3.0]


def test_multi_tensor_update_equals_the_loop_bit_for_bit():
    """float32, random shapes: the foreach update and the per-parameter loop give identical parameters and moments."""
    gen = torch.Generator().manual_seed(0)
    shapes = [(16, 8, 3, 3), (16,), (5, 16, 3, 3), (5,), (7, 1)]
    a = [torch.nn.Parameter(torch.randn(s, generator=gen)) for s in shapes]
    b = [torch.nn.Parameter(p.detach().clone()) for p in a]
    opt_a = KerasAdam(a, lr=1e-3, eps=1e-7, weight_decay=1e-4)
    opt_b = KerasAdam(b, lr=1e-3, eps=1e-7, weight_decay=1e-4, foreach=False)
    for _ in range(5):
        for pa, pb in zip(a, b):
            g = torch.randn(pa.shape, generator=gen) * 10.0 ** float(torch.randint(-8, 2, (), generator=gen))
            pa.grad, pb.grad = g.clone(), g.clone()
        opt_a.step()
        opt_b.step()
    for pa, pb in zip(a, b):
        assert torch.equal(pa, pb)
        for k in ("exp_avg", "exp_avg_sq", "step"):
            assert torch.equal(opt_a.state[pa][k], opt_b.state[pb][k])


def test_loads_a_torch_adam_state_dict_and_keeps_stepping():
    """A group loaded from torch.optim.Adam (foreach None) and one from an older KerasAdam (no foreach key)."""
    p = torch.nn.Parameter(torch.ones(2))
    torch_opt = torch.optim.Adam([p], lr=0.1)
    p.grad = torch.tensor([1.0, -1.0])
    torch_opt.step()
    sd = torch_opt.state_dict()
    q = torch.nn.Parameter(p.detach().clone())
    k = KerasAdam([q], lr=0.1)
    k.load_state_dict(sd)
    old = KerasAdam([torch.nn.Parameter(p.detach().clone())], lr=0.1)
    sd_old = copy.deepcopy(k.state_dict())  # (a state dict shares the optimizer's tensors)
    del sd_old["param_groups"][0]["foreach"]
    old.load_state_dict(sd_old)
    for opt in (k, old):
        r = opt.param_groups[0]["params"][0]
        r.grad = torch.tensor([1.0, -1.0])
        opt.step()
        assert float(opt.state[r]["step"]) == 2.0
    assert torch.equal(k.param_groups[0]["params"][0], old.param_groups[0]["params"][0])
