"""Metrics (design 11), best-checkpoint rule (design 9.5) and tables (design 15) against hand-computed values."""

from __future__ import annotations

import math

import pytest
import torch

from cosemdepth.errors import ConfigError, DatasetError
from cosemdepth.measures.metrics import (
    DEPTH_METRICS,
    ConfusionMatrix,
    DepthMetrics,
    EvaluationMetrics,
    LabelRangeError,
    depth_metrics,
    format_markdown_table,
    format_perfs,
    is_better,
    is_better_by,
    selection_rule,
)

# --- per-frame depth metrics -------------------------------------------------------------------------------------

# GT 2, 4, 0.5 and 0 (invalid); predictions 1, 5, 0.5 and 3. Ratios max(g/e, e/g): 2, 1.25, 1.
GT_A = torch.tensor([[2.0, 4.0], [0.5, 0.0]])
PRED_A = torch.tensor([[1.0, 5.0], [0.5, 3.0]])
LOG_SQ = [math.log(2.0) ** 2, math.log(0.8) ** 2, 0.0]  # squared log errors of the three valid pixels
EXPECTED_A = {
    "abs_rel": (1 / 2 + 1 / 4 + 0) / 3,
    "sq_rel": (1 / 2 + 1 / 4 + 0) / 3,
    "rmse": math.sqrt((1 + 1 + 0) / 3),
    "rmse_log": math.sqrt((LOG_SQ[0] + LOG_SQ[1]) / 2),  # quirk: the 0.5 m pixel is dropped
    "rmse_log_fixed": math.sqrt(sum(LOG_SQ) / 3),
    "delta1": 1 / 3,  # 1.25 is not < 1.25
    "delta2": 2 / 3,
    "delta3": 2 / 3,  # 2 >= 1.25^3 = 1.953
}


def test_depth_metrics_hand_computed_single_frame():
    m = depth_metrics(GT_A, PRED_A)
    assert set(m) == set(EXPECTED_A)
    for k, v in EXPECTED_A.items():
        assert m[k].dim() == 0
        assert float(m[k]) == pytest.approx(v, rel=1e-5), k


def test_depth_metrics_batched_shape():
    gt = torch.stack([GT_A, torch.full((2, 2), 3.0)])[:, None]
    pred = torch.stack([PRED_A, torch.full((2, 2), 3.0)])[:, None]
    m = depth_metrics(gt, pred)
    assert m["rmse"].shape == (2,)
    assert float(m["rmse"][0]) == pytest.approx(EXPECTED_A["rmse"], rel=1e-6)
    assert float(m["rmse"][1]) == 0.0 and float(m["delta1"][1]) == 1.0


def test_depth_metrics_clipping_and_non_finite_gt():
    # GT 100 and inf count as 80; NaN GT is invalid; predictions 90 -> 80 and 0 -> 0.001.
    gt = torch.tensor([[100.0, math.inf], [math.nan, 10.0]])
    pred = torch.tensor([[90.0, 80.0], [5.0, 0.0]])
    m = depth_metrics(gt, pred)
    assert float(m["abs_rel"]) == pytest.approx((10.0 - 0.001) / 10.0 / 3, rel=1e-5)
    assert float(m["rmse"]) == pytest.approx(math.sqrt((10.0 - 0.001) ** 2 / 3), rel=1e-6)
    assert float(m["delta1"]) == pytest.approx(2 / 3)
    # The cap is configurable: with 200 m, GT 100 vs prediction 90 is an error.
    m200 = depth_metrics(gt, pred, max_depth=200.0)
    assert float(m200["abs_rel"]) > float(m["abs_rel"])


def test_rmse_log_quirk_excludes_gt_up_to_one_metre():
    # Only the 3 m pixel has log(g + 1e-6) > 1e-6; it is exact, so the quirky RMSE_log is 0.
    gt = torch.tensor([[0.5, 1.0], [0.8, 3.0]])
    pred = torch.tensor([[1.0, 2.0], [0.4, 3.0]])
    m = depth_metrics(gt, pred)
    assert float(m["rmse_log"]) == 0.0
    expected_fixed = math.sqrt((math.log(0.5) ** 2 + math.log(0.5) ** 2 + math.log(2.0) ** 2) / 4)
    assert float(m["rmse_log_fixed"]) == pytest.approx(expected_fixed, rel=1e-5)
    # A frame whose GT is all <= 1 m has an empty quirk mask: 0 by the max(sum m, 1) rule.
    near = depth_metrics(torch.full((2, 2), 0.9), torch.full((2, 2), 0.3))
    assert float(near["rmse_log"]) == 0.0 and float(near["rmse_log_fixed"]) > 1.0


def test_frame_without_valid_pixel_gives_zero_not_nan():
    m = depth_metrics(torch.zeros(2, 2), torch.ones(2, 2))
    assert all(float(v) == 0.0 for v in m.values())


