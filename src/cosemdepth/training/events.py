"""The event log of a run: one JSON object per line in ``RUN_DIR/events.jsonl``, echoed on the console.

Every line has ``time`` (Unix seconds), ``kind`` and the event's own fields. Kinds written by the trainer:
``start``, ``resume``, ``config_changed``, ``train`` (losses every ``log_every`` steps), ``nonfinite_step``,
``rollback``, ``checkpoint``, ``checkpoint_deferred``, ``checkpoint_invalid``, ``checkpoint_removed``,
``checkpoint_temp_removed``, ``start_over`` (a run folder without a valid checkpoint to resume from), ``validation``,
``best``, ``epoch_end``, ``done``, ``error``.

Lines are appended with a single ``write`` on a file opened in append mode, so a crash can at worst leave one
incomplete last line; :func:`read_events` skips it.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterable

from tqdm import tqdm

#: Kinds shown on the console (the others only go to the file).
CONSOLE_KINDS = {
    "start",
    "resume",
    "config_changed",
    "nonfinite_step",
    "rollback",
    "checkpoint",
    "checkpoint_deferred",
    "checkpoint_invalid",
    "validation",
    "best",
    "epoch_end",
    "done",
    "error",
}


def _clean(x: Any) -> Any:
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, Path):
        return str(x)
    return x


class EventLog:
    """Append events to ``path`` (None: no file) and print a one-line summary of the important ones.

    Args:
        path: the JSON-lines file.
        console: print to stderr (through ``tqdm.write`` so that a progress bar is not broken).
        console_kinds: the kinds printed (default :data:`CONSOLE_KINDS`; add ``"train"`` when there is no
            progress bar).
        listeners: callables receiving each event dict after it was written (tests hook in here).
    """

    def __init__(
        self,
        path: str | os.PathLike | None,
        console: bool = True,
        listeners: Iterable[Callable[[dict], None]] = (),
        console_kinds: Iterable[str] | None = None,
    ) -> None:
        self.path = Path(path) if path is not None else None
        self.console = console
        self.console_kinds = set(CONSOLE_KINDS if console_kinds is None else console_kinds)
        self.listeners = list(listeners)
        self._fd: int | None = None

    def open(self) -> None:
        if self.path is not None and self._fd is None:
            self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __call__(self, kind: str, **fields: Any) -> dict:
        event = {"time": round(time.time(), 3), "kind": kind, **_clean(fields)}
        if self._fd is not None:
            line = json.dumps(event, separators=(",", ":")) + "\n"
            os.write(self._fd, line.encode("utf-8"))
        if self.console and kind in self.console_kinds:
            _echo(_describe(event))
        for fn in self.listeners:
            fn(event)
        return event


def _echo(msg: str) -> None:
    tqdm.write(msg, file=sys.stderr)


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _describe(event: dict) -> str:
    kind = event["kind"]
    skip = {"time", "kind", "iou", "config", "traceback"}
    fields = " ".join(f"{k}={_fmt(v)}" for k, v in event.items() if k not in skip and not isinstance(v, (dict, list)))
    for k, v in event.items():
        if k not in skip and isinstance(v, list) and all(isinstance(x, (str, int, float)) for x in v):
            fields += f" {k}=[{'; '.join(_fmt(x) for x in v)}]"
    metrics = event.get("metrics")
    if isinstance(metrics, dict):
        shown = {k: v for k, v in metrics.items() if isinstance(v, float)}
        fields += " " + " ".join(f"{k}={_fmt(v)}" for k, v in shown.items())
    return f"[{kind}] {fields.strip()}".rstrip()


def read_events(path: str | os.PathLike) -> list[dict]:
    """The events of a log file, skipping an incomplete (or otherwise unreadable) line."""
    out = []
    p = Path(path)
    if not p.exists():
        return out
    for line in p.read_text(encoding="utf-8", errors="replace").splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return out


__all__ = ["CONSOLE_KINDS", "EventLog", "read_events"]
