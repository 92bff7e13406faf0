"""Losses (design 8) against hand-computed values on small constructed cases."""

from __future__ import annotations

import math

import pytest
import torch

from cosemdepth.measures.losses import (
    LossTerms,
    depth_level_weights,
    depth_loss,
    median_frequency_weights,
    semantic_loss,
    total_loss,
)

# A 4x4 log-depth map. Level 0 (2x2) targets are its 2x2 block means, level 1 (1x1) target is BL2 4 -> 1, i.e. the mean
# of the central 2x2 pixels (source coordinate 1.5).
LOG_GT = torch.tensor(
    [
        [0.0, 2.0, 1.0, 1.0],
        [2.0, 0.0, 1.0, 1.0],
        [3.0, 3.0, 0.0, 0.0],
        [3.0, 3.0, 0.0, 4.0],
    ],
    dtype=torch.float64,
)
# Block means: [[1, 1], [3, 1]]; central mean: (0 + 1 + 3 + 0) / 4 = 1.
LOG_P0 = torch.tensor([[1.5, 1.0], [2.0, 1.0]], dtype=torch.float64)  # |err| = 0.5, 0, 1, 0 -> mean 0.375
LOG_P1 = torch.tensor([[0.25]], dtype=torch.float64)  # |err| = 0.75
# Loss for one supervised frame: 1.28 * 0.375 + 0.64 * 0.75 = 0.48 + 0.48 = 0.96.
FRAME_LOSS = 0.96


def _seq(*frames: torch.Tensor) -> torch.Tensor:
    """Stack ``[h, w]`` frames into ``[B=1, T, 1, h, w]``."""
    return torch.stack(frames).unsqueeze(0).unsqueeze(2)


def _two_level_case(t: int = 2):
    """GT and predictions for T frames: frame 1 is the hand-computed case, later frames are perfect, frame 0 is
    garbage (NaN predictions, absurd GT) that must be ignored."""
    gt = [torch.full((4, 4), 1e-9, dtype=torch.float64), LOG_GT.exp()]
    p0 = [torch.full((2, 2), math.nan, dtype=torch.float64), LOG_P0.exp()]
    p1 = [torch.full((1, 1), math.nan, dtype=torch.float64), LOG_P1.exp()]
    for _ in range(t - 2):
        gt.append(torch.full((4, 4), math.e, dtype=torch.float64))
        p0.append(torch.full((2, 2), math.e, dtype=torch.float64))
        p1.append(torch.full((1, 1), math.e, dtype=torch.float64))
    return [_seq(*p0), _seq(*p1)], _seq(*gt)


def test_level_weights_for_five_levels():
    assert depth_level_weights(5) == pytest.approx([1.28, 0.64, 0.32, 0.16, 0.08], abs=1e-15)
    assert depth_level_weights(1) == pytest.approx([1.28])


def test_depth_loss_two_levels_hand_computed_and_frame_zero_ignored():
    preds, gt = _two_level_case(t=2)
    loss = depth_loss(preds, gt)
    assert torch.isfinite(loss)  # frame 0 holds NaN predictions: it must not be read
    assert float(loss) == pytest.approx(FRAME_LOSS, abs=1e-12)


def test_depth_loss_averages_over_supervised_frames():
    preds, gt = _two_level_case(t=3)  # frame 2 is perfect: (0.96 + 0) / (T - 1 = 2)
    assert float(depth_loss(preds, gt)) == pytest.approx(FRAME_LOSS / 2, abs=1e-12)


def test_depth_loss_first_frame_is_configurable():
    preds, gt = _two_level_case(t=3)
    # From frame 2 on only the perfect frame is supervised.
    assert float(depth_loss(preds, gt, first_frame=2)) == pytest.approx(0.0, abs=1e-12)
    # From frame 0 on, the NaN predictions of frame 0 enter the loss.
    assert torch.isnan(depth_loss(preds, gt, first_frame=0))
    with pytest.raises(ValueError, match="first_frame"):
        depth_loss(preds, gt, first_frame=3)