def test_depth_metrics_rejects_bad_shapes():
    with pytest.raises(ValueError, match="same shape"):
        depth_metrics(torch.ones(2, 2), torch.ones(2, 3))
    with pytest.raises(ValueError, match=r"\[B, 1, H, W\]"):
        depth_metrics(torch.ones(2, 3, 2, 2), torch.ones(2, 3, 2, 2))


# --- accumulation over frames ------------------------------------------------------------------------------------


def test_per_frame_mean_differs_from_pixel_pooling():
    # Frame 1: one valid pixel with error 2 (RMSE 2). Frame 2: four exact pixels (RMSE 0).
    # Per-frame mean: (2 + 0) / 2 = 1. Pixel-pooled would be sqrt(4 / 5) = 0.894.
    acc = DepthMetrics()
    acc.update(torch.tensor([[4.0, 0.0], [0.0, 0.0]]), torch.tensor([[2.0, 1.0], [1.0, 1.0]]))
    acc.update(torch.full((2, 2), 5.0), torch.full((2, 2), 5.0))
    res = acc.compute()
    assert res["rmse"] == pytest.approx(1.0, rel=1e-6)
    assert res["rmse"] != pytest.approx(math.sqrt(4 / 5), rel=1e-3)
    assert res["abs_rel"] == pytest.approx((0.5 + 0.0) / 2, rel=1e-5)
    assert res["depth_frames"] == 2
    assert acc.per_frame()["rmse"].tolist() == pytest.approx([2.0, 0.0], rel=1e-6)


def test_excluded_frames_do_not_count():
    gt = torch.stack([torch.full((2, 2), 10.0), GT_A, torch.full((2, 2), 10.0)])[:, None]
    pred = torch.stack([torch.full((2, 2), 1000.0), PRED_A, torch.full((2, 2), 10.0)])[:, None]
    acc = DepthMetrics()
    acc.update(gt, pred, include=torch.tensor([False, True, True]))  # frame 0: a reset frame at 1000 m
    res = acc.compute()
    assert len(acc) == 2
    assert res["rmse"] == pytest.approx(EXPECTED_A["rmse"] / 2, rel=1e-6)
    assert res["delta1"] == pytest.approx((EXPECTED_A["delta1"] + 1.0) / 2, rel=1e-6)
    acc.update(torch.full((2, 2), 10.0), torch.full((2, 2), 1000.0), include=False)
    assert len(acc) == 2 and acc.compute()["rmse"] == pytest.approx(res["rmse"])
    acc.reset()
    assert len(acc) == 0 and math.isnan(acc.compute()["rmse"])
    with pytest.raises(ValueError, match="one flag per frame"):
        acc.update(gt, pred, include=torch.tensor([True, False]))


# --- confusion matrix and mIoU -----------------------------------------------------------------------------------

# 4 classes. GT [[0, 0], [1, 1]], prediction [[0, 1], [1, 2]]: class 2 is predicted but absent from GT, class 3 is
# absent from both.
GT_L = torch.tensor([[0, 0], [1, 1]])
PRED_L = torch.tensor([[0, 1], [1, 2]])


def test_confusion_matrix_iou_and_miou_keras_semantics():
    cm = ConfusionMatrix(4)
    cm.update(GT_L, PRED_L)
    assert cm.matrix.dtype == torch.int64
    assert cm.matrix.tolist() == [[1, 1, 0, 0], [0, 1, 1, 0], [0, 0, 0, 0], [0, 0, 0, 0]]
    iou = cm.iou()
    # IoU_0 = 1 / (2 + 1 - 1); IoU_1 = 1 / (2 + 2 - 1); IoU_2 = 0 / (0 + 1 - 0); IoU_3 = 0 / 0 -> NaN (excluded).
    assert iou[:3].tolist() == pytest.approx([1 / 2, 1 / 3, 0.0])
    assert math.isnan(float(iou[3]))
    assert cm.miou() == pytest.approx((1 / 2 + 1 / 3 + 0.0) / 3)
    assert cm.total() == 4


def test_confusion_matrix_is_global_not_per_frame_average():
    # Frame 1: perfect on class 0 (IoU 1). Frame 2: 1 of 3 class-0 pixels right, the rest predicted as class 1.
    cm = ConfusionMatrix(2)
    cm.update(torch.zeros(1, 2, 2, dtype=torch.long), torch.zeros(1, 2, 2, dtype=torch.long))
    cm.update(torch.tensor([[[0, 0], [0, 1]]]), torch.tensor([[[0, 1], [1, 1]]]))
    # Global: class 0 TP 5, FN 2, FP 0 -> 5/7; class 1 TP 1, FP 2 -> 1/3.
    assert cm.iou().tolist() == pytest.approx([5 / 7, 1 / 3])
    assert cm.miou() == pytest.approx((5 / 7 + 1 / 3) / 2)


