"""The dataset source: its lanes schedule, its rows, and the frames it yields."""

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
from _fakes import fake_dataset  # noqa: E402

from cosemdepth.errors import ConfigError  # noqa: E402
from cosemdepth.streaming import DatasetSource  # noqa: E402
from cosemdepth.streaming.sources.dataset import StepPlan, make_schedule, trajectory_rows  # noqa: E402


def test_one_lane_runs_trajectories_one_after_the_other():
    steps = make_schedule([[0, 1, 2], [3, 4]], lanes=1)
    assert steps == [
        StepPlan((0,), (0,), (True,)),
        StepPlan((1,), (0,), (False,)),
        StepPlan((2,), (0,), (False,)),
        StepPlan((3,), (0,), (True,)),
        StepPlan((4,), (0,), (False,)),
    ]


def test_lanes_refill_then_shrink():
    steps = make_schedule([[0, 1, 2], [3], [4, 5], [6]], lanes=2)
    assert [(s.indices, s.lanes, s.starts) for s in steps] == [
        ((0, 3), (0, 1), (True, True)),
        ((1, 4), (0, 1), (False, True)),  # lane 1 finished trajectory [3] and took [4, 5]
        ((2, 5), (0, 1), (False, False)),
        ((6,), (0,), (True,)),  # lane 0 took [6]; lane 1 had nothing left and was dropped
    ]
    # every index exactly once, each trajectory in order
    flat = [i for s in steps for i in s.indices]
    assert sorted(flat) == list(range(7))


def test_more_lanes_than_trajectories():
    steps = make_schedule([[0, 1], [2]], lanes=5)
    assert [(s.indices, s.lanes) for s in steps] == [((0, 2), (0, 1)), ((1,), (0,))]


def test_trajectory_rows_and_max_frames():
    ds = fake_dataset()
    assert trajectory_rows(ds) == [[0, 1, 2], [3, 4]]
    assert trajectory_rows(ds, max_frames=4) == [[0, 1, 2], [3]]


def test_bad_arguments():
    with pytest.raises(ConfigError, match="positive integer"):
        make_schedule([[0]], lanes=0)
    ds = fake_dataset()
    ds.seq_len = 2
    with pytest.raises(ConfigError, match="seq_len=1"):
        trajectory_rows(ds)
    with pytest.raises(ConfigError, match="sequence dataset"):
        trajectory_rows([1, 2, 3])


def test_the_frames_of_a_dataset_in_lanes():
    """Two lanes over trajectories A (codes 0-2) and B (10-11): each row's code, lane, reset and ground truth."""
    ds = fake_dataset()
    src = DatasetSource(ds)
    assert src.total_frames() == 5 and src.total_frames(max_frames=2) == 2
    batches = list(src.batches(lanes=2))
    codes = [[round(float(v) * 100) for v in b.rgb[:, 0, 0, 0]] for b in batches]
    assert codes == [[0, 10], [1, 11], [2]]
    assert [b.lanes for b in batches] == [(0, 1), (0, 1), (0,)]
    assert [b.index for b in batches] == [[0, 3], [1, 4], [2]]
    assert [b.reset.tolist() for b in batches] == [[True, True], [False, False], [False]]
    assert [b.trajectory for b in batches] == [["A", "B"], ["A", "B"], ["A"]]
    assert [b.frame.tolist() for b in batches] == [[0, 0], [1, 1], [2]]
    assert batches[0].name == ["0", "10"] and batches[0].stamp == [None, None] and batches[0].pose is None
    # every registered task's ground truth the frames have (a plugin's derived one too, when a test registered it)
    assert {"depth", "semantic"} <= set(batches[0].gt) and batches[0].gt["depth"].shape == (2, 1, 2, 2)
    assert torch.equal(batches[0].gt["semantic"][0], torch.tensor([[0, 1], [2, 2]]))
