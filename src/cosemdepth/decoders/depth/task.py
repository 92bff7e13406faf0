"""The depth decoder's task: the multi-level log-depth L1 loss (design 8.1), the depth metrics (design 11.1; with the
streaming policy's validity and frame statuses in the test protocol), its ``predict`` files and its training
pictures."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Optional

import numpy as np
import torch

from ...measures.losses import depth_loss
from ...measures.metrics import DepthMetrics, ValidDepthMetrics
from ...models.config import ModelConfig
from ...models.outputs import ESTIMATED, RESET, STATUSES
from ...render.examples import depth_to_rgb
from ...render.visualize import DEPTH_PNG_SCALE, depth_to_png16, save_npy, save_png
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
from .decoder import DepthDecoder


def valid_mask(depth: np.ndarray, valid: np.ndarray | None, reset: bool) -> np.ndarray:
    """``[H, W]`` bool: the pixels of ``depth`` written as estimates: those the prediction marks valid (all, for a
    stream without a mask, except on a reset frame), and only finite positive depths."""
    ok = np.isfinite(depth) & (depth > 0)
    if valid is not None:
        return ok & np.asarray(valid, dtype=bool)
    return ok & (not reset)


def no_depth_warning(frames: int, estimated: int, held: int, valid_fraction: float | None) -> str | None:
    """Why a run of ``frames`` frames, ``estimated`` and ``held`` of them with depth and ``valid_fraction`` of their
    pixels valid (None: not known), gave no usable depth; None when it gave some. The warning every command that
    streams depth prints (``cosemdepth CMD: warning: ...``)."""
    if frames <= 0:
        return None
    if not estimated and not held:
        if frames == 1:
            return (
                "no depth was produced: the input has 1 frame: the first frame of a flight is a reset, and depth "
                "needs the camera to move between frames"
            )
        return (
            f"no depth was produced: all {frames} frames are resets (the first frame of each trajectory, and the "
            "frames until the camera had moved the minimum baseline from it)"
        )
    if valid_fraction is not None and valid_fraction <= 0.0:
        n = estimated + held
        return (
            f"no valid depth: not one pixel of the {n} frame{'s' * (n != 1)} with depth is valid: the camera barely "
            "moved between frames (a hover or a yaw in place gives no parallax; docs/motion.md)"
        )
    return None


class DepthTaskMetrics(TaskMetrics):
    """The depth metrics of design 11.1 (:class:`~cosemdepth.measures.metrics.DepthMetrics`); in the test protocol
    also those of the valid pixels (:class:`~cosemdepth.measures.metrics.ValidDepthMetrics`) and the frames by
    status. A frame without depth (status ``reset``: the first of a trajectory, or one held before any estimate) is
    never in the depth metrics, whatever ``exclude_resets`` says: its depth is a placeholder, not a measurement
    (``exclude_resets=False``, a dataset of independent images, counts its labels)."""

    def __init__(self, context: MetricContext) -> None:
        self.test = context.protocol == TEST
        self.depth = DepthMetrics()
        self.valid = ValidDepthMetrics() if self.test else None
        self.statuses = {s: 0 for s in STATUSES}
        self.frames = 0

    def update(self, frames: Frames, include: Optional[torch.Tensor] = None) -> None:
        gt, pred = frames.gt["depth"], frames.heads["depth"]
        if not self.test:
            self.depth.update(gt, pred, include)
            return
        no_depth = (
            torch.tensor([st == RESET for st in frames.status], dtype=torch.bool, device=include.device)
            if frames.status
            else frames.reset.to(device=include.device, dtype=torch.bool)
        )
        depth_include = include & ~no_depth
        self.frames += int(depth_include.sum())
        self.depth.update(gt, pred, depth_include)
        if frames.valid is not None:
            self.valid.update(gt, pred, frames.valid, depth_include)
        for st, inc in zip(frames.status, include.tolist()):
            self.statuses[st] += int(inc)

    def compute(self) -> dict[str, Any]:
        return self.depth.compute()

    def report(self) -> dict[str, Any]:
        return {"metrics": self.valid.compute()} if self.valid is not None else {}


class DepthWriter(TaskWriter):
    """``depth/*.npy`` (float32 metres), ``depth_valid/*.png`` and ``depth_png/*.png`` (16-bit) of every frame; the
    frame's status, baseline and valid fraction in its record."""

    def __init__(self, options: WriteOptions) -> None:
        self.invalid = options.invalid
        self.statuses: dict[str, int] = {}

    def write(self, folder: Path, rel: str, stem: str, frames, b: int, record: dict[str, Any]) -> dict[str, str]:
        depth = frames.heads["depth"][b, 0].detach().float().cpu().numpy().astype(np.float32)
        mask = None if frames.valid is None else frames.valid[b, 0].detach().cpu().numpy().astype(bool)
        reset = bool(frames.reset[b])
        valid = valid_mask(depth, mask, reset)
        files = {
            "depth": f"{rel}/depth/{stem}.npy",
            "depth_valid": f"{rel}/depth_valid/{stem}.png",
            "depth_png": f"{rel}/depth_png/{stem}.png",
        }
        save_npy(
            folder / files["depth"], np.where(valid, depth, np.float32(np.nan)) if self.invalid == "nan" else depth
        )
        save_png(folder / files["depth_valid"], valid.astype(np.uint8) * np.uint8(255))
        save_png(folder / files["depth_png"], depth_to_png16(depth, valid))
        status = (frames.status[b] if b < len(frames.status) else "") or (RESET if reset else ESTIMATED)
        base = getattr(frames, "baseline", None)
        record.update(
            status=status,
            baseline_m=None if base is None else round(float(base[b]), 6),
            valid_fraction=round(float(valid.mean()), 6),
        )
        self.statuses[status] = self.statuses.get(status, 0) + 1
        return files

    def summary(self) -> dict[str, Any]:
        return {"frames_by_status": self.statuses}


class DepthTask(DecoderTask):
    """The depth decoder's task: ground truth ``"depth"`` (metres), the multi-level log-depth loss, the depth
    metrics, the ``depth`` / ``depth_valid`` / ``depth_png`` files of ``predict`` and the depth pictures."""

    name = "depth"
    decoder = DepthDecoder
    gt_key = "depth"
    predicts = "depth"

    def loss(self, out, batch: Mapping[str, Any], train) -> torch.Tensor:
        return depth_loss(float32_levels(out.maps("depth")), batch["depth"])

    def metrics(self, context: MetricContext) -> DepthTaskMetrics:
        return DepthTaskMetrics(context)

    def protocol_info(self, metrics: Optional[TaskMetrics]) -> dict[str, Any]:
        return {
            "frames_by_status": None if metrics is None else metrics.statuses,
            "depth_frames_evaluated": None if metrics is None else metrics.frames,
        }

    def example(self, gt, pred, model: ModelConfig) -> dict[str, torch.Tensor]:
        out = {} if gt is None else {"depth": gt.cpu()}
        out["pred_depth"] = pred.cpu()
        return out

    def strip_panels(self, example, model: ModelConfig) -> list[np.ndarray]:
        return [
            depth_to_rgb(d.reshape(d.shape[-2:]))
            for d in (example.get("depth"), example.get("pred_depth"))
            if d is not None
        ]

    def writer(self, options: WriteOptions) -> DepthWriter:
        return DepthWriter(options)

    def encodings(self, options: WriteOptions) -> dict[str, Any]:
        return {
            "depth": "depth/*.npy: float32 [H, W], metres, the model output as is"
            + (
                "; NaN where depth_valid is 0"
                if options.invalid == "nan"
                else " (also where depth_valid is 0: use the mask)"
            ),
            "depth_valid": "depth_valid/*.png: uint8, 255 where the depth is an estimate, 0 where it is not "
            "(a reset frame, a frame held without an earlier estimate, a baseline below the positions' resolution, "
            "ill-conditioned geometry, depth <= 0)",
            "depth_png": f"depth_png/*.png: uint16 = round(depth_m * {DEPTH_PNG_SCALE:g}) saturated to "
            f"[1, 65535]; depth_m = value / {DEPTH_PNG_SCALE:g}; 0 where depth_valid is 0",
            "status": "frames[].status: estimated (from the camera's motion since its reference frame), held "
            "(the reference frame's depth carried into this view: the camera moved less than "
            "policy.min_baseline_m), reset (no depth); frames[].baseline_m: metres from the reference frame",
            "depth_png_scale": DEPTH_PNG_SCALE,
        }


__all__ = ["DepthTask", "DepthTaskMetrics", "DepthWriter", "no_depth_warning", "valid_mask"]
