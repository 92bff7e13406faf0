"""Decoder tasks: what each registered decoder learns, how it is measured, written and drawn
(:class:`~cosemdepth.tasks.base.DecoderTask`), for the depth and semantic decoders and any decoder registered with
:func:`register_task` (see docs/architecture.md, "A new decoder")."""

from .base import (
    TASKS,
    TEST,
    VALIDATION,
    DecoderTask,
    Frames,
    MetricContext,
    TaskMetrics,
    TaskWriter,
    WriteOptions,
    architecture_of,
    class_count,
    float32_levels,
    register_task,
    task,
    tasks_for,
)
from .depth import DEPTH
from .semantic import SEMANTIC

__all__ = [
    "DEPTH",
    "DecoderTask",
    "Frames",
    "MetricContext",
    "SEMANTIC",
    "TASKS",
    "TEST",
    "TaskMetrics",
    "TaskWriter",
    "VALIDATION",
    "WriteOptions",
    "architecture_of",
    "class_count",
    "float32_levels",
    "register_task",
    "task",
    "tasks_for",
]