def test_depth_loss_logs_before_resizing():
    # GT 2x2 of (1, e^2) per row resized to 1x1: the log-first mean is 1, i.e. exp(1) = 2.718 m; resizing the depth
    # first would give (1 + e^2) / 2 = 4.19 m. A prediction of exactly e m must have zero loss.
    gt = _seq(
        torch.ones(2, 2, dtype=torch.float64), torch.tensor([[1.0, math.e**2], [1.0, math.e**2]], dtype=torch.float64)
    )
    pred = _seq(torch.ones(1, 1, dtype=torch.float64), torch.full((1, 1), math.e, dtype=torch.float64))
    assert float(depth_loss([pred], gt)) == pytest.approx(0.0, abs=1e-12)


def test_depth_loss_batch_mean_and_clipping():
    # Two sequences; for the second, GT 1000 m vs prediction 250 m (both clip to 200) and GT 0.001 vs prediction
    # 0.005 (both clip to 0.01) give zero error; the first has |log 2 - log 1| = log 2 everywhere.
    gt = torch.ones(2, 2, 1, 2, 2, dtype=torch.float64)
    pred = torch.ones(2, 2, 1, 2, 2, dtype=torch.float64)
    pred[0, 1] = 2.0
    gt[1, 1] = torch.tensor([[1000.0, 0.001], [1000.0, 0.001]])
    pred[1, 1] = torch.tensor([[250.0, 0.005], [250.0, 0.005]])
    loss = depth_loss([pred], gt)  # one level at full resolution: weight 1.28, mean over batch of (log 2, 0)
    assert float(loss) == pytest.approx(1.28 * math.log(2) / 2, abs=1e-12)


def test_depth_loss_non_finite_gt_is_capped_with_finite_gradient():
    gt = torch.ones(1, 2, 1, 2, 2)
    gt[0, 1] = torch.tensor([[math.inf, math.nan], [200.0, 50.0]])
    pred = torch.full((1, 2, 1, 2, 2), 50.0, requires_grad=True)
    coarse = torch.full((1, 2, 1, 1, 1), 200.0, requires_grad=True)
    loss = depth_loss([pred, coarse], gt)
    assert torch.isfinite(loss)
    # Level 0: inf, NaN and 200 all count as 200 m: three pixels with |log 200 - log 50| = log 4, one with 0.
    # Level 1 (BL2 4 -> 1 = mean of the 2x2 log map): target (3 log 200 + log 50) / 4, prediction log 200.
    expected = 1.28 * 0.75 * math.log(4) + 0.64 * abs(math.log(200) - (3 * math.log(200) + math.log(50)) / 4)
    assert loss.item() == pytest.approx(expected, rel=1e-6)
    loss.backward()
    assert torch.isfinite(pred.grad).all() and torch.isfinite(coarse.grad).all()
    # d/dpred of 1.28 * mean |log gt - log pred|: -1.28 / 4 / 50 for the three pixels below their target.
    assert float(pred.grad[0, 1, 0, 0, 0]) == pytest.approx(-1.28 / 4 / 50, rel=1e-6)
    assert float(pred.grad[0, 0].abs().sum()) == 0.0  # frame 0 gets no gradient


def test_depth_loss_mask():
    gt = _seq(torch.ones(2, 2), torch.tensor([[1.0, 1.0], [1.0, 1e6]]))
    pred = _seq(torch.ones(2, 2), torch.tensor([[math.e, 1.0], [1.0, 1.0]]))
    mask = torch.ones_like(gt, dtype=torch.bool)
    mask[0, 1, 0, 1, 1] = False  # the absurd GT pixel
    # Full-resolution level: mean over the 3 valid pixels of (1, 0, 0) -> 1/3.
    assert float(depth_loss([pred], gt, mask=mask)) == pytest.approx(1.28 / 3, rel=1e-6)
    # 1x1 level: the target is the mean log of the valid pixels (0), the prediction log 1 = 0.
    coarse = _seq(torch.ones(1, 1), torch.ones(1, 1))
    assert float(depth_loss([pred, coarse], gt, mask=mask)) == pytest.approx(1.28 / 3, rel=1e-6)
    # A level pixel with no valid source pixel is ignored; a frame without any valid pixel contributes 0.
    none = torch.zeros_like(mask)
    assert float(depth_loss([pred, coarse], gt, mask=none)) == 0.0


