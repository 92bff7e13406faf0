"""Validation during training, as the original runs it (design 7.3, 11.3).

Each validation item is a window of ``T`` (4) consecutive frames with ``reset = [True, False, ...]``. The streaming
model runs through the window, resetting at its first frame, and only the **last frame** of each window enters the
metrics (depth metrics of design 11.1 and the global confusion matrix of design 11.2, at the input resolution, the
prediction nearest-upsampled from the finest level by ``model.step``).
"""

from __future__ import annotations

import contextlib
from typing import Any, Iterable, Mapping

import torch

from ..evaluation.metrics import EvaluationMetrics
from .data import to_device


@torch.no_grad()
def run_window(model: torch.nn.Module, batch: Mapping[str, Any]):
    """Stream one batch of windows through ``model``; return the :class:`StepOutput` of the last frame.

    Args:
        batch: ``rgb [B,T,3,H,W]``, ``rot [B,T,4]``, ``trans [B,T,3]``, ``intrinsics [B,4]`` and optionally
            ``reset [B,T]`` (frame 0 always resets); ``depth [B,T,1,H,W]`` for a model that reads the ground-truth
            depth (``config.needs_depth_input``).
    """
    rgb, rot, trans, intr = batch["rgb"], batch["rot"], batch["trans"], batch["intrinsics"]
    b, t = rgb.shape[:2]
    reset = batch.get("reset")
    reset = torch.zeros(b, t, dtype=torch.bool, device=rgb.device) if reset is None else reset.bool().clone()
    reset[:, 0] = True
    state = None
    out = None
    guide = batch["depth"] if model.config.needs_depth_input else None
    for k in range(t):
        out, state = model.step(rgb[:, k], rot[:, k], trans[:, k], intr, reset[:, k], state,
                                guide_depth=None if guide is None else guide[:, k])
    return out


@torch.no_grad()
def validate(
    model: torch.nn.Module,
    batches: Iterable[Mapping[str, Any]],
    device: torch.device | str = "cpu",
    *,
    max_batches: int = 0,
    autocast: contextlib.AbstractContextManager | None = None,
    keep_example: bool = True,
) -> tuple[dict[str, Any], dict[str, torch.Tensor] | None]:
    """Windowed validation (design 7.3) of ``model`` (unwrapped, it is switched to eval mode and back).

    Args:
        batches: an iterable of collated validation windows (a DataLoader).
        device: where the model lives.
        max_batches: stop after this many batches (0: all).
        autocast: an autocast context for the forward passes (None: full precision).
        keep_example: also return the first window's last frame (inputs, ground truth, predictions) for pictures.
    Returns:
        ``(metrics, example)``: the :meth:`EvaluationMetrics.compute` dict (depth metrics and/or ``miou``, ``iou``)
        plus ``frames``; ``example`` has ``rgb [3,H,W]`` and those of ``depth``, ``pred_depth [1,H,W]``,
        ``semantic``, ``pred_labels [H,W]`` that exist (None if no batch or not asked).
    """
    cfg = model.config
    was_training = model.training
    model.eval()
    metrics = EvaluationMetrics(cfg.num_classes if cfg.has_semantic else None, depth=cfg.has_depth)
    example = None
    frames = 0
    try:
        for i, batch in enumerate(batches):
            if max_batches and i >= max_batches:
                break
            batch = to_device(batch, torch.device(device))
            with autocast if autocast is not None else contextlib.nullcontext():
                out = run_window(model, batch)
            pred_depth = None if out.depth is None else out.depth.float()
            pred_sem = None if out.semantic is None else out.semantic.float()
            metrics.update(
                gt_depth=batch["depth"][:, -1] if cfg.has_depth else None,
                pred_depth=pred_depth,
                gt_labels=batch["semantic"][:, -1] if cfg.has_semantic else None,
                pred_semantic=pred_sem,
            )
            frames += batch["rgb"].shape[0]
            if keep_example and example is None:
                example = {"rgb": batch["rgb"][0, -1].cpu()}
                if cfg.has_depth:
                    example["depth"] = batch["depth"][0, -1].cpu()
                    example["pred_depth"] = pred_depth[0].cpu()
                if cfg.has_semantic:
                    example["semantic"] = batch["semantic"][0, -1].cpu()
                    example["pred_labels"] = pred_sem[0].argmax(0).cpu()
    finally:
        model.train(was_training)
    result = metrics.compute() if frames else {}
    result["frames"] = frames
    return result, example


__all__ = ["run_window", "validate"]