def test_confusion_matrix_include_and_shapes():
    cm = ConfusionMatrix(4)
    gt = torch.stack([GT_L, torch.full((2, 2), 3)])[:, None]  # [B, 1, H, W]
    pred = torch.stack([PRED_L, torch.full((2, 2), 3)])[:, None]
    cm.update(gt, pred, include=torch.tensor([True, False]))
    assert cm.miou() == pytest.approx((1 / 2 + 1 / 3 + 0.0) / 3)
    cm.update(gt[1:], pred[1:])
    assert float(cm.iou()[3]) == 1.0


def test_confusion_matrix_label_range_and_ignore_index():
    cm = ConfusionMatrix(3)
    with pytest.raises(LabelRangeError, match=r"ground-truth labels must lie in \[0, 2\]"):
        cm.update(torch.tensor([[0, 3]]), torch.tensor([[0, 1]]))
    with pytest.raises(ValueError, match="predicted labels"):
        cm.update(torch.tensor([[0, 1]]), torch.tensor([[0, -1]]))
    assert issubclass(LabelRangeError, DatasetError)
    assert cm.total() == 0
    with pytest.raises(ValueError, match="integer labels"):
        cm.update(torch.zeros(2, 2), torch.zeros(2, 2))

    ign = ConfusionMatrix(3, ignore_index=255)
    ign.update(torch.tensor([[0, 255], [1, 255]]), torch.tensor([[0, 2], [1, 1]]))
    assert ign.total() == 2 and ign.miou() == pytest.approx(1.0)


def test_evaluation_metrics_both_tasks():
    ev = EvaluationMetrics(4)
    gt_depth = torch.stack([torch.full((2, 2), 10.0), GT_A])[:, None]
    pred_depth = torch.stack([torch.full((2, 2), 1000.0), PRED_A])[:, None]
    gt_labels = torch.stack([torch.full((2, 2), 3), GT_L])  # [B, H, W]
    probs = torch.nn.functional.one_hot(torch.stack([torch.zeros(2, 2, dtype=torch.long), PRED_L]), 4)
    probs = probs.permute(0, 3, 1, 2).float() * 0.7 + 0.075  # argmax = PRED_L for frame 1
    ev.update(
        gt_depth=gt_depth,
        pred_depth=pred_depth,
        gt_labels=gt_labels,
        pred_semantic=probs,
        include=torch.tensor([False, True]),
    )
    res = ev.compute()
    assert res["rmse"] == pytest.approx(EXPECTED_A["rmse"], rel=1e-6)
    assert res["miou"] == pytest.approx((1 / 2 + 1 / 3 + 0.0) / 3)
    assert res["iou"][:3] == pytest.approx([1 / 2, 1 / 3, 0.0]) and math.isnan(res["iou"][3])
    assert res["depth_frames"] == 1 and res["semantic_frames"] == 1

    depth_only = EvaluationMetrics(None)
    depth_only.update(gt_depth=gt_depth, pred_depth=pred_depth)
    assert "miou" not in depth_only.compute()
    sem_only = EvaluationMetrics(4, depth=False)
    sem_only.update(gt_labels=GT_L[None], pred_semantic=PRED_L[None])
    assert set(sem_only.compute()) == {"miou", "iou", "semantic_frames"}


# --- best-checkpoint selection -----------------------------------------------------------------------------------

BEST = {
    "abs_rel": 0.1,
    "sq_rel": 1.0,
    "rmse": 7.0,
    "rmse_log": 0.2,
    "delta1": 0.9,
    "delta2": 0.95,
    "delta3": 0.97,
    "miou": 0.7,
}


def _new(improve: tuple[str, ...], miou: float = 0.71) -> dict[str, float]:
    new = dict(BEST, miou=miou)
    for k in DEPTH_METRICS:
        if k in improve:
            new[k] = BEST[k] * (0.9 if k.startswith(("abs", "sq", "rmse")) else 1.01)
        else:
            new[k] = BEST[k] * (1.1 if k.startswith(("abs", "sq", "rmse")) else 0.99)
    return new


def test_is_better_paper_rule():
    four = ("abs_rel", "rmse", "delta1", "delta3")
    assert is_better(_new(four), BEST)
    assert not is_better(_new(four[:3]), BEST)  # only 3 of 7 depth metrics
    assert not is_better(_new(four, miou=0.7), BEST)  # mIoU equal: not strictly better
    assert not is_better(_new(DEPTH_METRICS, miou=0.69), BEST)  # all depth better, mIoU worse
    equal = dict(BEST, miou=0.8)
    equal["rmse"], equal["abs_rel"], equal["delta1"] = 6.0, 0.05, 0.95
    equal["delta2"] = BEST["delta2"]  # ties do not count
    assert not is_better(equal, BEST)
    equal["sq_rel"] = 0.5
    assert is_better(equal, BEST)
    assert is_better(BEST, None)  # no best yet


