"""The labels' temporal consistency (:mod:`cosemdepth.measures.temporal`) in evaluate's metrics, JSON and report."""

import json

from _fakes import FakeModel, fake_dataset

from cosemdepth.evaluation.evaluator import evaluate


def test_evaluate_reports_flicker_in_its_json():
    # the fake frames are 2x2, f = c = 1, 1 m forward, ground-truth depth [[10, 20], [40, 0]] (the 0 has no point):
    # every point stays on its pixel, the ground truth never changes; predicted labels (tests/evaluation/_fakes.py):
    # A: frame 0 -> 1 changes 3 of 3 pixels, 1 -> 2 changes 1 of 3; B: 10 -> 11 changes 2 of 3
    for lanes in (1, 2):
        res = evaluate(FakeModel(), fake_dataset(), lanes=lanes, warmup=0)
        m = res.metrics
        assert m["flicker_pairs"] == 3 and m["flicker"] == 6 / 9, lanes
        assert m["flicker_median"] == 2 / 3 and m["flicker_max"] == 1.0 and m["gt_change"] == 0.0
        data = json.loads(res.to_json())
        assert data["metrics"]["flicker"] == 6 / 9 and data["metrics"]["change_recall"] is None
        assert "flicker 66.7 %" in res.to_markdown()


def test_no_flicker_without_depth_ground_truth():
    m = evaluate(FakeModel(), fake_dataset(depth=False), warmup=0).metrics
    assert "flicker" not in m and "miou" in m
