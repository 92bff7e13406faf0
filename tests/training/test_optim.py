"""The training optimizer: Keras 2's Adam update (the original's), checked against the formula by hand."""

import math

import pytest
import torch

from cosemdepth.config import TrainConfig
from cosemdepth.errors import ConfigError
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
    for t, g in enumerate(grads, start=1):      # tf_keras/optimizers/adam.py update_step, written out
        m = m + (g - m) * (1 - b1)
        v = v + (g * g - v) * (1 - b2)
        alpha = lr * math.sqrt(1 - b2 ** t) / (1 - b1 ** t)
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
        _run(KerasAdam, [0.5], lr=0.1, eps=0.01)[0], abs=1e-12)


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
    other.load_state_dict(sd)                      # and back
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
