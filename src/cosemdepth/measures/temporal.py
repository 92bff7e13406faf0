"""Temporal consistency of the predicted labels: flicker, and how often real changes are followed (design 11.5).

Consecutive frames ``t - 1, t`` of a trajectory are compared point by point: every pixel ``p`` of frame ``t`` is
followed to where its 3D point was in frame ``t - 1``, with the **ground-truth** depth of frame ``t`` and the true
motion (design 2.6), and the labels there are read at the nearest pixel (``W`` below). A pixel counts where that
point is in front of both cameras and inside the previous image. Then

    stable(p)   = GT_t(p) == W(GT_{t-1})(p)            the ground truth does not change
    changed(p)  = GT_t(p) != W(GT_{t-1})(p)            it does (occlusions, label edges, the warp's own errors)
    moved(p)    = P_t(p)  != W(P_{t-1})(p)             the prediction changes

    flicker        = #(stable and moved) / #stable     summed over every pixel of every pair
    change_recall  = #(changed and moved) / #changed
    gt_change      = #changed / (#stable + #changed)

A model that never changes its labels has no flicker and follows no change; one that is right everywhere has the
flicker and change recall of the ground truth itself (0 and 1). ``flicker_median`` and ``flicker_max`` are over the
per-pair values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import torch

from ..geometry.correspondence import previous_points_from_motion


def warp_previous_labels(
    labels: torch.Tensor, depth: torch.Tensor, rot: torch.Tensor, trans: torch.Tensor, intrinsics: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The labels of the previous frame seen from the current one (nearest pixel).

    Args:
        labels: ``[B, H, W]`` integer labels of the previous frame.
        depth: ``[B, 1, H, W]`` depth of the current frame (metres; NaN, 0 or negative: no point there).
        rot: ``[B, 4]``, trans ``[B, 3]``: the motion previous -> current (``X_prev = R X_cur + t``).
        intrinsics: ``[B, 4]`` of the ``H x W`` grid.
    Returns:
        ``(warped [B, H, W], valid [B, H, W] bool)``; ``warped`` is 0 where not ``valid``.
    """
    b, h, w = labels.shape
    f = torch.float64  # exact pixel rounding for any image size
    points, ok = previous_points_from_motion(depth.to(f), rot.to(f), trans.to(f), intrinsics.to(f))
    col = torch.round(points[:, 0]).clamp(0, w - 1).long()
    row = torch.round(points[:, 1]).clamp(0, h - 1).long()
    warped = labels.reshape(b, -1).gather(1, (row * w + col).reshape(b, -1)).view(b, h, w)
    valid = ok[:, 0]
    return torch.where(valid, warped, torch.zeros_like(warped)), valid


@dataclass(frozen=True)
class PairCounts:
    """Pixel counts of one pair of frames (see the module docstring)."""

    stable: int
    flicker: int
    changed: int
    followed: int


def pair_counts(
    pred: torch.Tensor, pred_prev: torch.Tensor, gt: torch.Tensor, gt_prev: torch.Tensor, valid: torch.Tensor
) -> list[PairCounts]:
    """Per sample, the counts of one pair: ``pred``/``gt`` ``[B, H, W]`` labels of frame ``t``, ``pred_prev``/
    ``gt_prev`` those of frame ``t - 1`` already warped into frame ``t``, ``valid`` ``[B, H, W]`` the pixels that
    count."""
    stable = valid & (gt == gt_prev)
    changed = valid & (gt != gt_prev)
    moved = pred != pred_prev
    sums = torch.stack([stable, stable & moved, changed, changed & moved], 1).flatten(2).sum(2).tolist()
    return [PairCounts(*map(int, row)) for row in sums]


def _ratio(num: int, den: int) -> float:
    return num / den if den else math.nan


@dataclass
class _Last:
    gt: torch.Tensor
    pred: torch.Tensor


class TemporalConsistency:
    """Accumulates :func:`pair_counts` over a stream: call :meth:`update` with every streamed batch (frames in
    order within each trajectory, any number of trajectories side by side), then :meth:`compute`."""

    def __init__(self) -> None:
        self._last: dict[str, _Last] = {}
        self.pairs: list[PairCounts] = []

    def update(
        self,
        trajectory: Sequence[str],
        reset: torch.Tensor,
        gt_labels: torch.Tensor,
        pred_labels: torch.Tensor,
        gt_depth: torch.Tensor,
        rot: torch.Tensor,
        trans: torch.Tensor,
        intrinsics: torch.Tensor,
    ) -> None:
        """One streamed batch: ``trajectory`` names ``[B]``, ``reset`` ``[B]`` (a frame that starts a trajectory has
        no previous frame), labels ``[B, H, W]``, ``gt_depth`` ``[B, 1, H, W]``, the motion from each sample's
        previous frame and the intrinsics of the frame. A trajectory absent from a batch has ended."""
        rows = [b for b, name in enumerate(trajectory) if name in self._last and not bool(reset[b])]
        if rows:
            idx = torch.tensor(rows, device=gt_labels.device)
            prev_gt = torch.stack([self._last[trajectory[b]].gt for b in rows])
            prev_pred = torch.stack([self._last[trajectory[b]].pred for b in rows])
            pick = lambda x: x.index_select(0, idx.to(x.device))  # noqa: E731
            motion = (pick(gt_depth), pick(rot), pick(trans), pick(intrinsics))
            gt_w, valid = warp_previous_labels(prev_gt, *motion)
            pred_w, _ = warp_previous_labels(prev_pred, *motion)
            self.pairs += pair_counts(pick(pred_labels), pred_w, pick(gt_labels), gt_w, valid)
        self._last = {name: _Last(gt_labels[b], pred_labels[b]) for b, name in enumerate(trajectory)}

    def compute(self) -> dict[str, Any]:
        """``flicker``, ``flicker_median``, ``flicker_max``, ``change_recall``, ``gt_change`` (fractions, NaN without
        a pixel to count) and ``flicker_pairs`` (pairs of frames compared)."""
        stable = sum(p.stable for p in self.pairs)
        changed = sum(p.changed for p in self.pairs)
        per_pair = sorted(p.flicker / p.stable for p in self.pairs if p.stable)
        return {
            "flicker": _ratio(sum(p.flicker for p in self.pairs), stable),
            "flicker_median": _median(per_pair),
            "flicker_max": per_pair[-1] if per_pair else math.nan,
            "change_recall": _ratio(sum(p.followed for p in self.pairs), changed),
            "gt_change": _ratio(changed, stable + changed),
            "flicker_pairs": len(self.pairs),
        }


def _median(sorted_values: Sequence[float]) -> float:
    n = len(sorted_values)
    if not n:
        return math.nan
    mid = n // 2
    return sorted_values[mid] if n % 2 else (sorted_values[mid - 1] + sorted_values[mid]) / 2


#: The keys of :meth:`TemporalConsistency.compute` (the fields of ``evaluate``'s JSON ``metrics``).
TEMPORAL_METRICS = ("flicker", "flicker_median", "flicker_max", "change_recall", "gt_change", "flicker_pairs")

__all__ = ["PairCounts", "TEMPORAL_METRICS", "TemporalConsistency", "pair_counts", "warp_previous_labels"]
