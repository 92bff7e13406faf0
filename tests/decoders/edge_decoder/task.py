"""The edge decoder's task: its ground truth derived from the depth (:func:`edge_strength`), an L1 loss on every
level, a mean-absolute-error metric, a grey training picture and an 8-bit PNG per predicted frame."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Optional

import numpy as np
import torch
import torch.nn.functional as F

from cosemdepth.measures.losses import FIRST_SUPERVISED_FRAME
from cosemdepth.render.visualize import save_png
from cosemdepth.tasks import DecoderTask, Frames, MetricContext, TaskMetrics, TaskWriter, WriteOptions

from .decoder import EdgeDecoder


def edge_strength(depth: torch.Tensor) -> torch.Tensor:
    """``[..., 1, H, W]`` metres -> ``[..., 1, H, W]`` edge strength in ``[0, 1)``."""
    logd = torch.log(depth.float().clamp(min=1e-3))
    gx = F.pad(logd[..., :, 1:] - logd[..., :, :-1], (0, 1, 0, 0))
    gy = F.pad(logd[..., 1:, :] - logd[..., :-1, :], (0, 0, 0, 1))
    g = torch.sqrt(gx * gx + gy * gy)
    return g / (1 + g)


class EdgeMetrics(TaskMetrics):
    """``edge_mae``: the mean absolute error over every pixel of the frames included; ``edge_frames``."""

    def __init__(self) -> None:
        self.total, self.pixels, self.frames = 0.0, 0, 0

    def update(self, frames: Frames, include: Optional[torch.Tensor] = None) -> None:
        err = (frames.heads["edge"].float() - frames.gt["edge"].float().reshape(frames.heads["edge"].shape)).abs()
        keep = torch.ones(err.shape[0], dtype=torch.bool) if include is None else include.bool().cpu()
        err = err[keep.to(err.device)]
        self.total += float(err.double().sum())
        self.pixels += err.numel()
        self.frames += int(keep.sum())

    def compute(self) -> dict[str, Any]:
        return {"edge_mae": self.total / self.pixels if self.pixels else float("nan"), "edge_frames": self.frames}


class EdgeWriter(TaskWriter):
    """``edge/<stem>.png``: uint8, ``round(255 * e)``."""

    def write(self, folder: Path, rel: str, stem: str, frames, b: int, record: dict[str, Any]) -> dict[str, str]:
        e = frames.heads["edge"][b, 0].detach().float().cpu().numpy()
        path = f"{rel}/edge/{stem}.png"
        save_png(folder / path, np.round(np.clip(e, 0, 1) * 255).astype(np.uint8))
        return {"edge": path}


class EdgeTask(DecoderTask):
    name = "edge"
    decoder = EdgeDecoder
    gt_key = "edge"
    predicts = "edge strength"

    def ground_truth(self, batch: Mapping[str, Any]) -> Optional[torch.Tensor]:
        depth = batch.get("depth")
        return None if depth is None else edge_strength(depth)

    def loss(self, out, batch, train) -> torch.Tensor:
        first = FIRST_SUPERVISED_FRAME  # the frames before it are not decoded (their maps are undefined)
        gt = self.ground_truth(batch)[:, first:]  # [B, T - first, 1, H, W]
        total = gt.new_zeros(())
        for pred in out.maps("edge"):  # [B, T, 1, h, w] per level
            pred = pred[:, first:].float()
            b, t, c, h, w = pred.shape
            target = F.adaptive_avg_pool2d(gt.reshape(b * t, 1, *gt.shape[-2:]), (h, w))
            total = total + (pred.reshape(b * t, c, h, w) - target).abs().mean()
        return total

    def metrics(self, context: MetricContext) -> EdgeMetrics:
        return EdgeMetrics()

    def example(self, gt, pred, model) -> dict[str, torch.Tensor]:
        out = {} if gt is None else {"edge": gt.cpu()}
        out["pred_edge"] = pred.cpu()
        return out

    def strip_panels(self, example, model) -> list[np.ndarray]:
        return [
            np.repeat((np.clip(e.reshape(e.shape[-2:]).numpy(), 0, 1) * 255).astype(np.uint8)[..., None], 3, -1)
            for e in (example.get("edge"), example.get("pred_edge"))
            if e is not None
        ]

    def writer(self, options: WriteOptions) -> EdgeWriter:
        return EdgeWriter()

    def encodings(self, options: WriteOptions) -> dict[str, Any]:
        return {"edge": "edge/*.png: uint8 = round(255 * edge strength), edge strength = g / (1 + g), g = |grad log d|"}
