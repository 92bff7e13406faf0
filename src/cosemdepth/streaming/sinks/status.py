"""The depth's status counts and valid fractions of a run, for its summary line (``cosemdepth view``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..frames import StreamBatch
from ..registry import register_sink


class StatusSink:
    """Counts each frame's depth status (``reset``, ``estimated``, ``held``) and keeps its fraction of valid pixels;
    :meth:`close` returns them as ``frames_by_status`` and ``valid_fractions`` (empty for a model without depth)."""

    def __init__(self) -> None:
        self.statuses: dict[str, int] = {}
        self.fractions: list[float] = []

    def open(self, folder: Path | None) -> None:
        pass

    def __call__(self, batch: StreamBatch) -> None:
        for b, st in enumerate(batch.status if batch.valid is not None else ()):
            self.statuses[st] = self.statuses.get(st, 0) + 1
            self.fractions.append(float(batch.valid[b].float().mean()))

    def close(self) -> dict[str, Any]:
        return {"frames_by_status": dict(self.statuses), "valid_fractions": list(self.fractions)}

    def abort(self) -> None:
        pass


register_sink("status", StatusSink)

__all__ = ["StatusSink"]
