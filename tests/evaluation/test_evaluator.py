"""The evaluator against hand-computed values on a constructed case (fake model with known outputs, see _fakes.py)."""

import json
import math

import numpy as np
import pytest
import torch
from _fakes import FakeModel, fake_dataset

from cosemdepth.errors import ConfigError
from cosemdepth.evaluation.evaluator import Evaluator, evaluate, to_json

# Hand computation (reset frames A0 and B0 excluded; GT [[10, 20], [40, 0]], the 0 pixel invalid):
#   A1 pred [[10, 20], [40, 5]]: every valid error 0      -> AbsRel 0,   RMSE 0,                    d1 1
#   A2 pred [[20, 20], [20, 5]]: |err| 10, 0, 20          -> AbsRel (1 + 0 + 0.5)/3 = 0.5,
#                                                            RMSE sqrt((100 + 0 + 400)/3),       d1 1/3 (ratios 2,1,2)
#   B1 pred [[5, 40], [40, 7]]:  |err| 5, 20, 0           -> AbsRel (0.5 + 1 + 0)/3 = 0.5,
#                                                            RMSE sqrt((25 + 400 + 0)/3),        d1 1/3 (ratios 2,2,1)
# dataset values = unweighted means over the 3 frames.
ABS_REL = (0 + 0.5 + 0.5) / 3
RMSE = (0 + math.sqrt(500 / 3) + math.sqrt(425 / 3)) / 3
DELTA1 = (1 + 1 / 3 + 1 / 3) / 3
SQ_REL = (0 + (100 / 10 + 0 + 400 / 40) / 3 + (25 / 10 + 400 / 20 + 0) / 3) / 3
# Labels: GT [[0, 1], [2, 2]]; A1 [[0, 1], [2, 2]], A2 [[0, 0], [2, 1]], B1 [[1, 1], [2, 2]]
# confusion (rows GT): [[2, 1, 0], [1, 2, 0], [0, 1, 5]] -> IoU 2/4, 2/5, 5/6
CONFUSION = [[2, 1, 0], [1, 2, 0], [0, 1, 5]]
IOU = [0.5, 0.4, 5 / 6]


def test_metrics_match_hand_computed_values_and_resets_are_excluded():
    model = FakeModel()
    res = evaluate(model, fake_dataset())
    m = res.metrics
    assert m["abs_rel"] == pytest.approx(ABS_REL, rel=1e-5)
    assert m["rmse"] == pytest.approx(RMSE, rel=1e-9)
    assert m["delta1"] == pytest.approx(DELTA1, rel=1e-9)
    assert m["sq_rel"] == pytest.approx(SQ_REL, rel=1e-5)
    assert m["depth_frames"] == 3 and m["semantic_frames"] == 3
    assert res.confusion_matrix.tolist() == CONFUSION
    assert m["iou"] == pytest.approx(IOU)
    assert m["miou"] == pytest.approx(sum(IOU) / 3)
    # the model saw every frame once, in order, with the resets of the trajectories' first rows
    assert model.calls == [([0], [True]), ([1], [False]), ([2], [False]), ([10], [True]), ([11], [False])]
    proto = res.info["protocol"]
    assert proto["frames_streamed"] == 5 and proto["reset_frames"] == 2 and proto["frames_evaluated"] == 3
    assert res.params == 3


def test_rmse_log_quirk_and_fixed_variant():
    # only GT pixels > 1 m count in the original's RMSE_log; all GT here is >= 10 m so both agree; per frame:
    def rmse_log(pred):
        g = np.array([10.0, 20.0, 40.0])
        e = np.asarray(pred, dtype=float)
        return math.sqrt(np.mean((np.log(g + 1e-6) - np.log(e + 1e-6)) ** 2))

    expected = (rmse_log([10, 20, 40]) + rmse_log([20, 20, 20]) + rmse_log([5, 40, 40])) / 3
    m = evaluate(FakeModel(), fake_dataset()).metrics
    assert m["rmse_log"] == pytest.approx(expected, rel=1e-9)
    assert m["rmse_log_fixed"] == pytest.approx(expected, rel=1e-9)


def test_trajectories_side_by_side_give_the_same_metrics():
    model = FakeModel()
    one = evaluate(FakeModel(), fake_dataset()).metrics
    two = evaluate(model, fake_dataset(), lanes=2).metrics
    for k in ("abs_rel", "rmse", "delta1", "miou", "depth_frames"):
        assert two[k] == pytest.approx(one[k], rel=1e-12)
    # A and B ran as one batch with per-sample resets, then A alone (its state row kept, B's dropped)
    assert model.calls == [([0, 10], [True, True]), ([1, 11], [False, False]), ([2], [False])]


def test_a_lane_takes_the_next_trajectory_with_a_reset():
    model = FakeModel()
    trajs = {"A": [0, 1, 2], "B": [10, 11], "C": [20, 21]}
    import _fakes

    preds = dict(_fakes.PREDICTIONS)
    _fakes.PREDICTIONS.update({20: preds[10], 21: preds[11]})
    try:
        res = evaluate(model, fake_dataset(trajs), lanes=2)
    finally:
        _fakes.PREDICTIONS.clear()
        _fakes.PREDICTIONS.update(preds)
    assert model.calls == [
        ([0, 10], [True, True]),
        ([1, 11], [False, False]),
        ([2, 20], [False, True]),
        ([21], [False]),
    ]
    assert res.metrics["depth_frames"] == 4


def test_max_frames_keeps_the_first_rows():
    model = FakeModel()
    m = evaluate(model, fake_dataset(), max_frames=2).metrics
    assert [c for c, _ in model.calls] == [[0], [1]]
    assert m["depth_frames"] == 1 and m["abs_rel"] == pytest.approx(0.0, abs=1e-9)
    assert m["miou"] == pytest.approx(1.0)


