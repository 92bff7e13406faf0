"""The optimizers of training: Adam as Keras 2 applies it (the original's), or PyTorch's Adam.

Both keep the same moments, ``m <- b1 m + (1 - b1) g`` and ``v <- b2 v + (1 - b2) g^2``, and differ only in where
epsilon enters (step ``t`` counted from 1):

* Keras 2 (``tf.keras.optimizers.Adam``, the original's, tf-keras and TF 2.7 alike: epsilon is "epsilon hat"):
  ``p <- p - lr * sqrt(1 - b2^t) / (1 - b1^t) * m / (sqrt(v) + eps)``;
* PyTorch (``torch.optim.Adam``): ``p <- p - lr / (1 - b1^t) * m / (sqrt(v) / sqrt(1 - b2^t) + eps)``.

Written in PyTorch's form, Keras' epsilon is ``eps / sqrt(1 - b2^t)``: about 32x larger at step 1 (3.2e-6 for
eps 1e-7), 10x at step 10, 3x at step 100, still 1.3x at step 1000. Updates of parameters whose gradients are
smaller than about that (biases in front of an instance normalisation, whose true gradient is ~0, rarely-active
units) are damped in the original and are close to ``lr`` steps in PyTorch's form.

``train.optimizer`` selects one: ``"adam_keras"`` (default, the original) or ``"adam_torch"``. Both keep their
state under PyTorch's names (``step``, ``exp_avg``, ``exp_avg_sq``), so a checkpoint of one resumes with the other.
"""

from __future__ import annotations

import math
from typing import Iterable

import torch

OPTIMIZERS = ("adam_keras", "adam_torch")


class KerasAdam(torch.optim.Optimizer):
    """Adam with Keras 2's update (see the module docstring). ``weight_decay`` adds ``wd * p`` to the gradient,
    as ``torch.optim.Adam`` does (Keras' Adam of the original has none).

    ``foreach`` (default True): the update of a parameter group as a handful of multi-tensor ``torch._foreach_*``
    ops over all its parameters, instead of a Python loop of six ops per parameter; both give the same numbers
    (the same elementwise operations in the same order)."""

    def __init__(
        self,
        params: Iterable,
        lr: float = 1e-3,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-7,
        weight_decay: float = 0.0,
        foreach: bool = True,
    ) -> None:
        if not lr > 0 or not eps > 0 or weight_decay < 0 or not all(0.0 <= b < 1.0 for b in betas):
            raise ValueError(f"bad Adam settings lr={lr} betas={betas} eps={eps} weight_decay={weight_decay}")
        super().__init__(
            params, dict(lr=lr, betas=tuple(betas), eps=eps, weight_decay=weight_decay, foreach=bool(foreach))
        )
        #: Per-parameter buffers of the foreach update's denominator, kept between steps (not in the state dict):
        #: allocating all the denominators afresh every step (the model's size in float32 at once) costs page
        #: faults that made the update slower than the loop, whose per-parameter temporaries the allocator recycles.
        self._denom: dict[torch.Tensor, torch.Tensor] = {}

    @torch.no_grad()
    def step(self, closure=None):
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        for group in self.param_groups:
            params, grads, ms, vs, steps = [], [], [], [], []
            for p in group["params"]:
                if p.grad is None:
                    continue
                if p.grad.is_sparse:
                    raise RuntimeError("KerasAdam does not support sparse gradients")
                state = self.state[p]
                if not state:
                    state["step"] = torch.tensor(0.0)
                    state["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                    state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                params.append(p)
                grads.append(p.grad)
                ms.append(state["exp_avg"])
                vs.append(state["exp_avg_sq"])
                steps.append(state["step"])
            if params:
                # (a group loaded from an older or a torch.optim.Adam state dict may lack "foreach" or hold None)
                hyper = dict(lr=group["lr"], betas=group["betas"], eps=group["eps"], weight_decay=group["weight_decay"])
                if group.get("foreach") is False:
                    _keras_adam_single(params, grads, ms, vs, steps, **hyper)
                else:
                    denom = [self._denom.get(p) for p in params]
                    for i, (p, d) in enumerate(zip(params, denom)):
                        if d is None or d.shape != p.shape or d.dtype != p.dtype or d.device != p.device:
                            denom[i] = self._denom[p] = torch.empty_like(p, memory_format=torch.preserve_format)
                    _keras_adam_foreach(params, grads, ms, vs, steps, denom, **hyper)
        return loss


def _alphas(steps: list[torch.Tensor], lr: float, b1: float, b2: float) -> list[float]:
    """Keras' step size ``lr * sqrt(1 - b2^t) / (1 - b1^t)`` of each parameter (after its step count's increment)."""
    return [lr * math.sqrt(1 - b2**t) / (1 - b1**t) for t in (float(s) for s in steps)]


def _keras_adam_single(params, grads, ms, vs, steps, *, lr, betas, eps, weight_decay) -> None:
    """The update parameter by parameter (the reference of :func:`_keras_adam_foreach`)."""
    b1, b2 = betas
    for p, g, m, v, s in zip(params, grads, ms, vs, steps):
        if weight_decay:
            g = g.add(p, alpha=weight_decay)
        s += 1
        m.lerp_(g, 1 - b1)
        v.mul_(b2).addcmul_(g, g, value=1 - b2)
        (alpha,) = _alphas([s], lr, b1, b2)
        p.addcdiv_(m, v.sqrt().add_(eps), value=-alpha)


def _keras_adam_foreach(params, grads, ms, vs, steps, denom, *, lr, betas, eps, weight_decay) -> None:
    """The same update as multi-tensor ops over all the parameters at once; ``denom``: scratch tensors like
    ``params`` (overwritten)."""
    b1, b2 = betas
    if weight_decay:
        grads = torch._foreach_add(grads, params, alpha=weight_decay)
    torch._foreach_add_(steps, 1.0)
    torch._foreach_lerp_(ms, grads, 1 - b1)
    torch._foreach_mul_(vs, b2)
    torch._foreach_addcmul_(vs, grads, grads, value=1 - b2)
    torch._foreach_copy_(denom, vs)
    torch._foreach_sqrt_(denom)
    torch._foreach_add_(denom, eps)
    torch._foreach_addcdiv_(params, ms, denom, [-a for a in _alphas(steps, lr, b1, b2)])


def make_optimizer(
    kind: str, params: Iterable, lr: float, betas: tuple[float, float], eps: float, weight_decay: float = 0.0
) -> torch.optim.Optimizer:
    """``"adam_keras"`` -> :class:`KerasAdam`; ``"adam_torch"`` -> ``torch.optim.Adam``."""
    if kind == "adam_keras":
        return KerasAdam(params, lr=lr, betas=betas, eps=eps, weight_decay=weight_decay)
    if kind == "adam_torch":
        return torch.optim.Adam(params, lr=lr, betas=betas, eps=eps, weight_decay=weight_decay)
    raise ValueError(f"optimizer must be one of {OPTIMIZERS}, got {kind!r}")
