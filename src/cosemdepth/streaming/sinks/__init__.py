"""The built-in sinks of the streaming pipeline (:data:`cosemdepth.streaming.SINKS`): predict's files, pictures and
videos (:mod:`~cosemdepth.streaming.sinks.files`), the output bag (:mod:`~cosemdepth.streaming.sinks.bag`), a rerun
recording (:mod:`~cosemdepth.streaming.sinks.rerun`), the evaluator's metrics
(:mod:`~cosemdepth.streaming.sinks.metrics`), the depth's statuses (:mod:`~cosemdepth.streaming.sinks.status`).

Their modules are imported by :mod:`cosemdepth.streaming` (which registers them); the optional libraries of the bag
(``rosbags``) and rerun (``rerun-sdk``) sinks only when one is made."""

from __future__ import annotations

from .bag import BagSink
from .files import FilesSink
from .metrics import MetricsSink
from .rerun import RerunSink
from .status import StatusSink

__all__ = ["BagSink", "FilesSink", "MetricsSink", "RerunSink", "StatusSink"]