def test_single_task_models_and_semantic_only_data():
    d = evaluate(FakeModel(arch="m4depth"), fake_dataset()).metrics
    assert "miou" not in d and d["rmse"] == pytest.approx(RMSE)
    s = evaluate(FakeModel(arch="m4semantic"), fake_dataset()).metrics
    assert "rmse" not in s and s["miou"] == pytest.approx(sum(IOU) / 3)
    # a dataset without depth (e.g. Aeroscapes): Co-SemDepth is evaluated on segmentation only
    c = evaluate(FakeModel(), fake_dataset(depth=False)).metrics
    assert "rmse" not in c and c["miou"] == pytest.approx(sum(IOU) / 3)


def test_every_frame_counts_when_every_frame_is_a_reset():
    # independent images (Aeroscapes): all 5 frames count, so the confusion matrix gets the reset predictions too
    res = evaluate(FakeModel(arch="m4semantic"), fake_dataset(all_reset=True, depth=False))
    assert res.info["protocol"]["frames_evaluated"] == 5 and not res.info["protocol"]["reset_frames_excluded"]
    extra = np.zeros((3, 3), dtype=int)
    for g, p in zip([0, 1, 2, 2], [1, 0, 0, 1]):  # GT vs RESET_LABELS, twice
        extra[g, p] += 2
    assert res.confusion_matrix.tolist() == (np.array(CONFUSION) + extra).tolist()


def test_trajectories_of_one_frame_give_labels_but_no_depth_metrics():
    # every trajectory one frame: each a reset, so every frame counts for the labels, but the depth of a reset frame
    # (the 1000 m placeholder) is no measurement: no depth metrics, as a longer flight cut to its first frame gives
    res = evaluate(FakeModel(), fake_dataset({"A": [0], "B": [10]}))
    m, proto = res.metrics, res.info["protocol"]
    assert not proto["reset_frames_excluded"] and proto["frames_evaluated"] == 2
    assert m["semantic_frames"] == 2 and m["depth_frames"] == 0 and proto["depth_frames_evaluated"] == 0
    assert all(math.isnan(m[k]) for k in ("abs_rel", "rmse", "delta1"))
    assert m["valid_frames"] == 0 and math.isnan(m["coverage"])
    cut = evaluate(FakeModel(), fake_dataset(), max_frames=1).metrics
    assert cut["depth_frames"] == 0 and math.isnan(cut["abs_rel"])
    assert res.depth_warning().startswith("no depth was produced: all 2 frames are resets")
    # the fake flight moves along the optical axis: every pixel of its 2x2 frames is at the focus of expansion
    full = evaluate(FakeModel(), fake_dataset())
    assert full.metrics["coverage"] == 0.0 and full.depth_warning().startswith("no valid depth: not one pixel of the 3")
    assert "the depth metrics only on frames with depth" in res.to_markdown()


def test_nothing_to_evaluate_and_class_mismatch_are_clear_errors():
    with pytest.raises(ConfigError, match="nothing to evaluate.*m4depth.*no depth"):
        evaluate(FakeModel(arch="m4depth"), fake_dataset(depth=False))
    with pytest.raises(ConfigError, match="3 classes but the midair labels have 7"):
        evaluate(FakeModel(), fake_dataset(), dataset_name="midair")
    with pytest.raises(ConfigError, match="max_frames"):
        evaluate(FakeModel(), fake_dataset(), max_frames=0)


def test_result_json_and_markdown():
    res = evaluate(FakeModel(), fake_dataset())
    d = json.loads(res.to_json())
    assert d["metrics"]["abs_rel"] == pytest.approx(ABS_REL, rel=1e-5)
    assert d["per_class_iou"] == {
        "class 0": pytest.approx(0.5),
        "class 1": pytest.approx(0.4),
        "class 2": pytest.approx(5 / 6),
    }
    assert d["confusion_matrix"] == CONFUSION
    assert d["params"] == 3 and d["speed"]["ms_per_frame"] >= 0
    md = res.to_markdown("fake")
    assert "| fake | 0.00 M |" in md and "| 57.78% |" in md  # mIoU (0.5 + 0.4 + 0.8333) / 3
    assert "| class 0 | 2 | 1 | 0 |" in md  # confusion-matrix row
    # NaN becomes null: strict JSON
    assert json.loads(to_json({"x": float("nan"), "y": [1.0, float("inf")]})) == {"x": None, "y": [1.0, None]}


def test_further_sinks_see_every_step_and_the_protocol_says_which_frames_count():
    class Seen:
        def __init__(self, include):
            self.include, self.seen, self.closed = include, [], False

        def open(self, folder):
            assert folder is None  # the evaluation writes no folder

        def __call__(self, batch):
            self.seen.append((batch.trajectory, self.include(batch).tolist()))

        def close(self):
            self.closed = True
            return {}

        def abort(self):
            raise AssertionError("nothing failed")

    ev = Evaluator(FakeModel(), fake_dataset())
    sink = Seen(ev.include)
    ev.sinks.append(sink)
    ev.run()
    assert sink.seen == [(["A"], [False]), (["A"], [True]), (["A"], [True]), (["B"], [False]), (["B"], [True])]
    assert sink.closed


def test_peak_memory_is_measured():
    res = evaluate(FakeModel(), fake_dataset())
    assert res.peak_memory_mb is not None and res.peak_memory_mb >= 0 and res.memory_method
    assert torch.isfinite(torch.tensor(res.ms_per_frame))
