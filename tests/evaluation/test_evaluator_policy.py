"""``evaluate`` under a streaming policy: the paper's metrics count the frames with depth, the valid-pixel metrics and
the coverage count the mask, and a frame without depth (held before the first estimate) is left out of the depth
metrics but not of the label metrics. A stand-in model returns 20 m everywhere (the ground truth: 10 m)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "jobs"))  # the predict tests' plane scene
from test_predict_validity import H, K, Plane, W

from cosemdepth.data.sequence import SequenceDataset, Trajectory
from cosemdepth.evaluation.evaluator import evaluate


def dataset(motion):
    n = len(motion)
    traj = Trajectory(
        "t",
        [str(k) for k in range(n)],
        np.tile([1.0, 0, 0, 0], (n, 1)),
        np.array(motion),
        np.arange(n),
        depth=[str(k) for k in range(n)],
        semantic=[str(k) for k in range(n)],
    )

    def load(rec):
        return {
            "rgb": torch.full((3, H, W), 0.5),
            "depth": torch.full((1, H, W), 10.0),
            "semantic": torch.zeros(H, W, dtype=torch.long),
        }

    return SequenceDataset([traj], load, torch.tensor(K), name="t")


def test_a_frame_without_depth_counts_for_the_labels_only():
    # sideways 0.4 m (too little: no depth yet), then 1.2 m more: estimated against the first frame (1.6 m)
    ds = dataset([(0, 0, 0), (0.4, 0, 0), (1.2, 0, 0), (0, 0, 0)])
    r = evaluate(Plane(), ds, policy="baseline", min_baseline=1.0)
    proto = r.info["protocol"]
    assert proto["frames_by_status"] == {"reset": 1, "estimated": 1, "held": 1}  # frame 0 (the reset) excluded
    assert proto["depth_frames_evaluated"] == 2 and r.metrics["semantic_frames"] == 3
    # 20 m against 10 m: AbsRel 1 on every counted pixel; all of them valid (sideways motion, no reset among them)
    assert r.metrics["abs_rel"] == pytest.approx(1.0) and r.metrics["valid_abs_rel"] == pytest.approx(1.0)
    assert r.metrics["coverage"] == pytest.approx(1.0) and r.metrics["valid_frames"] == 2
    assert proto["policy"]["mode"] == "baseline" and proto["policy"]["min_baseline_m"] == 1.0


def test_every_frame_counts_every_frame_after_the_reset():
    ds = dataset([(0, 0, 0), (2, 0, 0), (2, 0, 0), (0, 0, 0)])
    r = evaluate(Plane(), ds)
    proto = r.info["protocol"]
    assert proto["policy"]["mode"] == "every-frame" and proto["frames_by_status"]["estimated"] == 3
    assert proto["depth_frames_evaluated"] == 3
    # the hover frame (no translation) has no valid pixel: coverage 2 frames of 3
    assert r.metrics["coverage"] == pytest.approx(2 / 3) and r.metrics["valid_frames"] == 2
