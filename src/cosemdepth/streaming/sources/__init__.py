"""The built-in sources of the streaming pipeline (:data:`cosemdepth.streaming.registry.SOURCES`)."""

from __future__ import annotations

from .dataset import DatasetSource

__all__ = ["DatasetSource"]
