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

from ..tasks import VALIDATION, Frames, MetricContext, tasks_for
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
        out, state = model.step(
            rgb[:, k],
            rot[:, k],
            trans[:, k],
            intr,
            reset[:, k],
            state,
            guide_depth=None if guide is None else guide[:, k],
        )
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
        ``(metrics, example)``: the metrics of every decoder of the model (its task's, in order: the depth metrics,
        ``miou``, ``iou``...) plus ``frames``; ``example`` has ``rgb [3,H,W]`` and each decoder's
        :meth:`~cosemdepth.tasks.DecoderTask.example` tensors (``depth``, ``pred_depth [1,H,W]``, ``semantic``,
        ``pred_labels [H,W]``...; None if no batch or not asked).
    """
    cfg = model.config
    was_training = model.training
    model.eval()
    tasks = tasks_for(cfg)
    context = MetricContext(VALIDATION, cfg)
    metrics = {t.name: t.metrics(context) for t in tasks}
    example = None
    frames = 0
    try:
        for i, batch in enumerate(batches):
            if max_batches and i >= max_batches:
                break
            batch = to_device(batch, torch.device(device))
            with autocast if autocast is not None else contextlib.nullcontext():
                out = run_window(model, batch)
            heads = {t.head: out.heads[t.head].float() for t in tasks}
            gt = {t.gt_key: t.ground_truth(batch)[:, -1] for t in tasks}
            for t in tasks:
                metrics[t.name].update(Frames(heads, gt))
            frames += batch["rgb"].shape[0]
            if keep_example and example is None:
                example = {"rgb": batch["rgb"][0, -1].cpu()}
                for t in tasks:
                    example.update(t.example(gt[t.gt_key][0], heads[t.head][0], cfg))
    finally:
        model.train(was_training)
    result = {k: v for m in metrics.values() for k, v in m.compute().items()} if frames else {}
    result["frames"] = frames
    return result, example


__all__ = ["run_window", "validate"]
