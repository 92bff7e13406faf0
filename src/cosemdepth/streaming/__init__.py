"""The streaming pipeline: a *source* yields frames (:class:`FrameBatch`), a
:class:`~cosemdepth.inference.policy.Streamer` runs the model, *sinks* consume the outputs (:class:`StreamBatch`);
:func:`run` drives them. Sources and sinks are found by name in :data:`SOURCES` and :data:`SINKS`."""

from __future__ import annotations

from . import sinks, sources  # noqa: F401 (the built-in sources and sinks register themselves)
from .frames import FrameBatch, Sink, Source, StreamBatch
from .pipeline import run
from .registry import SINKS, SOURCES, register_sink, register_source
from .sources.dataset import DatasetSource

__all__ = [
    "DatasetSource",
    "FrameBatch",
    "SINKS",
    "SOURCES",
    "Sink",
    "Source",
    "StreamBatch",
    "register_sink",
    "register_source",
    "run",
]
