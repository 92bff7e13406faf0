"""A fake model with known outputs and a tiny in-memory dataset, for checking the evaluation protocol by hand.

Every frame of the dataset carries a code in its RGB (``rgb = code / 100`` everywhere); the fake model looks the
code up and returns the depth map and labels the test chose for that frame. Its state carries the code of the last
frame per sample, so that it can check that each trajectory's state flows from its own previous frame.
"""

from __future__ import annotations

import numpy as np
import torch

from cosemdepth.data.sequence import SequenceDataset, Trajectory
from cosemdepth.models import StepOutput, StreamState
from cosemdepth.models.config import ModelConfig

GT_DEPTH = np.array([[10.0, 20.0], [40.0, 0.0]], dtype=np.float32)  # the 0 is an invalid pixel
GT_LABELS = np.array([[0, 1], [2, 2]], dtype=np.int64)
RESET_DEPTH = np.full((2, 2), 1000.0, dtype=np.float32)
RESET_LABELS = np.array([[1, 0], [0, 1]], dtype=np.int64)  # all wrong

#: code -> (predicted depth, predicted labels); codes 0-2 are trajectory A, 10-11 trajectory B.
PREDICTIONS = {
    0: (RESET_DEPTH, RESET_LABELS),
    1: (np.array([[10.0, 20.0], [40.0, 5.0]]), np.array([[0, 1], [2, 2]])),
    2: (np.array([[20.0, 20.0], [20.0, 5.0]]), np.array([[0, 0], [2, 1]])),
    10: (RESET_DEPTH, RESET_LABELS),
    11: (np.array([[5.0, 40.0], [40.0, 7.0]]), np.array([[1, 1], [2, 2]])),
}
TRAJECTORIES = {"A": [0, 1, 2], "B": [10, 11]}


class FakeModel(torch.nn.Module):
    """Returns ``PREDICTIONS[code]``; records the codes, resets and batch sizes it saw."""

    def __init__(self, arch: str = "cosemdepth", num_classes: int = 3) -> None:
        super().__init__()
        self.config = ModelConfig(arch=arch, num_classes=num_classes)
        self.dummy = torch.nn.Parameter(torch.zeros(3))
        self.calls: list[tuple[list[int], list[bool]]] = []

    def step(self, rgb, rot, trans, intrinsics, reset, state):
        codes = [int(round(float(v) * 100)) for v in rgb[:, 0, 0, 0]]
        self.calls.append((codes, [bool(r) for r in reset]))
        for i, (c, r) in enumerate(zip(codes, reset)):
            if not r:  # the state must hold this trajectory's previous frame
                assert state is not None and int(state.features[0][i, 0, 0, 0]) == c - 1, (codes, state)
        n = len(codes)
        depth = torch.stack([torch.from_numpy(np.asarray(PREDICTIONS[c][0], np.float32)) for c in codes])[:, None]
        labels = torch.stack([torch.from_numpy(np.asarray(PREDICTIONS[c][1], np.int64)) for c in codes])
        probs = torch.nn.functional.one_hot(labels, self.config.num_classes).permute(0, 3, 1, 2).float()
        code_t = torch.tensor(codes, dtype=torch.float32).view(n, 1, 1, 1)
        new_state = StreamState(feat=(code_t,), depth=(code_t.clone(),))
        heads = {"depth": depth, "semantic": probs}
        return StepOutput(heads={k: v for k, v in heads.items() if k in self.config.decoders}), new_state


def fake_dataset(
    trajectories: dict[str, list[int]] = TRAJECTORIES,
    *,
    depth: bool = True,
    labels: bool = True,
    all_reset: bool = False,
    name: str = "fake",
) -> SequenceDataset:
    """Frames of size 2x2 whose RGB encodes their code; GT depth/labels the same in every frame."""
    trajs = []
    for tname, codes in trajectories.items():
        n = len(codes)
        trajs.append(
            Trajectory(
                tname,
                [str(c) for c in codes],
                np.tile([1.0, 0, 0, 0], (n, 1)),
                np.tile([0, 0, 1.0], (n, 1)),
                np.arange(n),
                depth=[str(c) for c in codes] if depth else None,
                semantic=[str(c) for c in codes] if labels else None,
                reset=np.ones(n, dtype=bool) if all_reset else None,
            )
        )

    def load(rec):
        code = int(str(rec.rgb))
        out = {"rgb": torch.full((3, 2, 2), code / 100.0)}
        if rec.depth is not None:
            out["depth"] = torch.from_numpy(GT_DEPTH.copy())[None]
        if rec.semantic is not None:
            out["semantic"] = torch.from_numpy(GT_LABELS.copy())
        return out

    return SequenceDataset(trajs, load, torch.tensor([1.0, 1.0, 1.0, 1.0]), name=name)
