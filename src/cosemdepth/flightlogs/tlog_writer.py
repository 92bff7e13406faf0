"""MAVLink telemetry logs (``.tlog``) packed with ``pymavlink``'s message classes (MAVLink 2, the ``common``
dialect): each packet preceded by its 8-byte big-endian Unix time of reception in microseconds, as ground stations
write them. Packets are written in order of reception, each system/component with its own sequence numbers."""

from __future__ import annotations

import inspect
import struct
from pathlib import Path

from ..optional import require
from ..output_safety.atomic import atomic_open


class TlogWriter:
    """Collects messages: ``add(receive_us, "ATTITUDE", time_boot_ms=..., roll=...)`` (fields not given are 0), then
    :meth:`to_bytes` or :meth:`write`."""

    def __init__(self) -> None:
        self._dialect = require("pymavlink.dialects.v20.common", "writing a MAVLink telemetry log")
        self._links: dict[tuple[int, int], object] = {}
        self._queue: list[tuple[int, int, int, int, object]] = []

    def message(self, name: str, **fields):
        """A pymavlink message object ``name`` (e.g. ``"GLOBAL_POSITION_INT"``) with ``fields``, the others 0."""
        cls = getattr(self._dialect, f"MAVLink_{name.lower()}_message")
        kwargs = {}
        for p in list(inspect.signature(cls.__init__).parameters.values())[1:]:
            if p.name in fields:
                kwargs[p.name] = fields.pop(p.name)
            elif p.default is inspect.Parameter.empty:
                length = dict(zip(cls.fieldnames, cls.array_lengths)).get(p.name, 0)
                kwargs[p.name] = [0] * length if length else 0
        if fields:
            raise ValueError(f"MAVLink {name} has no field(s) {sorted(fields)}")
        return cls(**kwargs)

    def add(self, receive_us: int, name: str, system: int = 1, component: int = 1, **fields) -> None:
        """Queue message ``name`` from ``system``/``component``, received at Unix time ``receive_us``."""
        self._queue.append((int(receive_us), len(self._queue), system, component, self.message(name, **fields)))

    def to_bytes(self) -> bytes:
        """The tlog: every queued message in order of reception (ties in the order added)."""
        out = bytearray()
        for receive_us, _, system, component, msg in sorted(self._queue, key=lambda r: (r[0], r[1])):
            link = self._links.get((system, component))
            if link is None:
                link = self._dialect.MAVLink(None, srcSystem=system, srcComponent=component)
                self._links[(system, component)] = link
            out += struct.pack(">Q", receive_us) + msg.pack(link)
        return bytes(out)

    def write(self, path: str | Path) -> None:
        """Write :meth:`to_bytes` to ``path`` atomically."""
        with atomic_open(path, "wb") as f:
            f.write(self.to_bytes())


__all__ = ["TlogWriter"]