def test_depth_loss_all_true_mask_matches_unmasked():
    preds, gt = _two_level_case(t=3)
    gt = gt.clone()
    gt[:, 0] = 1.0  # frame 0 is ignored either way; keep it finite for the mask product
    mask = torch.ones_like(gt, dtype=torch.bool)
    assert float(depth_loss(preds, gt, mask=mask)) == pytest.approx(float(depth_loss(preds, gt)), abs=1e-9)


def test_depth_loss_rejects_bad_shapes():
    preds, gt = _two_level_case()
    with pytest.raises(ValueError, match="gt_depth"):
        depth_loss(preds, gt[:, :, 0])
    with pytest.raises(ValueError, match="level 1"):
        depth_loss([preds[0], preds[1][:, :1]], gt)
    with pytest.raises(ValueError, match="level weights"):
        depth_loss(preds, gt, level_weights=[1.0])


# --- semantic ----------------------------------------------------------------------------------------------------


def _probs(rows: list[list[float]], h: int, w: int) -> torch.Tensor:
    """``h*w`` probability vectors (row-major pixels) -> ``[N, h, w]``."""
    return torch.tensor(rows, dtype=torch.float64).T.reshape(-1, h, w)


def _sem_seq(frame1: torch.Tensor, frame0: torch.Tensor | None = None) -> torch.Tensor:
    if frame0 is None:
        frame0 = torch.full_like(frame1, math.nan)
    return torch.stack([frame0, frame1]).unsqueeze(0)


def test_semantic_loss_hand_computed_one_level():
    p = _probs([[0.5, 0.25, 0.25], [0.25, 0.25, 0.5], [0.1, 0.8, 0.1], [0.6, 0.3, 0.1]], 2, 2)
    labels = torch.tensor([[[0, 0], [0, 0]], [[0, 2], [1, 1]]])[None]  # [1, T=2, 2, 2]
    loss = semantic_loss([_sem_seq(p)], labels)
    expected = -(math.log(0.5) + math.log(0.5) + math.log(0.8) + math.log(0.3)) / 4
    assert torch.isfinite(loss)
    assert float(loss) == pytest.approx(expected, abs=1e-12)


def test_semantic_loss_nn2_label_pyramid_and_unit_level_weights():
    # 4x4 labels: NN2 to 2x2 picks rows/cols (1, 3), to 1x1 picks (2, 2).
    lab = torch.zeros(4, 4, dtype=torch.long)
    lab[1, 1], lab[1, 3], lab[3, 1], lab[3, 3] = 1, 2, 2, 1
    lab[2, 2] = 2
    labels = torch.stack([torch.zeros(4, 4, dtype=torch.long), lab])[None]
    # Level 0 (2x2) probabilities: target probability 0.5 at (0,0) and (1,1) (class 1), 0.25 at (0,1), (1,0) (class 2).
    p0 = _probs([[0.25, 0.5, 0.25], [0.5, 0.25, 0.25], [0.5, 0.25, 0.25], [0.25, 0.5, 0.25]], 2, 2)
    # Level 1 (1x1): class 2 has probability 0.2.
    p1 = _probs([[0.4, 0.4, 0.2]], 1, 1)
    loss = semantic_loss([_sem_seq(p0), _sem_seq(p1)], labels)
    expected = -(2 * math.log(0.5) + 2 * math.log(0.25)) / 4 - math.log(0.2)
    assert float(loss) == pytest.approx(expected, abs=1e-12)


