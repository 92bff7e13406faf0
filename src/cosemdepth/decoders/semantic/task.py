"""The semantic decoder's task: the multi-level sparse categorical cross-entropy (design 8.2, weighted by
``train.semantic_weight``), the global confusion matrix and mIoU (design 11.2; with the labels' temporal consistency in
the test protocol when the dataset has depth), its ``predict`` files and its training pictures."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Optional

import numpy as np
import torch

from ...errors import ConfigError
from ...measures.classes import class_info, dataset_classes
from ...measures.losses import semantic_loss
from ...measures.metrics import ConfusionMatrix
from ...measures.temporal import TemporalConsistency
from ...models.config import ModelConfig
from ...render.examples import labels_to_rgb
from ...render.visualize import colorize_labels, save_png
from ...tasks.base import (
    TEST,
    DecoderTask,
    Frames,
    MetricContext,
    TaskMetrics,
    TaskWriter,
    WriteOptions,
    float32_levels,
)
from .decoder import SemanticDecoder


def _labels(scores: torch.Tensor, like: torch.Tensor, num_classes: int) -> torch.Tensor:
    """The argmax labels of class scores ``[B, N, H, W]`` shaped like the ground truth ``like`` (``[B, H, W]`` or
    ``[B, 1, H, W]``); integer labels pass through."""
    if not scores.dtype.is_floating_point:
        return scores
    if scores.dim() != 4 or scores.shape[1] != num_classes:
        raise ValueError(f"pred_semantic scores must be [B, {num_classes}, H, W], got {list(scores.shape)}")
    return scores.argmax(dim=1, keepdim=like.dim() == 4)


class SemanticTaskMetrics(TaskMetrics):
    """mIoU and the per-class IoU from one global confusion matrix (design 11.2); in the test protocol also the
    labels' temporal consistency (:class:`~cosemdepth.measures.temporal.TemporalConsistency`) when the dataset has
    the depth to follow the pixels with, and the confusion matrix and class names for the report."""

    def __init__(self, context: MetricContext) -> None:
        cfg = context.model
        self.test = context.protocol == TEST
        self.matrix = ConfusionMatrix(cfg.num_classes)
        self.temporal = TemporalConsistency() if self.test and "depth" in context.ground_truth else None
        self.class_names = class_info(cfg.num_classes, context.dataset_name)[0] if self.test else ()

    def update(self, frames: Frames, include: Optional[torch.Tensor] = None) -> None:
        gt = frames.gt["semantic"]
        labels = _labels(frames.heads["semantic"], gt, self.matrix.num_classes)
        self.matrix.update(gt, labels, include)
        if self.temporal is not None:
            self.temporal.update(
                frames.trajectory,
                frames.reset,
                gt,
                labels,
                frames.gt["depth"],
                frames.rot,
                frames.trans,
                frames.intrinsics,
            )

    def compute(self) -> dict[str, Any]:
        return {
            "miou": self.matrix.miou(),
            "iou": [float(x) for x in self.matrix.iou()],
            "semantic_frames": self.matrix.frames,
        }

    def report(self) -> dict[str, Any]:
        if not self.test:
            return {}
        out: dict[str, Any] = {"confusion_matrix": self.matrix.matrix.clone(), "class_names": tuple(self.class_names)}
        if self.temporal is not None:
            out["metrics"] = self.temporal.compute()
        return out


class LabelsWriter(TaskWriter):
    """``labels/*.png`` (class indices) and ``labels_color/*.png`` (the dataset's palette) of every frame."""

    def __init__(self, options: WriteOptions) -> None:
        self.palette = options.palette

    def write(self, folder: Path, rel: str, stem: str, frames, b: int, record: dict[str, Any]) -> dict[str, str]:
        labels = frames.heads["semantic"][b].argmax(0).detach().cpu().numpy().astype(np.uint8)
        files = {"labels": f"{rel}/labels/{stem}.png", "labels_color": f"{rel}/labels_color/{stem}.png"}
        save_png(folder / files["labels"], labels)
        save_png(folder / files["labels_color"], colorize_labels(labels, self.palette))
        return files


class SemanticTask(DecoderTask):
    """The semantic decoder's task: ground truth ``"semantic"`` (class indices), the cross-entropy weighted by
    ``train.semantic_weight``, mIoU (and the labels' temporal consistency), the ``labels`` / ``labels_color`` files of
    ``predict`` and the label pictures."""

    name = "semantic"
    decoder = SemanticDecoder
    gt_key = "semantic"
    predicts = "class labels"

    def loss(self, out, batch: Mapping[str, Any], train) -> torch.Tensor:
        scores = out.maps("semantic_logits" if train.semantic_from_logits else "semantic")
        return semantic_loss(
            float32_levels(scores),
            batch["semantic"],
            from_logits=train.semantic_from_logits,
            class_weights=train.semantic_class_weights or None,
        )

    def loss_weight(self, train) -> float:
        return train.semantic_weight

    def check_dataset(self, model: ModelConfig, dataset_name: str) -> None:
        expected = dataset_classes().get(dataset_name)
        if expected is not None and expected != model.num_classes:
            raise ConfigError(
                f"the model predicts {model.num_classes} classes but the {dataset_name} labels have "
                f"{expected}; evaluate it on a dataset with the same class set"
            )

    def metrics(self, context: MetricContext) -> SemanticTaskMetrics:
        return SemanticTaskMetrics(context)

    def model_info(self, model: ModelConfig) -> dict[str, Any]:
        return {"num_classes": model.num_classes}

    def example(self, gt, pred, model: ModelConfig) -> dict[str, torch.Tensor]:
        out = {} if gt is None else {"semantic": gt.cpu()}
        out["pred_labels"] = pred.argmax(0).cpu()
        return out

    def strip_panels(self, example, model: ModelConfig) -> list[np.ndarray]:
        return [
            labels_to_rgb(lab.reshape(lab.shape[-2:]), model.num_classes)
            for lab in (example.get("semantic"), example.get("pred_labels"))
            if lab is not None
        ]

    def writer(self, options: WriteOptions) -> LabelsWriter:
        return LabelsWriter(options)

    def encodings(self, options: WriteOptions) -> dict[str, Any]:
        return {
            "labels": "labels/*.png: uint8 class index (argmax of the probabilities)",
            "labels_color": "labels_color/*.png: RGB, palette below",
        }


__all__ = ["LabelsWriter", "SemanticTask", "SemanticTaskMetrics"]
