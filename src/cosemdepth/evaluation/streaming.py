"""Stream a model over the trajectories of a dataset, frame by frame, with its explicit state (design 7.2, 11.3).

This is the loop shared by ``cosemdepth evaluate``, ``predict`` and ``demo``. The dataset must yield single frames in
stream mode (``open_dataset(..., seq_len=1)`` on a test split: every CSV row, in order, with ``reset`` on the rows that
start a trajectory).

With ``lanes = 1`` (the original's protocol) the trajectories are processed one after the other, batch 1. With
``lanes = B > 1`` up to B trajectories run side by side as one batch: each lane takes the next trajectory when its
own ends (with a per-sample reset), and when no trajectory is left a lane is dropped and its rows are removed from
the state. Every trajectory still sees exactly the same frames in the same order with the same resets, so the
outputs are those of batch 1 (up to floating-point summation order).
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from typing import Iterator, Sequence

import torch
from torch.utils.data import DataLoader

from ..data.loader import collate
from ..errors import ConfigError, NonFiniteOutputError
from ..inference.policy import EVERY_FRAME, Streamer
from ..tasks import TASKS
from ..workers import check_workers


@dataclass(frozen=True)
class StepPlan:
    """The inputs of one streaming step (one ``model.step`` call): dataset ``indices`` (one per lane), the ``lanes``
    they run in, and which start a trajectory in their lane (``starts``)."""

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


@dataclass
class StreamBatch:
    """The inputs, ground truth and predictions of one step (B frames, one per lane); tensors on the model's device.

    Attributes:
        indices: dataset index of each frame; trajectory: trajectory names; frame: row in the trajectory ``[B]``.
        reset: ``[B]`` bool, the frame starts a trajectory (the model reset its state); such frames are left out of
            the metrics of the test protocol (design 11.3).
        rgb: ``[B, 3, H, W]``; intrinsics ``[B, 4]``.
        gt_depth: ``[B, 1, H, W]`` metres or None; gt_labels: ``[B, H, W]`` int64 or None.
        depth: predicted ``[B, 1, H, W]`` metres or None; semantic: ``[B, N, H, W]`` probabilities or None;
            labels: ``[B, H, W]`` int64 argmax or None.
        seconds: wall time of the model step (synchronised on CUDA).
        valid: ``[B, 1, H, W]`` bool, the depth pixels that are estimates (None without depth); status: per frame
            ``"reset"``, ``"estimated"`` or ``"held"``; baseline: ``[B]`` metres from the frame the depth was
            estimated against (see :class:`~cosemdepth.models.outputs.StepOutput`).
        rot, trans: ``[B, 4]``, ``[B, 3]`` the input motion (previous -> current frame).
        heads: every decoder's output by head name (``StepOutput.heads``: ``depth``, ``semantic``, ...).
        gt: the ground truth by key, of every registered decoder task whose ground truth the frames have
            (:attr:`~cosemdepth.tasks.DecoderTask.gt_key`: ``depth``, ``semantic``, ...).
    """

    indices: list[int]
    trajectory: list[str]
    frame: torch.Tensor
    reset: torch.Tensor
    rgb: torch.Tensor
    intrinsics: torch.Tensor
    gt_depth: torch.Tensor | None
    gt_labels: torch.Tensor | None
    depth: torch.Tensor | None
    semantic: torch.Tensor | None
    labels: torch.Tensor | None
    seconds: float
    valid: torch.Tensor | None = None
    status: list[str] = field(default_factory=list)
    baseline: torch.Tensor | None = None
    rot: torch.Tensor | None = None
    trans: torch.Tensor | None = None
    heads: dict[str, torch.Tensor] = field(default_factory=dict)
    gt: dict[str, torch.Tensor] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.indices)


def _slice_state(state, rows: list[int]):
    if state is None:
        return state
    if hasattr(state, "select"):
        return state.select(rows)
    if not state.flatten():
        return state
    idx = torch.tensor(rows, device=state.flatten()[0].device)
    return type(state)(**{k: tuple(t.index_select(0, idx) for t in v) for k, v in state.components.items()})


def _model_device(model) -> torch.device:
    for p in model.parameters():
        return p.device
    return torch.device("cpu")


def _model_dtype(model) -> torch.dtype:
    for p in model.parameters():
        if p.is_floating_point():
            return p.dtype
    return torch.float32


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def frame_source(dataset, index: int) -> str | None:
    """The image file of dataset row ``index`` when the dataset knows it (Mid-Air-format readers, flights)."""
    windows = getattr(dataset, "windows", None)
    trajs = getattr(dataset, "trajectories", None)
    try:
        ti, row = windows[index]
        return str(trajs[ti].frame(row).rgb)
    except Exception:  # noqa: BLE001 - only used to name a frame in a message; any reader without it gives None
        return None


def check_finite_outputs(out, dataset, indices: list[int], trajectories: list[str], frames) -> None:
    """Raise :class:`NonFiniteOutputError` naming the first frame whose output (any decoder's head) holds NaN/inf."""
    for name, t in (getattr(out, "heads", None) or {}).items():
        if t is None:
            continue
        bad = ~torch.isfinite(t.reshape(t.shape[0], -1))
        rows = bad.any(dim=1).nonzero().flatten().tolist()
        if rows:
            b = rows[0]
            i = indices[b]
            src = frame_source(dataset, i)
            where = f"{src} (" if src else ""
            where += f"dataset row {i}, trajectory {trajectories[b]}, frame {int(frames[b])}" + (")" if src else "")
            raise NonFiniteOutputError(
                f"{where}: the model's {name} output holds NaN/inf ({int(bad[b].sum())} of {bad.shape[1]} values); "
                "the model weights or this input are broken; stopped, no output was written"
            )


class GroundTruthDepthGuide:
    """A model whose semantic decoder warps with the ground-truth depth (``semantic_time="gt"``), seen through
    ``step`` without that argument: :func:`stream` sets :attr:`depth` to each frame's ground truth before the step,
    so that a :class:`~cosemdepth.inference.Streamer` (whose ``step`` has no such input) can drive it."""

    def __init__(self, model) -> None:
        self.model = model
        self.depth: torch.Tensor | None = None

    def step(self, *args, **kwargs):
        return self.model.step(*args, guide_depth=self.depth, **kwargs)

    def __getattr__(self, name):  # parameters(), config, decoders...: the model's
        return getattr(self.model, name)


def needs_depth_input(model) -> bool:
    """Whether ``model`` (or the model a :class:`Streamer` drives) reads the ground-truth depth of every frame."""
    inner = model.model if isinstance(model, Streamer) else model
    cfg = getattr(inner, "config", None)
    return bool(getattr(cfg, "needs_depth_input", False))


def stream(
    model,
    dataset,
    *,
    lanes: int = 1,
    max_frames: int | None = None,
    num_workers: int = 0,
    schedule: Sequence[StepPlan] | None = None,
    policy=EVERY_FRAME,
) -> Iterator[StreamBatch]:
    """Run ``model.step`` over ``dataset`` (see the module docstring) and yield one :class:`StreamBatch` per step.

    Args:
        model: a :class:`~cosemdepth.models.SceneModel` (or anything with the same ``step`` and ``parameters``), or a
            :class:`~cosemdepth.inference.Streamer` (then ``policy`` is ignored).
        policy: the streaming policy (:class:`~cosemdepth.inference.StreamPolicy` or its mode name):
            ``"every-frame"`` (default: the paper's protocol) or ``"baseline"``.
        dataset: stream-mode, ``seq_len = 1`` dataset from :func:`cosemdepth.data.open_dataset`.
        lanes: trajectories streamed side by side (batch size); 1 as the original.
        max_frames: only the first ``max_frames`` rows of the dataset (in order).
        num_workers: DataLoader worker processes reading the frames (0: in this process).
        schedule: a precomputed :func:`make_schedule` result (default: computed from the dataset).
    """
    if schedule is None:
        schedule = make_schedule(trajectory_rows(dataset, max_frames), lanes)
    device = _model_device(model)
    dtype = _model_dtype(model)
    streamer = model if isinstance(model, Streamer) else Streamer(model, policy)
    guide = None
    if needs_depth_input(streamer):
        guide = GroundTruthDepthGuide(streamer.model)
        streamer = Streamer(guide, streamer.policy, min_baseline=streamer.min_baseline)
    loader = DataLoader(
        dataset,
        batch_sampler=[list(s.indices) for s in schedule],
        collate_fn=collate,
        num_workers=check_workers(num_workers, "num_workers"),
    )
    state = None
    prev_lanes: tuple[int, ...] = ()
    with torch.inference_mode():
        for step, batch in zip(schedule, loader):
            if prev_lanes and step.lanes != prev_lanes:
                pos = {lane: i for i, lane in enumerate(prev_lanes)}
                state = _slice_state(state, [pos[lane] for lane in step.lanes])
            prev_lanes = step.lanes
            rgb = batch["rgb"][:, 0].to(device=device, dtype=dtype)
            rot = batch["rot"][:, 0].to(device=device, dtype=dtype)
            trans = batch["trans"][:, 0].to(device=device, dtype=dtype)
            intr = batch["intrinsics"].to(device=device, dtype=dtype)
            reset = batch["reset"][:, 0] | torch.tensor(step.starts, dtype=torch.bool)
            reset_dev = reset.to(device)
            if guide is not None:
                if batch.get("depth") is None:
                    raise ConfigError(
                        "the model's semantic decoder warps the previous labels with the ground-truth "
                        "depth (semantic_time 'gt'), and this dataset has no depth"
                    )
                guide.depth = batch["depth"][:, 0].to(device=device, dtype=dtype)
            _sync(device)
            t0 = time.perf_counter()
            source_valid = batch.get("source_valid")
            if source_valid is not None:
                source_valid = source_valid[:, 0].to(device)
            out, state = streamer.step(rgb, rot, trans, intr, reset_dev, state, source_valid=source_valid)
            _sync(device)
            seconds = time.perf_counter() - t0
            check_finite_outputs(out, dataset, list(step.indices), list(batch["trajectory"]), batch["frame"][:, 0])
            gt = {}
            for t in TASKS.values():
                g = t.ground_truth(batch)
                if g is not None:
                    gt[t.gt_key] = g[:, 0].to(device)
            yield StreamBatch(
                indices=list(step.indices),
                trajectory=list(batch["trajectory"]),
                frame=batch["frame"][:, 0],
                reset=reset,
                rgb=rgb,
                intrinsics=intr,
                gt_depth=gt.get("depth"),
                gt_labels=gt.get("semantic"),
                depth=out.depth,
                semantic=out.semantic,
                labels=None if out.semantic is None else out.semantic.argmax(dim=1),
                seconds=seconds,
                valid=out.valid,
                status=list(out.status),
                baseline=out.baseline,
                rot=rot,
                trans=trans,
                heads=dict(out.heads),
                gt=gt,
            )


__all__ = [
    "GroundTruthDepthGuide",
    "StepPlan",
    "StreamBatch",
    "check_finite_outputs",
    "frame_source",
    "make_schedule",
    "needs_depth_input",
    "stream",
    "trajectory_rows",
]
