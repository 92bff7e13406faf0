"""A stream-mode :class:`~cosemdepth.data.sequence.SequenceDataset` as a source: a dataset split, a folder of images
with a pose file (:mod:`cosemdepth.data.flight`), a ROS bag (:mod:`cosemdepth.robotics.bag_flight`).

The dataset must yield single frames in stream mode (``open_dataset(..., seq_len=1)``: every row, in order, with
``reset`` on the rows that start a trajectory).

With ``lanes = 1`` (the original's protocol) the trajectories are streamed one after the other, batch 1. With
``lanes = B > 1`` up to B trajectories run side by side as one batch: each lane takes the next trajectory when its own
ends (with a per-sample reset), and when no trajectory is left a lane is dropped (the pipeline removes its rows from
the state). Every trajectory still sees exactly the same frames in the same order with the same resets, so the
outputs are those of batch 1 (up to floating-point summation order).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Optional, Sequence

import torch
from torch.utils.data import DataLoader

from ...data import open_dataset
from ...data.decode import DEFAULT_JPEG_IDCT, check_jpeg_idct, image_size
from ...data.frames import as_size
from ...data.loader import collate
from ...data.registry import DATASETS
from ...errors import ConfigError
from ...output_safety.outdir import Input
from ...tasks import TASKS
from ...workers import check_workers
from ..frames import FrameBatch
from ..registry import register_source


@dataclass(frozen=True)
class StepPlan:
    """The inputs of one streaming step: dataset ``indices`` (one per lane), the ``lanes`` they run in, and which
    start a trajectory in their lane (``starts``)."""

    indices: tuple[int, ...]
    lanes: tuple[int, ...]
    starts: tuple[bool, ...]


def trajectory_rows(dataset, max_frames: int | None = None) -> list[list[int]]:
    """Dataset indices grouped by trajectory, in dataset order; only indices ``< max_frames`` when given.

    The dataset must be a stream-mode :class:`~cosemdepth.data.sequence.SequenceDataset` with ``seq_len = 1``.
    """
    seq_len = getattr(dataset, "seq_len", None)
    windows = getattr(dataset, "windows", None)
    if windows is None or seq_len is None:
        raise ConfigError(f"streaming needs a sequence dataset from open_dataset(), got {type(dataset).__name__}")
    if seq_len != 1 or getattr(dataset, "mode", "stream") != "stream":
        raise ConfigError(
            f"streaming evaluation needs single frames in stream mode (open_dataset(..., seq_len=1) on a test "
            f"split), got seq_len={seq_len}, mode={getattr(dataset, 'mode', None)!r}"
        )
    if max_frames is not None and (not isinstance(max_frames, int) or max_frames < 1):
        raise ConfigError(f"max_frames must be a positive integer, got {max_frames!r}")
    n = len(windows) if max_frames is None else min(len(windows), max_frames)
    groups: list[list[int]] = []
    last = None
    for i in range(n):
        ti = windows[i][0]
        if ti != last:
            groups.append([])
            last = ti
        groups[-1].append(i)
    return groups


def make_schedule(groups: Sequence[Sequence[int]], lanes: int = 1) -> list[StepPlan]:
    """Schedule trajectories (lists of dataset indices) on ``lanes`` parallel lanes; see the module docstring."""
    if not isinstance(lanes, int) or lanes < 1:
        raise ConfigError(f"the number of trajectories streamed at once must be a positive integer, got {lanes!r}")
    queue = deque(list(g) for g in groups if len(g))
    active: dict[int, deque] = {}
    for lane in range(lanes):
        if queue:
            active[lane] = deque(queue.popleft())
    fresh = set(active)
    steps: list[StepPlan] = []
    while active:
        order = sorted(active)
        steps.append(
            StepPlan(tuple(active[k].popleft() for k in order), tuple(order), tuple(k in fresh for k in order))
        )
        fresh = set()
        for k in order:
            if not active[k]:
                if queue:
                    active[k] = deque(queue.popleft())
                    fresh.add(k)
                else:
                    del active[k]
    return steps


def frame_source(dataset, index: int) -> str | None:
    """The image file (or a bag frame's ``bag:topic@stamp``) of dataset row ``index`` when the dataset knows it."""
    windows = getattr(dataset, "windows", None)
    trajs = getattr(dataset, "trajectories", None)
    try:
        ti, row = windows[index]
        return str(trajs[ti].frame(row).rgb)
    except Exception:  # noqa: BLE001 - only used to name a frame; any reader without it gives None
        return None


def dataset_frame_size(dataset) -> tuple[int, int] | None:
    """``(H, W)`` of the frames ``dataset`` feeds the model: its loader's output size, else (native size) the first
    image's, from its header; None if neither is known."""
    size = as_size(getattr(getattr(dataset, "load_frame", None), "size", None))
    trajs = getattr(dataset, "trajectories", None)
    if size is None and trajs and len(trajs[0]):
        rgb = getattr(trajs[0].frame(0), "rgb", None)
        if isinstance(rgb, (str, Path)):
            size = image_size(rgb)
    return size


@dataclass(frozen=True)
class DatasetOptions:
    """A dataset split as the input (``--dataset NAME --root ROOT [--split-dir D] [--split S]``).

    Attributes:
        dataset: a registered dataset with split files; root: its root folder.
        split_dir: the folder of its split files (default: the dataset table's); split: default the table's.
        jpeg_idct: JPEG decoding (:mod:`cosemdepth.data.decode`).
        calibration: the lens of the split's images (a calibration file, for the readers that take one: Mid-Air,
            SynthAir); frames and ground truth undistorted to a pinhole.
    """

    dataset: Optional[str]
    root: Optional[Path]
    split_dir: Optional[Path] = None
    split: Optional[str] = None
    jpeg_idct: str = DEFAULT_JPEG_IDCT
    calibration: Optional[Path] = None

    #: the source table's name of this input
    source = "dataset"

    def __post_init__(self) -> None:
        if not self.dataset or self.root is None:
            raise ConfigError(
                "give --dataset NAME --root ROOT (a dataset split), or --flight --images DIR --poses FILE"
            )
        check_jpeg_idct(self.jpeg_idct)

    def inputs(self) -> list[Input]:
        """The paths it reads (the output policy of :mod:`cosemdepth.output_safety.outdir`)."""
        given = (("--root", self.root), ("--split-dir", self.split_dir), ("--calibration", self.calibration))
        return [Input(label, p) for label, p in given if p is not None]

    def check_split_dir(self) -> None:
        """A ConfigError naming ``--split-dir`` (and how to make one) when the dataset has no default split folder
        and none is given."""
        spec = DATASETS.get(self.dataset)
        if self.split_dir is None and spec is not None and spec.needs_split_dir and spec.split_dir is None:
            raise ConfigError(
                f"--dataset {self.dataset} needs --split-dir D, the folder of its split files "
                f"(<split>_data/**/*.csv); write them with: cosemdepth splits {self.dataset} ROOT D"
            )


class DatasetSource:
    """The frames of a stream-mode ``dataset`` (see the module docstring).

    Args:
        dataset: a stream-mode, ``seq_len = 1`` :class:`~cosemdepth.data.sequence.SequenceDataset`.
        info: :meth:`describe`'s entries (default: the dataset's name and root).
    """

    name = "dataset"

    def __init__(self, dataset, *, info: dict[str, Any] | None = None) -> None:
        self.dataset = dataset
        self.info = dict(info) if info is not None else {"name": getattr(dataset, "name", "") or ""}

    @classmethod
    def from_options(cls, options: DatasetOptions, size=None) -> "DatasetSource":
        """The split of ``options`` at ``size`` (an int, ``(H, W)``, a :class:`~cosemdepth.data.frames.FocalSize`
        or None: the dataset table's size), streamed frame by frame."""
        options.check_split_dir()
        dataset = open_dataset(
            options.dataset,
            options.root,
            split_dir=options.split_dir,
            split=options.split,
            seq_len=1,
            size=size,
            jpeg_idct=options.jpeg_idct,
            **({} if options.calibration is None else {"calibration": options.calibration}),
        )
        return cls(dataset, info={"root": str(options.root), "split": options.split})

    def report(self) -> str:
        """What the summary line of a run says about the input beyond its frames (``""``: nothing)."""
        return ""

    # ------------------------------------------------------------------ what it is
    def describe(self) -> dict[str, Any]:
        """The input: ``info``, and how its images were undistorted (``undistortion``) when they were."""
        undistortion = getattr(self.dataset, "calibration", None)
        return {**self.info, **({"undistortion": undistortion} if undistortion else {})}

    def calibration_note(self) -> str | None:
        """What the undistortion says about the calibration it was given (e.g. scaled to the images' size)."""
        return ((getattr(self.dataset, "calibration", None) or {}).get("calibration") or {}).get("note")

    def frame_size(self) -> tuple[int, int] | None:
        return dataset_frame_size(self.dataset)

    @property
    def intrinsics(self) -> torch.Tensor | None:
        """``[4]`` (fx, fy, cx, cy) at the input size."""
        return getattr(self.dataset, "intrinsics", None)

    @property
    def trajectories(self) -> int:
        """How many trajectories it holds."""
        return len(getattr(self.dataset, "trajectories", None) or ())

    def schedule(self, lanes: int = 1, max_frames: int | None = None) -> list[StepPlan]:
        """The streaming steps of :meth:`batches` (see :func:`make_schedule`)."""
        return make_schedule(trajectory_rows(self.dataset, max_frames), lanes)

    def total_frames(self, max_frames: int | None = None) -> int:
        """Frames :meth:`batches` yields with ``max_frames``."""
        return sum(len(g) for g in trajectory_rows(self.dataset, max_frames))

    # ------------------------------------------------------------------ per-frame extras (subclasses)
    def pose(self, trajectory: int, row: int) -> torch.Tensor | None:
        """``[4, 4]`` camera-to-world of a row, None when unknown (for every row of the source)."""
        return None

    def meta(self, trajectory: int, row: int) -> dict[str, Any]:
        """Per-frame entries for the sinks."""
        return {}

    # ------------------------------------------------------------------ frames
    def batches(
        self,
        *,
        lanes: int = 1,
        max_frames: int | None = None,
        num_workers: int = 0,
        schedule: Sequence[StepPlan] | None = None,
    ) -> Iterator[FrameBatch]:
        """One :class:`~cosemdepth.streaming.frames.FrameBatch` per step of ``schedule`` (default:
        :meth:`schedule`), read by a DataLoader with ``num_workers`` worker processes."""
        if schedule is None:
            schedule = self.schedule(lanes, max_frames)
        ds = self.dataset
        loader = DataLoader(
            ds,
            batch_sampler=[list(s.indices) for s in schedule],
            collate_fn=collate,
            num_workers=check_workers(num_workers, "num_workers"),
        )
        stamps_of = [getattr(t, "timestamps", None) for t in ds.trajectories]
        for step, batch in zip(schedule, loader):
            rows = [ds.windows[i] for i in step.indices]
            gt = {}
            for t in TASKS.values():
                g = t.ground_truth(batch)
                if g is not None:
                    gt[t.gt_key] = g[:, 0]
            poses = [self.pose(ti, row) for ti, row in rows]
            yield FrameBatch(
                rgb=batch["rgb"][:, 0],
                rot=batch["rot"][:, 0],
                trans=batch["trans"][:, 0],
                intrinsics=batch["intrinsics"],
                reset=batch["reset"][:, 0] | torch.tensor(step.starts, dtype=torch.bool),
                trajectory=list(batch["trajectory"]),
                frame=batch["frame"][:, 0],
                index=list(step.indices),
                lanes=tuple(step.lanes),
                gt=gt,
                name=[frame_source(ds, i) for i in step.indices],
                stamp=[None if stamps_of[ti] is None else float(stamps_of[ti][row]) for ti, row in rows],
                meta=[self.meta(ti, row) for ti, row in rows],
                pose=None if any(p is None for p in poses) else torch.stack(poses),
                source_valid=None if batch.get("source_valid") is None else batch["source_valid"][:, 0],
            )

    def close(self) -> None:
        close = getattr(getattr(self.dataset, "load_frame", None), "close", None)
        if callable(close):
            close()


__all__ = [
    "DatasetOptions",
    "DatasetSource",
    "StepPlan",
    "dataset_frame_size",
    "frame_source",
    "make_schedule",
    "trajectory_rows",
]


register_source("dataset", DatasetSource)
