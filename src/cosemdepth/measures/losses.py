"""Training losses of Co-SemDepth, M4Depth and M4Semantic, as the original code computes them (design 8).

Both losses take the per-level predictions of a training forward pass over a ``T``-frame sequence, finest level
first, and supervise frames ``first_frame .. T-1`` (frame 0 is the reset frame and is never supervised by default).
Each supervised frame contributes ``mean over batch and pixels`` and the frame terms are averaged, i.e. summed and
divided by the number of supervised frames (``T - 1`` by default).

Depth (design 8.1)::

    pre(x)  = log(clip(x, 0.01, 200))
    L_depth = sum_t sum_i  w_i * mean_{b,h,w} | BL2(pre(D_gt^t), size_i) - pre(D_i^t) |  / (T - 1)
    w_i     = 0.64 / 2^(i-1) = 1.28, 0.64, 0.32, 0.16, 0.08  (i = 0 finest .. 4 coarsest)

The ground truth is log-transformed first and then resized to every level (TF2 half-pixel bilinear, ``BL2``).

Semantic (design 8.2): Keras ``SparseCategoricalCrossentropy`` on softmax probabilities, weight 1 per level, labels
resized with TF2 half-pixel nearest (``NN2``). Keras clips the probabilities to ``[1e-7, 1 - 1e-7]``, takes their log
and feeds it as logits to a softmax cross-entropy, so the per-pixel loss is::

    -log( clip(p_y) / sum_c clip(p_c) ) = -log(clip(p_y)) + log(sum_c clip(p_c))

For a probability vector with no clipped entry the second term is exactly ``log 1 = 0``; otherwise it is at most
``log(1 + N * 1e-7)``. The loss is therefore capped at ``-log(1e-7) = 16.118`` (plus that tiny term), and a pixel whose
target probability is below ``1e-7`` sends no gradient through it. ``from_logits=True`` switches to the numerically
stable ``log_softmax`` of logits, a documented deviation (design 8.2).

Total (design 8.3): ``L = L_depth + 0.1 * L_sem``. M4Depth has no semantic term; M4Semantic has only ``0.1 * L_sem``.

Deliberate deviation (design 8.1): non-finite ground-truth depth (``inf`` from a zero disparity, ``NaN`` from a
resize of ``inf``) is replaced by the 200 m cap before the log. The original let ``NaN`` through ``clip`` and into the
loss. Predictions are left as they are, so a diverging model still shows up as a non-finite loss.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass
from typing import Sequence

import torch
import torch.nn.functional as F

from ..ops.resample import resize_bl2, resize_nn2

#: Depth clipping range of the loss, in metres (design 8.1).
LOSS_MIN_DEPTH = 0.01
LOSS_MAX_DEPTH = 200.0
#: Keras ``epsilon()``: the probability clip of the sparse categorical cross-entropy (design 8.2).
SCCE_EPSILON = 1e-7
#: Weight of the semantic loss in the total loss (design 8.3).
SEMANTIC_WEIGHT = 0.1
#: First supervised frame of a training sequence (frame 0 is the reset frame).
FIRST_SUPERVISED_FRAME = 1


def depth_level_weights(levels: int) -> list[float]:
    """Depth-loss weight of each level, finest first: ``0.64 / 2^(i-1)`` for ``i = 0..levels-1``.

    >>> depth_level_weights(5)
    [1.28, 0.64, 0.32, 0.16, 0.08]
    """
    if levels < 1:
        raise ValueError(f"levels must be >= 1, got {levels}")
    return [0.64 / 2.0 ** (i - 1) for i in range(levels)]


def log_depth(
    depth: torch.Tensor, min_depth: float = LOSS_MIN_DEPTH, max_depth: float = LOSS_MAX_DEPTH
) -> torch.Tensor:
    """``log(clip(depth, min_depth, max_depth))`` (the loss's ``pre``); NaN passes through as in TF."""
    return torch.log(depth.clamp(min_depth, max_depth))


def sanitize_gt_depth(depth: torch.Tensor, max_depth: float = LOSS_MAX_DEPTH) -> torch.Tensor:
    """Replace non-finite ground-truth depth (``+-inf``, ``NaN``) by ``max_depth`` (deliberate fix, design 8.1)."""
    return torch.where(torch.isfinite(depth), depth, torch.full_like(depth, max_depth))


def _supervised_frames(t: int, first_frame: int, what: str) -> int:
    if not 0 <= first_frame < t:
        raise ValueError(f"{what}: first_frame must be in [0, T-1] = [0, {t - 1}], got {first_frame}")
    return t - first_frame


def _check_levels(preds: Sequence[torch.Tensor], batch: int, frames: int, what: str, channels: int | None) -> None:
    if len(preds) == 0:
        raise ValueError(f"{what}: the list of per-level predictions is empty")
    for i, p in enumerate(preds):
        if p.dim() != 5 or p.shape[0] != batch or p.shape[1] != frames:
            raise ValueError(
                f"{what}: level {i} prediction must be [B={batch}, T={frames}, C, h, w], got {list(p.shape)}"
            )
        if channels is not None and p.shape[2] != channels:
            raise ValueError(f"{what}: level {i} prediction must have {channels} channel(s), got {p.shape[2]}")


def _weights(level_weights: Sequence[float] | None, default: list[float], levels: int, what: str) -> list[float]:
    w = default if level_weights is None else [float(x) for x in level_weights]
    if len(w) != levels:
        raise ValueError(f"{what}: {len(w)} level weights for {levels} prediction levels")
    return w


def depth_loss(
    pred_depths: Sequence[torch.Tensor],
    gt_depth: torch.Tensor,
    *,
    mask: torch.Tensor | None = None,
    first_frame: int = FIRST_SUPERVISED_FRAME,
    level_weights: Sequence[float] | None = None,
    min_depth: float = LOSS_MIN_DEPTH,
    max_depth: float = LOSS_MAX_DEPTH,
) -> torch.Tensor:
    """Multi-level L1 loss on log depth (design 8.1).

    Args:
        pred_depths: per-level predicted depth in metres, finest first, each ``[B, T, 1, h_l, w_l]``.
        gt_depth: ground-truth depth in metres, ``[B, T, 1, H, W]``. Non-finite values count as ``max_depth``.
        mask: optional validity mask ``[B, T, 1, H, W]`` (bool or 0/1). ``None`` (default) is the original, unmasked
            loss. With a mask, each level's target is the BL2-weighted mean of the *valid* log-depth pixels
            (``BL2(m * pre(gt)) / BL2(m)``), level pixels with no valid source are ignored, and each frame's term is
            the mean over its valid pixels (batch pooled, ``max(count, 1)`` as denominator). An all-true mask gives
            the unmasked value up to float rounding.
        first_frame: first supervised frame (default 1; frames before it are ignored).
        level_weights: per-level weights, finest first; default :func:`depth_level_weights`.
        min_depth, max_depth: the clip range of ``pre``.
    Returns:
        Scalar loss (float32, or float64 if the inputs are float64).
    """
    if gt_depth.dim() != 5 or gt_depth.shape[2] != 1:
        raise ValueError(f"depth_loss: gt_depth must be [B, T, 1, H, W], got {list(gt_depth.shape)}")
    b, t, _, h, w = gt_depth.shape
    n_frames = _supervised_frames(t, first_frame, "depth_loss")
    _check_levels(pred_depths, b, t, "depth_loss", channels=1)
    weights = _weights(level_weights, depth_level_weights(len(pred_depths)), len(pred_depths), "depth_loss")
    dtype = torch.promote_types(gt_depth.dtype, torch.float32)

    gt = sanitize_gt_depth(gt_depth[:, first_frame:].to(dtype), max_depth)
    log_gt = log_depth(gt, min_depth, max_depth).reshape(b * n_frames, 1, h, w)
    if mask is not None:
        if mask.shape != gt_depth.shape:
            raise ValueError(
                f"depth_loss: mask must have the shape of gt_depth {list(gt_depth.shape)}, got {list(mask.shape)}"
            )
        m = mask[:, first_frame:].reshape(b * n_frames, 1, h, w).to(dtype)
        masked_log_gt = log_gt * m

    total = gt.new_zeros(())
    for i, pred in enumerate(pred_depths):
        size = tuple(pred.shape[-2:])
        log_pred = log_depth(pred[:, first_frame:].to(dtype), min_depth, max_depth).reshape(b * n_frames, 1, *size)
        if mask is None:
            err = (resize_bl2(log_gt, size) - log_pred).abs()
            level = err.mean()  # equal frame sizes: mean over (b, t, h, w) == sum_t mean_(b,h,w) / n_frames
        else:
            weight = resize_bl2(m, size)
            valid = weight > 1e-6
            target = resize_bl2(masked_log_gt, size) / weight.clamp_min(1e-6)
            err = torch.where(valid, (target - log_pred).abs(), torch.zeros_like(log_pred))
            err_sum = err.reshape(b, n_frames, -1).sum(dim=(0, 2))
            count = valid.reshape(b, n_frames, -1).sum(dim=(0, 2)).clamp_min(1)
            level = (err_sum / count).mean()
        total = total + weights[i] * level
    return total


def semantic_loss(
    pred_semantic: Sequence[torch.Tensor],
    gt_labels: torch.Tensor,
    *,
    from_logits: bool = False,
    first_frame: int = FIRST_SUPERVISED_FRAME,
    level_weights: Sequence[float] | None = None,
    epsilon: float = SCCE_EPSILON,
    class_weights: Sequence[float] | None = None,
) -> torch.Tensor:
    """Multi-level sparse categorical cross-entropy (design 8.2).

    Args:
        pred_semantic: per-level class scores, finest first, each ``[B, T, N, h_l, w_l]``: softmax probabilities
            (default, the original) or logits (``from_logits=True``).
        gt_labels: integer labels in ``[0, N-1]``, ``[B, T, H, W]`` (or ``[B, T, 1, H, W]``).
        from_logits: use ``log_softmax`` on logits instead of the clipped-probability path (stable deviation).
        first_frame: first supervised frame (default 1).
        level_weights: per-level weights, finest first; default 1 for every level.
        epsilon: the probability clip (Keras ``epsilon()``).
        class_weights: ``N`` weights, one per class (a deviation from the paper, which weighs every pixel
            alike): each level's loss is then ``sum(w[y] * nll) / sum(w[y])`` over its pixels, the weighted mean
            of ``torch.nn.functional.cross_entropy(weight=...)``. ``None``: the paper's plain mean.
    Returns:
        Scalar loss.
    Raises:
        ValueError: a label outside ``[0, N-1]`` (there is no ignore label), or ``class_weights`` not ``N``
            finite numbers >= 0.
    """
    if gt_labels.dim() == 5 and gt_labels.shape[2] == 1:
        gt_labels = gt_labels[:, :, 0]
    if gt_labels.dim() != 4:
        raise ValueError(f"semantic_loss: gt_labels must be [B, T, H, W], got {list(gt_labels.shape)}")
    if gt_labels.dtype.is_floating_point or gt_labels.dtype == torch.bool:
        raise ValueError(f"semantic_loss: gt_labels must be an integer tensor, got {gt_labels.dtype}")
    b, t, h, w = gt_labels.shape
    n_frames = _supervised_frames(t, first_frame, "semantic_loss")
    _check_levels(pred_semantic, b, t, "semantic_loss", channels=None)
    n_classes = pred_semantic[0].shape[2]
    if any(p.shape[2] != n_classes for p in pred_semantic):
        raise ValueError(
            f"semantic_loss: all levels must have the same number of classes, got {[p.shape[2] for p in pred_semantic]}"
        )
    weights = _weights(level_weights, [1.0] * len(pred_semantic), len(pred_semantic), "semantic_loss")

    labels = gt_labels[:, first_frame:].reshape(b * n_frames, 1, h, w).long()
    lo, hi = int(labels.min()), int(labels.max())
    if lo < 0 or hi >= n_classes:
        raise ValueError(
            f"semantic_loss: labels must lie in [0, {n_classes - 1}] for {n_classes} classes, "
            f"found values in [{lo}, {hi}]"
        )

    dtype = torch.promote_types(pred_semantic[0].dtype, torch.float32)
    class_w = None
    if class_weights is not None:
        class_w = torch.as_tensor(class_weights, dtype=dtype, device=labels.device).flatten()
        if class_w.numel() != n_classes or not bool(torch.isfinite(class_w).all()) or bool((class_w < 0).any()):
            raise ValueError(
                f"semantic_loss: class_weights must be {n_classes} finite numbers >= 0, got {class_w.tolist()}"
            )
    total = labels.new_zeros((), dtype=dtype)
    for i, pred in enumerate(pred_semantic):
        size = tuple(pred.shape[-2:])
        scores = pred[:, first_frame:].to(dtype).reshape(b * n_frames, n_classes, *size)
        if from_logits:
            log_p = F.log_softmax(scores, dim=1)
        else:
            log_p = F.log_softmax(torch.log(scores.clamp(epsilon, 1.0 - epsilon)), dim=1)
        target = resize_nn2(labels, size)
        nll = -log_p.gather(1, target)
        if class_w is None:
            level = nll.mean()
        else:
            pixel_w = class_w[target]
            level = (pixel_w * nll).sum() / pixel_w.sum().clamp_min(torch.finfo(dtype).tiny)
        total = total + weights[i] * level
    return total


def median_frequency_weights(counts: Sequence[int], power: float = 0.5) -> list[float]:
    """Class weights for :func:`semantic_loss` from pixel counts: ``(median(f) / f_c) ** power``.

    ``f_c`` is class ``c``'s share of the labelled pixels and the median is taken over the classes present;
    ``power`` 1 is median-frequency balancing (Eigen & Fergus 2015), 0.5 its square root (milder: rare classes
    weighted up, frequent ones barely down). A class absent from ``counts`` gets weight 1 (it is never a target).

    Args:
        counts: ``N`` pixel counts, one per class.
        power: exponent of the frequency ratio, >= 0.
    Returns:
        ``N`` weights.
    """
    freq = torch.as_tensor(counts, dtype=torch.float64)
    if freq.dim() != 1 or freq.numel() == 0 or bool((freq < 0).any()) or float(freq.sum()) <= 0:
        raise ValueError(
            f"median_frequency_weights: counts must be N >= 1 non-negative numbers with a positive sum, "
            f"got {freq.tolist()}"
        )
    if not (math.isfinite(power) and power >= 0):
        raise ValueError(f"median_frequency_weights: power must be a finite number >= 0, got {power}")
    freq = freq / freq.sum()
    median = statistics.median(f for f in freq.tolist() if f > 0)
    return [float((median / f) ** power) if f > 0 else 1.0 for f in freq.tolist()]


@dataclass(frozen=True)
class LossTerms:
    """The loss of one training step and its parts.

    ``total = sum(weights[k] * parts[k])`` over the model's decoders, in their order (:func:`weighted_total`):
    ``depth + semantic_weight * semantic`` for Co-SemDepth. ``parts`` are the unweighted losses by decoder name.
    """

    total: torch.Tensor
    parts: dict[str, torch.Tensor]
    weights: dict[str, float]

    @property
    def depth(self) -> torch.Tensor | None:
        return self.parts.get("depth")

    @property
    def semantic(self) -> torch.Tensor | None:
        return self.parts.get("semantic")

    def as_dict(self) -> dict[str, float]:
        """Detached Python floats for logging: ``total`` and the unweighted parts (``depth``, ``semantic``, ...)."""
        return {"total": float(self.total.detach()), **{k: float(v.detach()) for k, v in self.parts.items()}}


def weighted_total(parts: dict[str, torch.Tensor], weights: dict[str, float]) -> LossTerms:
    """``sum(weights[k] * parts[k])`` in the order of ``parts`` (a weight of 1 adds the part as it is)."""
    if not parts:
        raise ValueError("the loss has no part: nothing to supervise")
    total = None
    for k, part in parts.items():
        w = weights.get(k, 1.0)
        term = part if w == 1.0 else w * part
        total = term if total is None else total + term
    return LossTerms(total=total, parts=dict(parts), weights={k: float(weights.get(k, 1.0)) for k in parts})


def total_loss(
    pred_depths: Sequence[torch.Tensor] | None = None,
    gt_depth: torch.Tensor | None = None,
    pred_semantic: Sequence[torch.Tensor] | None = None,
    gt_labels: torch.Tensor | None = None,
    *,
    semantic_weight: float = SEMANTIC_WEIGHT,
    first_frame: int = FIRST_SUPERVISED_FRAME,
    depth_mask: torch.Tensor | None = None,
    from_logits: bool = False,
    class_weights: Sequence[float] | None = None,
) -> LossTerms:
    """``L_depth + semantic_weight * L_sem`` (design 8.3) for any of the three architectures.

    Co-SemDepth passes both pairs; M4Depth only ``(pred_depths, gt_depth)``; M4Semantic only
    ``(pred_semantic, gt_labels)`` (its total is ``semantic_weight * L_sem``, as in the original).

    Args:
        pred_depths, gt_depth: see :func:`depth_loss`.
        pred_semantic, gt_labels: see :func:`semantic_loss`.
        semantic_weight: weight of the semantic loss (0.1).
        first_frame: first supervised frame (1).
        depth_mask: optional depth validity mask, see :func:`depth_loss`.
        from_logits: ``pred_semantic`` holds logits, see :func:`semantic_loss`.
        class_weights: per-class weights of the semantic loss, see :func:`semantic_loss` (``None``: the paper).
    """
    has_depth = pred_depths is not None or gt_depth is not None
    has_sem = pred_semantic is not None or gt_labels is not None
    if has_depth and (pred_depths is None or gt_depth is None):
        raise ValueError("total_loss: pass both pred_depths and gt_depth, or neither")
    if has_sem and (pred_semantic is None or gt_labels is None):
        raise ValueError("total_loss: pass both pred_semantic and gt_labels, or neither")
    if not (has_depth or has_sem):
        raise ValueError("total_loss: nothing to supervise (no depth and no semantic predictions)")
    parts = {}
    if has_depth:
        parts["depth"] = depth_loss(pred_depths, gt_depth, mask=depth_mask, first_frame=first_frame)
    if has_sem:
        parts["semantic"] = semantic_loss(
            pred_semantic, gt_labels, from_logits=from_logits, first_frame=first_frame, class_weights=class_weights
        )
    return weighted_total(parts, {"depth": 1.0, "semantic": semantic_weight})


__all__ = [
    "FIRST_SUPERVISED_FRAME",
    "LOSS_MAX_DEPTH",
    "LOSS_MIN_DEPTH",
    "LossTerms",
    "SCCE_EPSILON",
    "SEMANTIC_WEIGHT",
    "depth_level_weights",
    "depth_loss",
    "log_depth",
    "median_frequency_weights",
    "sanitize_gt_depth",
    "semantic_loss",
    "total_loss",
    "weighted_total",
]
