"""What travels through the streaming pipeline: a source's :class:`FrameBatch`, the sinks' :class:`StreamBatch`, and
the two protocols, :class:`Source` and :class:`Sink` (:mod:`cosemdepth.streaming.pipeline` runs them).

Conventions of every batch (B frames, one per lane):

* motion from the lane's previous frame, camera axes (x right, y down, z forward): ``X_prev = R X_curr + t``, ``rot``
  ``(w, x, y, z)``, identity and zero on reset frames;
* intrinsics ``(fx, fy, cx, cy)`` at the input size, the package's pixel convention (pixel centres at +0.5);
* a reset starts the lane's state afresh (the first frame, a new trajectory, a break in the motion).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Optional, Protocol, runtime_checkable

import torch

Tensor = torch.Tensor


@dataclass
class FrameBatch:
    """The frames a source yields for one streaming step.

    Attributes:
        rgb: ``[B, 3, H, W]`` float32 in [0, 1] at the model's input size.
        rot, trans: ``[B, 4]``, ``[B, 3]`` the motion from the lane's previous frame (see the module docstring).
        intrinsics: ``[B, 4]`` at the input size.
        reset: ``[B]`` bool, the lane's state starts afresh.
        trajectory: ``[B]`` trajectory names (predict's output folders).
        frame: ``[B]`` int64 row of the frame in its trajectory (0-based, after frame skipping).
        index: ``[B]`` the source's frame index (unique in a run; the decoding order for a video).
        lanes: the lane each row runs in (the pipeline reorders and slices the state when the lanes change).
        gt: the ground truth by task ``gt_key`` (``"depth"`` ``[B, 1, H, W]``, ``"semantic"`` ``[B, H, W]``...).
        name: ``[B]`` the frame's source name (an image path, ``"bag:topic@stamp"``...); the file stem of predict's
            outputs comes from it (None: the row number).
        stamp: ``[B]`` seconds on the source's clock, None where unknown.
        meta: ``[B]`` per-frame entries for the sinks (predict's frame record copies them).
        pose: ``[B, 4, 4]`` camera-to-world (camera optical axes) when the source knows it, else None.
        depth_ok: ``[B]`` bool, False where the source cannot give a motion usable for depth (None: all True).
        source_valid: ``[B, 1, H, W]`` bool, the pixels of an undistorted image that have a source pixel (a
            calibrated lens, :class:`cosemdepth.camera.Undistorter`); no depth is valid elsewhere (None: all).
    """

    rgb: Tensor
    rot: Tensor
    trans: Tensor
    intrinsics: Tensor
    reset: Tensor
    trajectory: list[str]
    frame: Tensor
    index: list[int]
    lanes: tuple[int, ...]
    gt: dict[str, Tensor] = field(default_factory=dict)
    name: list[Optional[str]] = field(default_factory=list)
    stamp: list[Optional[float]] = field(default_factory=list)
    meta: list[dict] = field(default_factory=list)
    pose: Optional[Tensor] = None
    depth_ok: Optional[Tensor] = None
    source_valid: Optional[Tensor] = None

    def __post_init__(self) -> None:
        n = len(self.index)
        for attr, fill in (("name", None), ("stamp", None)):
            if not getattr(self, attr):
                setattr(self, attr, [fill] * n)
        if not self.meta:
            self.meta = [{} for _ in range(n)]

    def __len__(self) -> int:
        return len(self.index)


@dataclass
class StreamBatch(FrameBatch):
    """A :class:`FrameBatch` with the model's outputs, what the sinks get. The frame tensors and the ground truth are
    on the model's device (as the model saw them).

    Attributes:
        heads: every decoder's output at the input size by head name (``"depth"`` ``[B, 1, H, W]`` metres,
            ``"semantic"`` ``[B, N, H, W]`` probabilities, further decoders' heads).
        valid: ``[B, 1, H, W]`` bool, the depth pixels that are estimates (None without depth).
        status: per frame ``"reset"``, ``"estimated"`` or ``"held"`` (empty without depth).
        baseline: ``[B]`` metres from the frame the depth was estimated against (None without depth).
        seconds: wall time of the streaming step (synchronised on CUDA).
    """

    heads: dict[str, Tensor] = field(default_factory=dict)
    valid: Optional[Tensor] = None
    status: list[str] = field(default_factory=list)
    baseline: Optional[Tensor] = None
    seconds: float = 0.0

    @property
    def depth(self) -> Optional[Tensor]:
        """``[B, 1, H, W]`` predicted metres, None without a depth decoder."""
        return self.heads.get("depth")

    @property
    def semantic(self) -> Optional[Tensor]:
        """``[B, N, H, W]`` class probabilities, None without a semantic decoder."""
        return self.heads.get("semantic")

    @functools.cached_property
    def labels(self) -> Optional[Tensor]:
        """``[B, H, W]`` int64, the argmax over the class axis of :attr:`semantic` (``max(dim=1).indices``: the
        first maximum's index, as ``argmax``, whose CPU kernel is several times slower over this strided axis)."""
        return None if self.semantic is None else self.semantic.max(dim=1).indices

    @property
    def gt_depth(self) -> Optional[Tensor]:
        """``[B, 1, H, W]`` ground-truth metres, or None."""
        return self.gt.get("depth")

    @property
    def gt_labels(self) -> Optional[Tensor]:
        """``[B, H, W]`` ground-truth class indices, or None."""
        return self.gt.get("semantic")

    @property
    def indices(self) -> list[int]:
        """:attr:`index` (the source's frame index of each row)."""
        return self.index


@runtime_checkable
class Source(Protocol):
    """Yields :class:`FrameBatch` objects (the registry builds one from its options: ``SOURCES[name]``).

    Optional attributes a source may have: ``total_frames() -> int | None`` (progress bars), ``min_baseline_m`` (a
    floor for the policy's baseline: no frame with a shorter baseline from its reference has valid depth), ``intrinsics`` (camera_info), ``class_names`` / ``palette`` hints."""

    name: str

    def describe(self) -> dict:
        """``predictions.json`` entries about the input (root, split, pose matching, ...)."""
        ...

    def frame_size(self) -> tuple[int, int] | None:
        """``(H, W)`` fed to the model, None until known."""
        ...

    def batches(self, *, lanes: int = 1, max_frames: int | None = None, num_workers: int = 0) -> Iterator[FrameBatch]:
        """The frames, ``lanes`` trajectories side by side, at most ``max_frames`` in all."""
        ...

    def close(self) -> None:
        """Release files, sockets, readers."""
        ...


@runtime_checkable
class Sink(Protocol):
    """Consumes :class:`StreamBatch` objects."""

    def open(self, folder: Path | None) -> None:
        """Start; ``folder`` is the run's staged output folder (None: the run writes none)."""
        ...

    def __call__(self, batch: StreamBatch) -> None:
        """One streaming step's frames and outputs."""
        ...

    def close(self) -> dict:
        """Finish; entries merged into the run's manifest / summary."""
        ...

    def abort(self) -> None:
        """The run failed: leave nothing half-written."""
        ...


def with_outputs(frames: FrameBatch, **outputs: Any) -> StreamBatch:
    """The :class:`StreamBatch` of ``frames`` (its fields as they are) with ``outputs`` (``heads``, ``valid``,
    ``status``, ``baseline``, ``seconds``)."""
    fields = {k: getattr(frames, k) for k in FrameBatch.__dataclass_fields__}
    return StreamBatch(**fields, **outputs)


__all__ = ["FrameBatch", "Sink", "Source", "StreamBatch", "with_outputs"]
