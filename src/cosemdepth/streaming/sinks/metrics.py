"""The evaluator's accumulation as a sink: every task's metrics, the frame counts and the model's step time.

Which frames count is the evaluation protocol's rule (:meth:`cosemdepth.evaluation.evaluator.Evaluator.include`),
given as ``include``; this sink only accumulates.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Mapping

import torch

from ...tasks import TaskMetrics
from ..frames import StreamBatch
from ..registry import register_sink


class MetricsSink:
    """Feeds every batch to the ``metrics`` accumulators (task name -> :class:`~cosemdepth.tasks.TaskMetrics`) with
    the frames ``include(batch)`` counts, and counts frames and timed seconds.

    Args:
        metrics: the accumulators, updated in order.
        include: ``batch -> [B] bool``, the frames the metrics count (default: all).
        warmup: streaming steps left out of the timing (unless the run has no more than that).
        steps: the run's number of streaming steps (for the rule above; None: unknown, always left out).
        progress: called with each batch and the mean ms per timed frame so far (None before any), e.g. a bar.
    """

    def __init__(
        self,
        metrics: Mapping[str, TaskMetrics],
        include: Callable[[StreamBatch], torch.Tensor] | None = None,
        *,
        warmup: int = 0,
        steps: int | None = None,
        progress: Callable[[StreamBatch, float | None], None] | None = None,
    ) -> None:
        self.metrics = dict(metrics)
        self.include = include
        self.warmup = max(int(warmup), 0)
        self.steps = steps
        self.progress = progress
        self.frames = self.evaluated = self.resets = self.timed_frames = 0
        self.timed_seconds = 0.0
        self._step = 0

    def open(self, folder: Path | None) -> None:
        pass

    def __call__(self, batch: StreamBatch) -> None:
        include = self.include(batch) if self.include is not None else torch.ones_like(batch.reset)
        for m in self.metrics.values():
            m.update(batch, include)
        n = len(batch)
        self.frames += n
        self.evaluated += int(include.sum())
        self.resets += int(batch.reset.sum())
        if self._step >= self.warmup or (self.steps is not None and self.steps <= self.warmup):
            self.timed_seconds += batch.seconds
            self.timed_frames += n
        self._step += 1
        if self.progress is not None:
            ms = 1000 * self.timed_seconds / self.timed_frames if self.timed_frames else None
            self.progress(batch, ms)

    @property
    def warmup_steps(self) -> int:
        """The steps left out of the timing."""
        return min(self.warmup, self._step)

    def close(self) -> dict[str, Any]:
        return {}

    def abort(self) -> None:
        pass


register_sink("metrics", MetricsSink)

__all__ = ["MetricsSink"]