def test_semantic_loss_cap_16_118_and_zero_gradient_below_epsilon():
    # The target class has probability 0: clipped to 1e-7, the loss saturates at -log(1e-7) = 16.118.
    p = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64).reshape(1, 1, 3, 1, 1).repeat(1, 2, 1, 1, 1)
    p.requires_grad_(True)
    labels = torch.ones(1, 2, 1, 1, dtype=torch.long)
    loss = semantic_loss([p], labels)
    assert -math.log(1e-7) == pytest.approx(16.118, abs=1e-3)
    # Keras feeds log(clip(p)) to a softmax cross-entropy, which renormalises the clipped probabilities
    # (1 - 1e-7, 1e-7, 1e-7): + log(1 + 1e-7) on top of the cap.
    assert loss.item() == pytest.approx(-math.log(1e-7) + math.log(1 + 1e-7), abs=1e-12)
    loss.backward()
    assert float(p.grad[0, 1, 1]) == 0.0  # target probability below 1e-7: no gradient through it
    # Even more confident wrong predictions cannot exceed the cap.
    worse = torch.tensor([1.0, 1e-30, 0.0], dtype=torch.float64).reshape(1, 1, 3, 1, 1).repeat(1, 2, 1, 1, 1)
    assert float(semantic_loss([worse], labels)) == pytest.approx(loss.item(), abs=1e-12)
    # In float32 (the training dtype) the same cap holds.
    assert float(semantic_loss([p.detach().float()], labels)) == pytest.approx(16.118, abs=1e-3)


def test_semantic_loss_from_logits():
    logits = torch.tensor([0.0, math.log(3.0)]).reshape(1, 1, 2, 1, 1).repeat(1, 2, 1, 1, 1)
    labels = torch.ones(1, 2, 1, 1, dtype=torch.long)  # softmax = (0.25, 0.75)
    assert float(semantic_loss([logits], labels, from_logits=True)) == pytest.approx(-math.log(0.75), rel=1e-6)
    # Far beyond the probability clip the logits path keeps growing (no 16.118 cap) and keeps a gradient.
    far = torch.tensor([0.0, -40.0]).reshape(1, 1, 2, 1, 1).repeat(1, 2, 1, 1, 1).requires_grad_(True)
    loss = semantic_loss([far], labels, from_logits=True)
    assert loss.item() == pytest.approx(40.0, rel=1e-6)
    loss.backward()
    assert float(far.grad[0, 1, 1]) == pytest.approx(-1.0, rel=1e-6)


def test_semantic_loss_class_weights_hand_computed():
    # The hand-computed case above with class weights (2, 1, 0.5): pixels of frame 1 are classes 0, 2, 1, 1 with
    # target probabilities 0.5, 0.5, 0.8, 0.3.
    p = _probs([[0.5, 0.25, 0.25], [0.25, 0.25, 0.5], [0.1, 0.8, 0.1], [0.6, 0.3, 0.1]], 2, 2)
    labels = torch.tensor([[[0, 0], [0, 0]], [[0, 2], [1, 1]]])[None]
    loss = semantic_loss([_sem_seq(p)], labels, class_weights=[2.0, 1.0, 0.5])
    expected = -(2 * math.log(0.5) + 0.5 * math.log(0.5) + math.log(0.8) + math.log(0.3)) / (2 + 0.5 + 1 + 1)
    assert float(loss) == pytest.approx(expected, abs=1e-12)
    # The same as torch's weighted cross-entropy on the log-probabilities (its weighted mean), and equal weights
    # give the paper's plain mean.
    log_p = torch.log(p)[None]
    ref = torch.nn.functional.nll_loss(log_p, labels[:, 1], weight=torch.tensor([2.0, 1.0, 0.5], dtype=p.dtype))
    assert float(loss) == pytest.approx(float(ref), abs=1e-12)
    assert float(semantic_loss([_sem_seq(p)], labels, class_weights=[3.0] * 3)) == pytest.approx(
        float(semantic_loss([_sem_seq(p)], labels)), abs=1e-12
    )
    for bad in ([1.0, 1.0], [1.0, -1.0, 1.0], [1.0, math.nan, 1.0]):
        with pytest.raises(ValueError, match="class_weights"):
            semantic_loss([_sem_seq(p)], labels, class_weights=bad)


