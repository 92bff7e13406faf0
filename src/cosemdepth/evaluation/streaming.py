"""Stream a model over the trajectories of a dataset: :func:`stream`, the streaming pipeline's steps
(:func:`cosemdepth.streaming.pipeline.steps`) over a :class:`~cosemdepth.streaming.sources.dataset.DatasetSource`."""

from __future__ import annotations

from typing import Iterator

from ..inference.policy import EVERY_FRAME, Streamer
from ..streaming.frames import StreamBatch
from ..streaming.pipeline import steps
from ..streaming.sources.dataset import DatasetSource, StepPlan, make_schedule, trajectory_rows


def stream(
    model,
    dataset,
    *,
    lanes: int = 1,
    max_frames: int | None = None,
    num_workers: int = 0,
    policy=EVERY_FRAME,
) -> Iterator[StreamBatch]:
    """Run ``model`` (a model, or a :class:`~cosemdepth.inference.Streamer`: then ``policy`` is ignored) over a
    stream-mode ``dataset``; one :class:`~cosemdepth.streaming.frames.StreamBatch` per step."""
    streamer = model if isinstance(model, Streamer) else Streamer(model, policy)
    yield from steps(DatasetSource(dataset), streamer, lanes=lanes, max_frames=max_frames, num_workers=num_workers)


__all__ = ["StepPlan", "StreamBatch", "make_schedule", "stream", "trajectory_rows"]
