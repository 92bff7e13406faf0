"""The labels' temporal consistency (flicker, change recall), by hand on tiny frames (in evaluate's JSON:
tests/evaluation/test_temporal_report.py)."""

import math

import torch

from cosemdepth.measures.temporal import PairCounts, TemporalConsistency, pair_counts, warp_previous_labels

IDENTITY = torch.tensor([[1.0, 0.0, 0.0, 0.0]])


def test_a_sideways_step_of_one_pixel_reads_the_right_neighbour():
    # f = 2, t_x = 1 m, depth 2 m: every point was one pixel to the right in the previous frame
    prev = torch.tensor([[[0, 1, 2, 3], [4, 5, 6, 7]]])
    depth = torch.full((1, 1, 2, 4), 2.0)
    K = torch.tensor([[2.0, 2.0, 2.0, 1.0]])
    warped, valid = warp_previous_labels(prev, depth, IDENTITY, torch.tensor([[1.0, 0.0, 0.0]]), K)
    assert valid.tolist() == [[[True, True, True, False], [True, True, True, False]]]
    assert warped.tolist() == [[[1, 2, 3, 0], [5, 6, 7, 0]]]


def test_no_motion_keeps_every_label_and_no_depth_keeps_none():
    prev = torch.tensor([[[3, 1], [2, 0]]])
    K = torch.tensor([[1.0, 1.0, 1.0, 1.0]])
    warped, valid = warp_previous_labels(prev, torch.full((1, 1, 2, 2), 7.0), IDENTITY, torch.zeros(1, 3), K)
    assert torch.equal(warped, prev) and bool(valid.all())
    _, valid = warp_previous_labels(
        prev, torch.tensor([[[[0.0, math.nan], [-1.0, 0.0]]]]), IDENTITY, torch.zeros(1, 3), K
    )
    assert not bool(valid.any())


def test_pair_counts_by_hand():
    gt_prev = torch.tensor([[[0, 0, 1, 1]]])
    gt = torch.tensor([[[0, 0, 1, 2]]])  # the last pixel really changes
    pred_prev = torch.tensor([[[0, 1, 1, 1]]])
    pred = torch.tensor([[[0, 0, 2, 2]]])  # pixel 1 and 2 flicker, pixel 3 follows the change
    valid = torch.tensor([[[True, True, True, True]]])
    assert pair_counts(pred, pred_prev, gt, gt_prev, valid) == [PairCounts(stable=3, flicker=2, changed=1, followed=1)]
    valid = torch.tensor([[[True, False, True, False]]])
    assert pair_counts(pred, pred_prev, gt, gt_prev, valid) == [PairCounts(stable=2, flicker=1, changed=0, followed=0)]


def test_pairs_follow_each_trajectory_and_break_at_resets():
    acc = TemporalConsistency()
    K = torch.tensor([[1.0, 1.0, 0.5, 0.5]]).expand(2, 4)
    depth = torch.full((2, 1, 1, 1), 5.0)
    motion = (IDENTITY.expand(2, 4), torch.zeros(2, 3))
    gt = torch.zeros(2, 1, 1, dtype=torch.long)
    lab = lambda *v: torch.tensor(v).view(-1, 1, 1)  # noqa: E731

    acc.update(["A", "B"], torch.tensor([True, True]), gt, lab(0, 0), depth, *motion, K)  # first frames: no pair
    acc.update(["A", "B"], torch.tensor([False, False]), gt, lab(1, 0), depth, *motion, K)  # A flickers, B not
    acc.update(["A", "C"], torch.tensor([False, True]), gt[:2], lab(1, 5), depth, *motion, K)  # B ended, C starts
    acc.update(["A", "C"], torch.tensor([True, False]), gt[:2], lab(2, 5), depth, *motion, K)  # A restarts: no pair
    assert [(p.stable, p.flicker) for p in acc.pairs] == [(1, 1), (1, 0), (1, 0), (1, 0)]
    m = acc.compute()
    assert m["flicker"] == 0.25 and m["flicker_pairs"] == 4 and m["flicker_max"] == 1.0 and m["flicker_median"] == 0.0
    assert math.isnan(m["change_recall"]) and m["gt_change"] == 0.0