def test_median_frequency_weights_hand_computed():
    # Shares 1/8, 1/8, 1/4, 1/2: median 3/16.
    assert median_frequency_weights([1, 1, 2, 4], power=1.0) == pytest.approx([1.5, 1.5, 0.75, 0.375])
    assert median_frequency_weights([1, 1, 2, 4]) == pytest.approx([1.5**0.5, 1.5**0.5, 0.75**0.5, 0.375**0.5])
    # An absent class gets 1 and does not move the median (of 1/4, 3/4: 1/2).
    assert median_frequency_weights([1, 0, 3], power=1.0) == pytest.approx([2.0, 1.0, 2 / 3])
    assert median_frequency_weights([5, 5, 5], power=0.0) == [1.0, 1.0, 1.0]
    for bad in ([], [0, 0], [1, -1]):
        with pytest.raises(ValueError, match="counts"):
            median_frequency_weights(bad)


def test_semantic_loss_rejects_out_of_range_labels():
    p = torch.full((1, 2, 3, 2, 2), 1 / 3)
    labels = torch.zeros(1, 2, 2, 2, dtype=torch.long)
    labels[0, 1, 0, 0] = 3
    with pytest.raises(ValueError, match=r"\[0, 2\]"):
        semantic_loss([p], labels)
    with pytest.raises(ValueError, match="integer"):
        semantic_loss([p], labels.float())


def test_semantic_loss_accepts_channel_axis_labels():
    p = torch.full((1, 2, 3, 2, 2), 0.25)
    p[:, :, 0] = 0.5
    labels = torch.zeros(1, 2, 1, 2, 2, dtype=torch.uint8)
    assert float(semantic_loss([p], labels)) == pytest.approx(-math.log(0.5), rel=1e-6)


# --- total --------------------------------------------------------------------------------------------------------


def _sem_case():
    p = _probs([[0.5, 0.5], [0.5, 0.5], [0.5, 0.5], [0.5, 0.5]], 2, 2)
    labels = torch.zeros(1, 2, 2, 2, dtype=torch.long)
    return [_sem_seq(p, frame0=p)], labels  # semantic loss log 2


def test_total_loss_cosemdepth_m4depth_m4semantic():
    preds, gt = _two_level_case()
    sem, labels = _sem_case()

    joint = total_loss(preds, gt, sem, labels)
    assert isinstance(joint, LossTerms)
    assert float(joint.depth) == pytest.approx(FRAME_LOSS, abs=1e-12)
    assert float(joint.semantic) == pytest.approx(math.log(2), abs=1e-12)
    assert float(joint.total) == pytest.approx(FRAME_LOSS + 0.1 * math.log(2), abs=1e-12)
    assert joint.as_dict() == pytest.approx(
        {"total": FRAME_LOSS + 0.1 * math.log(2), "depth": FRAME_LOSS, "semantic": math.log(2)}
    )

    depth_only = total_loss(preds, gt)
    assert depth_only.semantic is None and float(depth_only.total) == pytest.approx(FRAME_LOSS, abs=1e-12)
    assert set(depth_only.as_dict()) == {"total", "depth"}

    sem_only = total_loss(pred_semantic=sem, gt_labels=labels)  # M4Semantic: 0.1 * L_sem
    assert sem_only.depth is None and float(sem_only.total) == pytest.approx(0.1 * math.log(2), abs=1e-12)

    weighted = total_loss(preds, gt, sem, labels, semantic_weight=1.0)
    assert float(weighted.total) == pytest.approx(FRAME_LOSS + math.log(2), abs=1e-12)


def test_total_loss_gradient_reaches_both_heads():
    preds, gt = _two_level_case()
    preds = [p.clone().nan_to_num(1.0).requires_grad_(True) for p in preds]
    sem, labels = _sem_case()
    sem = [s.clone().requires_grad_(True) for s in sem]
    total_loss(preds, gt, sem, labels).total.backward()
    assert all(torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0 for p in preds + sem)


def test_total_loss_needs_pairs():
    preds, gt = _two_level_case()
    with pytest.raises(ValueError, match="pred_depths and gt_depth"):
        total_loss(preds)
    with pytest.raises(ValueError, match="nothing to supervise"):
        total_loss()
