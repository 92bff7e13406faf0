"""Depth and segmentation metrics exactly as the original evaluation computes them (design 11, 9.5, 15).

Depth (design 11.1), per frame, with ``g = clip(GT, 0, 80)``, ``e = clip(pred, 0.001, 80)``, valid mask
``m = g > 1e-6`` and the NaN-safe masked mean ``sum(x * m) / max(sum(m), 1)``:

==================  ==============================================================================================
``abs_rel``         ``|g - e| / (g + 1e-6)``
``sq_rel``          ``(g - e)^2 / (g + 1e-6)``
``rmse``            ``sqrt(mean (g - e)^2)``
``rmse_log``        ``sqrt(mean (log(g + 1e-6) - log(e + 1e-6))^2)`` over the mask ``log(g + 1e-6) > 1e-6``: the
                    original's bug, which drops every pixel with GT <= 1 m. Kept for comparability (design 11.1).
``rmse_log_fixed``  the same error over the plain valid mask ``m`` (the corrected variant)
``delta1..3``       ``max(g/e, e/g) < 1.25^k``, as fractions in [0, 1]
==================  ==============================================================================================

Sky and far pixels count as 80 m (design 10.7). The dataset value of a metric is the **unweighted mean of its per-frame
values** (design 11.1): RMSE is the mean of per-frame RMSEs, not a pixel-pooled RMSE. Frames marked as not included
(the reset frames of the test protocol, design 11.3) are left out.

Segmentation (design 11.2): one global confusion matrix over all included frames and pixels; ``IoU_c = TP / (TP + FP +
FN)``, and mIoU is the mean over the classes with a non-zero denominator (Keras ``MeanIoU``): a class absent from both
GT and prediction is left out, a class predicted but absent from GT counts with IoU 0.

Best checkpoint (design 9.5): :func:`is_better`. Tables like the paper's (design 15): :func:`format_markdown_table`.

Per-frame depth metrics are computed in float64 (float32 on MPS, which has no float64); the original used float32.
The difference is rounding only.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Iterable, Mapping, Sequence

import torch

from ..defaults import DEPTH_CAP_M, MIN_DEPTH_M
from ..errors import ConfigError, DatasetError

#: Evaluation clipping (design 10.7): GT to [0, EVAL_MAX_DEPTH], prediction to [EVAL_MIN_PRED, EVAL_MAX_DEPTH].
EVAL_MAX_DEPTH = DEPTH_CAP_M
EVAL_MIN_PRED = MIN_DEPTH_M
#: The epsilon of the original metrics (validity threshold and the ``+ 1e-6`` in divisions and logs).
EPS = 1e-6

#: The seven depth metrics of the original, in the order of its ``perfs-*.txt`` files; ``rmse_log`` is the quirky one.
DEPTH_METRICS = ("abs_rel", "sq_rel", "rmse", "rmse_log", "delta1", "delta2", "delta3")
#: Every per-frame depth value this module computes.
ALL_DEPTH_METRICS = DEPTH_METRICS + ("rmse_log_fixed",)
#: The order of the original ``perfs-midair.txt``: the seven depth metrics, then mIoU (design 11.4).
PERFS_ORDER = DEPTH_METRICS + ("miou",)
#: Whether a lower ("min") or higher ("max") value is better, for every scalar metric.
METRIC_MODES = {
    "abs_rel": "min",
    "sq_rel": "min",
    "rmse": "min",
    "rmse_log": "min",
    "rmse_log_fixed": "min",
    "delta1": "max",
    "delta2": "max",
    "delta3": "max",
    "miou": "max",
}
#: Number of the seven depth metrics that must improve strictly for a new best checkpoint (design 9.5).
MIN_DEPTH_IMPROVED = 4


class LabelRangeError(DatasetError, ValueError):
    """A ground-truth or predicted label outside ``[0, num_classes - 1]`` (and not the ignore index)."""


# ---------------------------------------------------------------------------------------------------------------
# Depth
# ---------------------------------------------------------------------------------------------------------------


def _metric_dtype(device: torch.device) -> torch.dtype:
    return torch.float32 if device.type == "mps" else torch.float64


def _as_frames(x: torch.Tensor, name: str) -> torch.Tensor:
    """``[H, W]`` -> ``[1, H, W]``; ``[B, 1, H, W]`` -> ``[B, H, W]``."""
    if x.dim() == 2:
        return x.unsqueeze(0)
    if x.dim() == 4 and x.shape[1] == 1:
        return x[:, 0]
    raise ValueError(f"{name} must be [H, W] or [B, 1, H, W], got {list(x.shape)}")


def _masked_mean(x: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """``sum(x * m) / max(sum(m), 1)`` over the last two axes, where masked-out NaN/inf count as 0."""
    total = torch.where(m, x, torch.zeros_like(x)).sum(dim=(-2, -1))
    count = m.sum(dim=(-2, -1)).clamp_min(1).to(x.dtype)
    return total / count


def depth_metrics(
    gt: torch.Tensor,
    pred: torch.Tensor,
    *,
    max_depth: float = EVAL_MAX_DEPTH,
    min_pred: float = EVAL_MIN_PRED,
    mask: torch.Tensor | None = None,
) -> dict[str, torch.Tensor]:
    """Per-frame depth metrics of design 11.1.

    Args:
        gt: ground-truth depth in metres, ``[H, W]`` (one frame) or ``[B, 1, H, W]`` (B frames).
        pred: predicted depth in metres, same shape as ``gt`` (upsample it to the GT size first).
        max_depth: the evaluation cap (80 m); GT is clipped to ``[0, max_depth]``, prediction to
            ``[min_pred, max_depth]``.
        min_pred: the prediction floor (0.001 m).
        mask: optional bool, shaped like ``gt``: only these pixels count (e.g. the prediction's validity mask); the
            paper's metrics use every pixel with ground truth.
    Returns:
        ``{name: value}`` for :data:`ALL_DEPTH_METRICS`; each value a 0-d tensor for ``[H, W]`` input, else ``[B]``.
        A frame with no valid pixel gets 0 for every metric (the original's ``max(sum m, 1)``).
    """
    if gt.shape != pred.shape:
        raise ValueError(f"depth_metrics: gt {list(gt.shape)} and pred {list(pred.shape)} must have the same shape")
    single = gt.dim() == 2
    dtype = _metric_dtype(gt.device)
    g = _as_frames(gt, "gt").to(dtype).clamp(0.0, max_depth)
    e = _as_frames(pred, "pred").to(dtype).clamp(min_pred, max_depth)
    valid = g > EPS
    if mask is not None:
        if mask.shape != gt.shape:
            raise ValueError(f"depth_metrics: mask {list(mask.shape)} must have the shape of gt {list(gt.shape)}")
        valid = valid & _as_frames(mask, "mask").to(torch.bool)

    diff = g - e
    sq = diff * diff
    log_g = torch.log(g + EPS)
    log_e = torch.log(e + EPS)
    sq_log = (log_g - log_e) ** 2
    ratio = torch.maximum(g / e, e / g)

    out = {
        "abs_rel": _masked_mean(diff.abs() / (g + EPS), valid),
        "sq_rel": _masked_mean(sq / (g + EPS), valid),
        "rmse": torch.sqrt(_masked_mean(sq, valid)),
        # The original's mask: computed on log(g + 1e-6) instead of g, so GT <= 1 m is excluded (design 11.1).
        "rmse_log": torch.sqrt(_masked_mean(sq_log, log_g > EPS)),
        "delta1": _masked_mean((ratio < 1.25).to(dtype), valid),
        "delta2": _masked_mean((ratio < 1.25**2).to(dtype), valid),
        "delta3": _masked_mean((ratio < 1.25**3).to(dtype), valid),
        "rmse_log_fixed": torch.sqrt(_masked_mean(sq_log, valid)),
    }
    if single:
        out = {k: v[0] for k, v in out.items()}
    return out


def _include_mask(include: Any, frames: int, device: torch.device) -> torch.Tensor:
    if include is None:
        return torch.ones(frames, dtype=torch.bool, device=device)
    inc = torch.as_tensor(include, device=device)
    if inc.dtype != torch.bool:
        raise ValueError(f"include must be boolean, got {inc.dtype}")
    inc = inc.reshape(-1)
    if inc.numel() != frames:
        raise ValueError(f"include must have one flag per frame ({frames}), got {inc.numel()}")
    return inc


class DepthMetrics:
    """Accumulates per-frame depth metrics; the dataset value is the unweighted mean over the included frames.

    ``update(gt, pred, include)`` takes one frame ``[H, W]`` or a batch ``[B, 1, H, W]`` and an optional boolean
    ``include`` (scalar or ``[B]``): frames with ``include = False`` (e.g. ``new_traj`` frames) are not counted.
    """

    def __init__(self, *, max_depth: float = EVAL_MAX_DEPTH, min_pred: float = EVAL_MIN_PRED) -> None:
        self.max_depth = float(max_depth)
        self.min_pred = float(min_pred)
        self.reset()

    def reset(self) -> None:
        self._values: dict[str, list[torch.Tensor]] = {k: [] for k in ALL_DEPTH_METRICS}

    def update(self, gt: torch.Tensor, pred: torch.Tensor, include: Any = None) -> dict[str, torch.Tensor]:
        """Add frames; returns their per-frame values (all frames, included or not)."""
        values = depth_metrics(gt, pred, max_depth=self.max_depth, min_pred=self.min_pred)
        frames = 1 if gt.dim() == 2 else gt.shape[0]
        inc = _include_mask(include, frames, gt.device)
        for k, v in values.items():
            self._values[k].append(v.reshape(-1)[inc].detach().cpu())
        return values

    def __len__(self) -> int:
        return int(sum(v.numel() for v in self._values["rmse"]))

    def per_frame(self) -> dict[str, torch.Tensor]:
        """Per-frame values of the included frames, ``{name: [F]}`` (float64)."""
        return {
            k: torch.cat(v).to(torch.float64) if v else torch.zeros(0, dtype=torch.float64)
            for k, v in self._values.items()
        }

    def compute(self) -> dict[str, float]:
        """``{name: mean over included frames}`` plus ``depth_frames``; NaN values when no frame was included."""
        out: dict[str, Any] = {}
        for k, v in self.per_frame().items():
            out[k] = float(v.mean()) if v.numel() else math.nan
        out["depth_frames"] = len(self)
        return out


#: The metrics of :class:`ValidDepthMetrics`.
VALID_DEPTH_METRICS = ("valid_abs_rel", "valid_delta1", "valid_rmse", "coverage")


class ValidDepthMetrics:
    """Depth metrics over the pixels a prediction marks valid, and how many it marks.

    Per frame: AbsRel, delta1 and RMSE over the pixels with ground truth that the prediction's ``valid`` mask keeps
    (the dataset value: mean over the frames with at least one such pixel), and the coverage, the fraction of the
    pixels with ground truth that are valid (the dataset value: pooled over the pixels of every included frame).
    """

    def __init__(self, *, max_depth: float = EVAL_MAX_DEPTH, min_pred: float = EVAL_MIN_PRED) -> None:
        self.max_depth = float(max_depth)
        self.min_pred = float(min_pred)
        self.reset()

    def reset(self) -> None:
        self._values: dict[str, list[torch.Tensor]] = {k: [] for k in ("abs_rel", "delta1", "rmse")}
        self._kept: list[torch.Tensor] = []
        self._total: list[torch.Tensor] = []

    def update(
        self, gt: torch.Tensor, pred: torch.Tensor, valid: torch.Tensor, include: Any = None
    ) -> dict[str, torch.Tensor]:
        """Add frames ``[B, 1, H, W]`` (or one ``[H, W]``); returns their per-frame ``{abs_rel, delta1, rmse,
        coverage, valid_pixels, gt_pixels}`` (all frames, included or not)."""
        values = depth_metrics(gt, pred, max_depth=self.max_depth, min_pred=self.min_pred, mask=valid)
        has_gt = _as_frames(gt, "gt").clamp(0.0, self.max_depth) > EPS
        kept = (has_gt & _as_frames(valid, "valid").to(torch.bool)).sum(dim=(-2, -1)).reshape(-1)
        total = has_gt.sum(dim=(-2, -1)).reshape(-1)
        inc = _include_mask(include, total.numel(), gt.device)
        scored = inc & (kept > 0)
        for k in self._values:
            self._values[k].append(values[k].reshape(-1)[scored].detach().cpu())
        self._kept.append(kept[inc].cpu())
        self._total.append(total[inc].cpu())
        out = {k: values[k].reshape(-1) for k in self._values}
        out["coverage"] = kept.to(torch.float64) / total.clamp_min(1).to(torch.float64)
        out["valid_pixels"], out["gt_pixels"] = kept, total
        return out

    def compute(self) -> dict[str, float]:
        """``{valid_abs_rel, valid_delta1, valid_rmse, coverage, valid_frames}``; NaN where nothing was counted."""
        out: dict[str, Any] = {}
        for k, v in self._values.items():
            t = torch.cat(v).to(torch.float64) if v else torch.zeros(0, dtype=torch.float64)
            out[f"valid_{k}"] = float(t.mean()) if t.numel() else math.nan
            if k == "abs_rel":
                out["valid_frames"] = int(t.numel())
        kept = int(torch.cat(self._kept).sum()) if self._kept else 0
        total = int(torch.cat(self._total).sum()) if self._total else 0
        out["coverage"] = kept / total if total else math.nan
        return out


# ---------------------------------------------------------------------------------------------------------------
# Segmentation
# ---------------------------------------------------------------------------------------------------------------


def _label_frames(x: torch.Tensor, name: str) -> torch.Tensor:
    """``[H, W]`` -> ``[1, H, W]``; ``[B, H, W]`` unchanged; ``[B, 1, H, W]`` -> ``[B, H, W]``."""
    if x.dtype.is_floating_point or x.dtype.is_complex or x.dtype == torch.bool:
        raise ValueError(f"{name} must hold integer labels, got {x.dtype} (take the argmax of probabilities first)")
    if x.dim() == 2:
        return x.unsqueeze(0)
    if x.dim() == 3:
        return x
    if x.dim() == 4 and x.shape[1] == 1:
        return x[:, 0]
    raise ValueError(f"{name} must be [H, W], [B, H, W] or [B, 1, H, W], got {list(x.shape)}")


class ConfusionMatrix:
    """One global confusion matrix over all included frames and pixels (Keras ``MeanIoU``, design 11.2).

    ``matrix[i, j]`` counts pixels with ground truth ``i`` predicted as ``j`` (int64). Labels must lie in
    ``[0, num_classes - 1]``; there is no ignore label unless ``ignore_index`` is given, in which case GT pixels with
    that value are skipped.
    """

    def __init__(self, num_classes: int, *, ignore_index: int | None = None) -> None:
        if int(num_classes) < 1:
            raise ValueError(f"num_classes must be >= 1, got {num_classes}")
        self.num_classes = int(num_classes)
        self.ignore_index = None if ignore_index is None else int(ignore_index)
        self.reset()

    def reset(self) -> None:
        self.matrix = torch.zeros(self.num_classes, self.num_classes, dtype=torch.int64)
        self.frames = 0  # number of included frames seen

    def update(self, gt: torch.Tensor, pred: torch.Tensor, include: Any = None) -> None:
        """Add frames of labels.

        Args:
            gt: ground-truth labels, ``[H, W]``, ``[B, H, W]`` or ``[B, 1, H, W]``, integer.
            pred: predicted labels (argmax of the probabilities), same shape.
            include: optional boolean per frame (scalar or ``[B]``); excluded frames are not counted.
        Raises:
            LabelRangeError: a label outside ``[0, num_classes - 1]`` (GT pixels equal to ``ignore_index`` apart).
        """
        if gt.shape != pred.shape:
            raise ValueError(
                f"ConfusionMatrix.update: gt {list(gt.shape)} and pred {list(pred.shape)} must have the same shape"
            )
        g = _label_frames(gt, "gt").long()
        p = _label_frames(pred, "pred").long()
        inc = _include_mask(include, g.shape[0], g.device)
        g, p = g[inc], p[inc]
        frames = g.shape[0]
        if self.ignore_index is not None:
            keep = g != self.ignore_index
            g, p = g[keep], p[keep]
        g, p = g.reshape(-1), p.reshape(-1)
        n = self.num_classes
        if g.numel():
            for name, x in (("ground-truth", g), ("predicted", p)):
                lo, hi = int(x.min()), int(x.max())
                if lo < 0 or hi >= n:
                    extra = "" if self.ignore_index is None else f" (ignore_index={self.ignore_index})"
                    raise LabelRangeError(
                        f"{name} labels must lie in [0, {n - 1}] for {n} classes{extra}; found values in [{lo}, {hi}]"
                    )
            self.matrix += torch.bincount(g * n + p, minlength=n * n).reshape(n, n).cpu()
        self.frames += frames

    def iou(self) -> torch.Tensor:
        """Per-class IoU ``TP / (TP + FP + FN)`` as float64 ``[N]``; NaN for a class absent from GT and prediction."""
        m = self.matrix.to(torch.float64)
        tp = m.diagonal()
        denom = m.sum(dim=0) + m.sum(dim=1) - tp
        return torch.where(denom > 0, tp / denom.clamp_min(1), torch.full_like(tp, math.nan))

    def miou(self) -> float:
        """Mean IoU over the classes with a non-zero denominator; NaN when nothing was counted."""
        iou = self.iou()
        present = ~torch.isnan(iou)
        return float(iou[present].mean()) if bool(present.any()) else math.nan

    def total(self) -> int:
        """Number of pixels counted."""
        return int(self.matrix.sum())


# ---------------------------------------------------------------------------------------------------------------
# Both tasks
# ---------------------------------------------------------------------------------------------------------------


class EvaluationMetrics:
    """Depth metrics and the confusion matrix of a model, updated together with one ``include`` mask.

    Args:
        num_classes: number of classes, or ``None`` for a depth-only model.
        depth: whether the model predicts depth.
    """

    def __init__(
        self,
        num_classes: int | None,
        *,
        depth: bool = True,
        max_depth: float = EVAL_MAX_DEPTH,
        min_pred: float = EVAL_MIN_PRED,
        ignore_index: int | None = None,
    ) -> None:
        if num_classes is None and not depth:
            raise ValueError("EvaluationMetrics: nothing to evaluate (no depth and no classes)")
        self.depth = DepthMetrics(max_depth=max_depth, min_pred=min_pred) if depth else None
        self.semantic = None if num_classes is None else ConfusionMatrix(num_classes, ignore_index=ignore_index)

    def reset(self) -> None:
        if self.depth is not None:
            self.depth.reset()
        if self.semantic is not None:
            self.semantic.reset()

    def update(
        self,
        *,
        gt_depth: torch.Tensor | None = None,
        pred_depth: torch.Tensor | None = None,
        gt_labels: torch.Tensor | None = None,
        pred_semantic: torch.Tensor | None = None,
        include: Any = None,
        depth_include: Any = None,
    ) -> None:
        """Add a batch of frames.

        Args:
            gt_depth, pred_depth: ``[B, 1, H, W]`` metres (depth models).
            gt_labels: ``[B, H, W]`` or ``[B, 1, H, W]`` integer labels (semantic models).
            pred_semantic: ``[B, N, H, W]`` probabilities or logits (argmax is taken over dim 1), or integer labels
                shaped like ``gt_labels``.
            include: optional boolean ``[B]``; excluded frames count in neither metric.
            depth_include: optional boolean ``[B]`` for the depth metrics only (default: ``include``), e.g. frames
                without depth (status ``reset``) whose labels still count.
        """
        if self.depth is not None:
            if gt_depth is None or pred_depth is None:
                raise ValueError("EvaluationMetrics.update: a depth model needs gt_depth and pred_depth")
            self.depth.update(gt_depth, pred_depth, include if depth_include is None else depth_include)
        if self.semantic is not None:
            if gt_labels is None or pred_semantic is None:
                raise ValueError("EvaluationMetrics.update: a semantic model needs gt_labels and pred_semantic")
            if pred_semantic.dtype.is_floating_point:
                if pred_semantic.dim() != 4 or pred_semantic.shape[1] != self.semantic.num_classes:
                    raise ValueError(
                        f"pred_semantic scores must be [B, {self.semantic.num_classes}, H, W], got "
                        f"{list(pred_semantic.shape)}"
                    )
                pred_semantic = pred_semantic.argmax(dim=1, keepdim=gt_labels.dim() == 4)
            self.semantic.update(gt_labels, pred_semantic, include)

    def compute(self) -> dict[str, Any]:
        """Depth metrics (:class:`DepthMetrics`) and ``miou``, ``iou`` (list per class), ``semantic_frames``."""
        out: dict[str, Any] = {}
        if self.depth is not None:
            out.update(self.depth.compute())
        if self.semantic is not None:
            out["miou"] = self.semantic.miou()
            out["iou"] = [float(x) for x in self.semantic.iou()]
            out["semantic_frames"] = self.semantic.frames
        return out


# ---------------------------------------------------------------------------------------------------------------
# Best-checkpoint selection
# ---------------------------------------------------------------------------------------------------------------


def _value(d: Mapping[str, Any], key: str) -> float | None:
    v = d.get(key)
    return None if v is None else float(v)


def _improved(new: float, best: float, mode: str) -> bool:
    """Strict improvement; a NaN new value never improves, a finite value improves on a NaN best."""
    if math.isnan(new):
        return False
    if math.isnan(best):
        return True
    return new < best if mode == "min" else new > best


def _has_group(d: Mapping[str, Any], keys: Iterable[str]) -> bool:
    return all(_value(d, k) is not None for k in keys)


def is_better(
    new: Mapping[str, Any], best: Mapping[str, Any] | None, *, min_depth_improved: int = MIN_DEPTH_IMPROVED
) -> bool:
    """The original best-checkpoint rule (design 9.5), restricted naturally to single-task models.

    * Co-SemDepth (both the seven :data:`DEPTH_METRICS` and ``miou`` present): at least ``min_depth_improved`` (4)
      of the seven depth metrics strictly better **and** ``miou`` strictly better.
    * M4Depth (no ``miou``): at least 4 of the 7 depth metrics strictly better.
    * M4Semantic (no depth metrics): ``miou`` strictly better.

    ``rmse_log`` is the original's (quirky) variant. ``best is None`` (no best yet) gives True. A metric group present
    in only one of the two results is an error. NaN handling (not covered by the original): a NaN new value never
    counts as better, and any finite value beats a NaN best.
    """
    if best is None:
        return True
    groups = {"depth": DEPTH_METRICS, "semantic": ("miou",)}
    present = {}
    for name, keys in groups.items():
        in_new, in_best = _has_group(new, keys), _has_group(best, keys)
        if in_new != in_best:
            raise ValueError(
                f"is_better: the {name} metrics {list(keys)} are in {'the new' if in_new else 'the best'} results only"
            )
        present[name] = in_new
    if not any(present.values()):
        raise ValueError(f"is_better: the results hold neither the depth metrics {list(DEPTH_METRICS)} nor 'miou'")
    if present["depth"]:
        n = sum(_improved(_value(new, k), _value(best, k), METRIC_MODES[k]) for k in DEPTH_METRICS)
        if n < min_depth_improved:
            return False
    if present["semantic"]:
        if not _improved(_value(new, "miou"), _value(best, "miou"), "max"):
            return False
    return True


def is_better_by(metric: str, mode: str | None = None) -> Callable[[Mapping[str, Any], Mapping[str, Any] | None], bool]:
    """A rule with the signature of :func:`is_better` that selects on one metric alone.

    Args:
        metric: a key of the results, e.g. ``"rmse"`` or ``"miou"``.
        mode: ``"min"`` or ``"max"``; default from :data:`METRIC_MODES`.
    Raises:
        ConfigError: unknown metric without a mode, or a bad mode.
    """
    if mode is None:
        if metric not in METRIC_MODES:
            raise ConfigError(
                f"unknown metric {metric!r} for best-checkpoint selection; known: "
                f"{sorted(METRIC_MODES)} (or give a mode, min or max)"
            )
        mode = METRIC_MODES[metric]
    if mode not in ("min", "max"):
        raise ConfigError(f"selection mode must be 'min' or 'max', got {mode!r}")

    def rule(new: Mapping[str, Any], best: Mapping[str, Any] | None) -> bool:
        if best is None:
            return True
        a, b = _value(new, metric), _value(best, metric)
        if a is None or b is None:
            raise ValueError(
                f"is_better_by({metric!r}): the metric is missing from the {'new' if a is None else 'best'} results"
            )
        return _improved(a, b, mode)

    rule.__name__ = f"is_better_by_{metric}_{mode}"
    return rule


def selection_rule(name: str) -> Callable[[Mapping[str, Any], Mapping[str, Any] | None], bool]:
    """Parse a best-checkpoint rule name: ``"paper"`` (:func:`is_better`), ``"<metric>"`` or ``"<metric>:<min|max>"``."""
    if name == "paper":
        return is_better
    metric, _, mode = name.partition(":")
    return is_better_by(metric, mode or None)


# ---------------------------------------------------------------------------------------------------------------
# Reports
# ---------------------------------------------------------------------------------------------------------------

_DASH = "–"


def _num(v: Any) -> float | None:
    if v is None:
        return None
    v = float(v)
    return None if math.isnan(v) else v


def _fmt(v: Any, kind: str) -> str:
    x = _num(v)
    if x is None:
        return _DASH
    if kind == "pct":
        return f"{100.0 * x:.2f}%"
    if kind == "params":
        return f"{x / 1e6:.2f} M"
    if kind == "ms":
        return f"{x:.1f}"
    if kind == "rmse":
        return f"{x:.3f}"
    return f"{x:.4f}"


#: Columns of the paper's main table (design 15): (header, result key, format).
TABLE_COLUMNS = (
    ("params", "params", "params"),
    ("ms/frame", "ms_per_frame", "ms"),
    ("mIoU", "miou", "pct"),
    ("RMSE", "rmse", "rmse"),
    ("AbsRel", "abs_rel", "rel"),
    ("δ<1.25", "delta1", "pct"),
    ("δ<1.25²", "delta2", "pct"),
    ("δ<1.25³", "delta3", "pct"),
)
#: Further columns shown with ``extra_columns=True``.
EXTRA_COLUMNS = (
    ("SqRel", "sq_rel", "rel"),
    ("RMSE_log", "rmse_log", "rel"),
    ("RMSE_log (fixed)", "rmse_log_fixed", "rel"),
)


def _row(cells: Sequence[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def format_markdown_table(
    results: Mapping[str, Mapping[str, Any]],
    class_names: Sequence[str] | None = None,
    *,
    extra_columns: bool = False,
) -> str:
    """Markdown tables laid out like the paper's (design 15).

    Args:
        results: ``{row name: result dict}``. Keys used: ``params`` (a count), ``ms_per_frame``, ``miou``, ``rmse``,
            ``abs_rel``, ``delta1..3`` (fractions; shown in percent), ``iou`` (per-class fractions); with
            ``extra_columns`` also ``sq_rel``, ``rmse_log``, ``rmse_log_fixed``. Missing or NaN values show as "–".
        class_names: names of the classes for the per-class IoU table (default ``class 0``, ``class 1``, ...).
        extra_columns: add SqRel, RMSE_log and the corrected RMSE_log.
    Returns:
        The main table, followed by a per-class IoU table when any row has ``iou``.
    """
    cols = TABLE_COLUMNS + (EXTRA_COLUMNS if extra_columns else ())
    lines = [_row(["model"] + [c[0] for c in cols]), _row(["---"] * (len(cols) + 1))]
    for name, res in results.items():
        lines.append(_row([str(name)] + [_fmt(res.get(key), kind) for _, key, kind in cols]))

    iou_rows = {name: res["iou"] for name, res in results.items() if res.get("iou") is not None}
    if iou_rows:
        n = max(len(v) for v in iou_rows.values())
        names = list(class_names) if class_names is not None else [f"class {i}" for i in range(n)]
        if len(names) < n:
            raise ValueError(f"format_markdown_table: {len(names)} class names for {n} per-class IoU values")
        lines += ["", _row(["model"] + names[:n] + ["mIoU"]), _row(["---"] * (n + 2))]
        for name, iou in iou_rows.items():
            cells = [_fmt(iou[i] if i < len(iou) else None, "pct") for i in range(n)]
            lines.append(_row([str(name)] + cells + [_fmt(results[name].get("miou"), "pct")]))
    return "\n".join(lines) + "\n"


def format_perfs(results: Mapping[str, Any]) -> str:
    """The original ``perfs-<dataset>.txt`` content: one value per line in :data:`PERFS_ORDER` (present keys)."""
    return "".join(f"{float(results[k])}\n" for k in PERFS_ORDER if results.get(k) is not None)


__all__ = [
    "ALL_DEPTH_METRICS",
    "ConfusionMatrix",
    "DEPTH_METRICS",
    "DepthMetrics",
    "EVAL_MAX_DEPTH",
    "EVAL_MIN_PRED",
    "EvaluationMetrics",
    "LabelRangeError",
    "METRIC_MODES",
    "MIN_DEPTH_IMPROVED",
    "PERFS_ORDER",
    "depth_metrics",
    "format_markdown_table",
    "format_perfs",
    "is_better",
    "is_better_by",
    "selection_rule",
    "VALID_DEPTH_METRICS",
    "ValidDepthMetrics",
]