def test_is_better_single_task_restrictions():
    depth_keys = {k: v for k, v in BEST.items() if k != "miou"}
    assert is_better(
        {k: v for k, v in _new(("abs_rel", "sq_rel", "rmse", "rmse_log")).items() if k != "miou"}, depth_keys
    )
    assert not is_better({k: v for k, v in _new(("abs_rel", "sq_rel", "rmse")).items() if k != "miou"}, depth_keys)
    assert is_better({"miou": 0.71, "rmse": None}, {"miou": 0.7})
    assert not is_better({"miou": 0.7}, {"miou": 0.7})
    with pytest.raises(ValueError, match="only"):
        is_better({"miou": 0.8}, BEST)
    with pytest.raises(ValueError, match="neither"):
        is_better({"loss": 1.0}, {"loss": 2.0})


def test_is_better_nan_handling():
    nan_new = _new(DEPTH_METRICS)
    nan_new["miou"] = math.nan
    assert not is_better(nan_new, BEST)
    nan_best = {k: math.nan for k in BEST}
    assert is_better(BEST, nan_best)


def test_is_better_by_one_metric():
    by_rmse = is_better_by("rmse")
    assert by_rmse({"rmse": 6.9}, {"rmse": 7.0}) and not by_rmse({"rmse": 7.0}, {"rmse": 7.0})
    assert by_rmse({"rmse": 1.0}, None)
    by_miou = is_better_by("miou")
    assert by_miou({"miou": 0.8}, {"miou": 0.7}) and not by_miou({"miou": 0.6}, {"miou": 0.7})
    by_loss = is_better_by("val_loss", "min")
    assert by_loss({"val_loss": 1.0}, {"val_loss": 2.0})
    with pytest.raises(ConfigError, match="unknown metric"):
        is_better_by("val_loss")
    with pytest.raises(ConfigError, match="min' or 'max"):
        is_better_by("rmse", "lower")
    assert selection_rule("paper") is is_better
    assert selection_rule("delta1")({"delta1": 0.95}, {"delta1": 0.9})
    assert selection_rule("rmse:max")({"rmse": 8.0}, {"rmse": 7.0})


# --- reports -----------------------------------------------------------------------------------------------------


def test_markdown_table_like_the_paper():
    classes = ["Sky", "Water", "Trees", "Land", "Boulders", "Road", "Others"]
    results = {
        "Co-SemDepth": {
            "params": 5_202_528,
            "ms_per_frame": 49.6,
            "miou": 0.7424,
            "rmse": 7.15,
            "abs_rel": 0.103,
            "delta1": 0.921,
            "delta2": 0.954,
            "delta3": 0.9694,
            "iou": [0.885, 0.837, 0.794, 0.817, 0.344, 0.947, 0.6012],
        },
        "M4Depth": {
            "params": 3_060_000,
            "ms_per_frame": 44.9,
            "rmse": 6.821,
            "abs_rel": 0.0973,
            "delta1": 0.9226,
            "delta2": 0.9562,
            "delta3": 0.9718,
        },
    }
    text = format_markdown_table(results, classes)
    lines = text.splitlines()
    assert lines[0] == "| model | params | ms/frame | mIoU | RMSE | AbsRel | δ<1.25 | δ<1.25² | δ<1.25³ |"
    assert lines[2] == "| Co-SemDepth | 5.20 M | 49.6 | 74.24% | 7.150 | 0.1030 | 92.10% | 95.40% | 96.94% |"
    assert lines[3] == "| M4Depth | 3.06 M | 44.9 | – | 6.821 | 0.0973 | 92.26% | 95.62% | 97.18% |"
    assert lines[5] == "| model | Sky | Water | Trees | Land | Boulders | Road | Others | mIoU |"
    assert lines[7] == "| Co-SemDepth | 88.50% | 83.70% | 79.40% | 81.70% | 34.40% | 94.70% | 60.12% | 74.24% |"
    assert len(lines) == 8  # M4Depth has no per-class row

    extra = format_markdown_table({"x": {"sq_rel": 0.5, "rmse_log": math.nan}}, extra_columns=True).splitlines()
    assert extra[0].endswith("| SqRel | RMSE_log | RMSE_log (fixed) |")
    assert extra[2].endswith("| 0.5000 | – | – |")


def test_perfs_file_order():
    res = dict(BEST, rmse_log_fixed=0.3)
    assert format_perfs(res).splitlines() == ["0.1", "1.0", "7.0", "0.2", "0.9", "0.95", "0.97", "0.7"]
