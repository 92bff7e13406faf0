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
    as ``torch.optim.Adam`` does (Keras' Adam of the original has none)."""

    def __init__(self, params: Iterable, lr: float = 1e-3, betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-7, weight_decay: float = 0.0) -> None:
        if not lr > 0 or not eps > 0 or weight_decay < 0 or not all(0.0 <= b < 1.0 for b in betas):
            raise ValueError(f"bad Adam settings lr={lr} betas={betas} eps={eps} weight_decay={weight_decay}")
        super().__init__(params, dict(lr=lr, betas=tuple(betas), eps=eps, weight_decay=weight_decay))

    @torch.no_grad()
    def step(self, closure=None):
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        for group in self.param_groups:
            b1, b2 = group["betas"]
            for p in group["params"]:
                if p.grad is None:
                    continue
                g = p.grad
                if group["weight_decay"]:
                    g = g.add(p, alpha=group["weight_decay"])
                state = self.state[p]
                if not state:
                    state["step"] = torch.tensor(0.0)
                    state["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                    state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                state["step"] += 1
                t = float(state["step"])
                m, v = state["exp_avg"], state["exp_avg_sq"]
                m.lerp_(g, 1 - b1)
                v.mul_(b2).addcmul_(g, g, value=1 - b2)
                alpha = group["lr"] * math.sqrt(1 - b2 ** t) / (1 - b1 ** t)
                p.addcdiv_(m, v.sqrt().add_(group["eps"]), value=-alpha)
        return loss


def make_optimizer(kind: str, params: Iterable, lr: float, betas: tuple[float, float], eps: float,
                   weight_decay: float = 0.0) -> torch.optim.Optimizer:
    """``"adam_keras"`` -> :class:`KerasAdam`; ``"adam_torch"`` -> ``torch.optim.Adam``."""
    if kind == "adam_keras":
        return KerasAdam(params, lr=lr, betas=betas, eps=eps, weight_decay=weight_decay)
    if kind == "adam_torch":
        return torch.optim.Adam(params, lr=lr, betas=betas, eps=eps, weight_decay=weight_decay)
    raise ValueError(f"optimizer must be one of {OPTIMIZERS}, got {kind!r}")
