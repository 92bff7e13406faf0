"""``cosemdepth node``'s loop: the live source through the streamer into the topics sink, until SIGINT / SIGTERM.

The loop is the streaming pipeline's (:func:`cosemdepth.streaming.pipeline.run`); this module adds what a
long-running process needs: a clean stop on SIGINT and SIGTERM (the frame in progress is finished and published, the
participant leaves the graph; a second signal stops at once), and a report once a minute on stderr (frames received,
processed, dropped, without a pose, the resets, and the latency's percentiles over the frames since the last report).
Memory is bounded: the queues and the latency window have fixed lengths, counters are integers.
"""

from __future__ import annotations

import resource
import signal
import threading
import time
from collections import deque
from typing import Any, Callable

import numpy as np

from ..streaming.pipeline import run
from .sink import TopicSink
from .source import LiveSource, LiveStats, log_stderr

#: Seconds between two progress reports on stderr.
REPORT_EVERY = 60.0


def percentiles(values, qs=(50, 95)) -> dict[str, float | None]:
    """``{"p50": ..., "p95": ...}`` of ``values`` (None when empty)."""
    v = np.asarray(list(values), dtype=np.float64)
    return {f"p{q}": (None if v.size == 0 else float(np.percentile(v, q))) for q in qs}


def max_rss_mb() -> float:
    """The process's peak resident memory so far, MiB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class Reporter:
    """The pipeline's progress callback: a line on ``log`` every ``every`` seconds."""

    def __init__(self, stats: LiveStats, sink: TopicSink, log: Callable[[str], None], every: float = REPORT_EVERY):
        self.stats, self.sink, self.log, self.every = stats, sink, log, every
        self.t0 = self.last = time.monotonic()
        self.seen = 0
        self.window: deque[float] = deque(maxlen=4096)

    def __call__(self, batch) -> None:
        if self.sink.latencies:
            self.window.append(self.sink.latencies[-1])
        now = time.monotonic()
        if self.every > 0 and now - self.last >= self.every:
            self.log(self.line(now))
            self.last, self.seen = now, self.stats.processed
            self.window.clear()

    def line(self, now: float | None = None, final: bool = False) -> str:
        """The report since the last one (``final``: over the whole run, the latency over the last frames)."""
        now = time.monotonic() if now is None else now
        s = self.stats
        since, seen = (self.t0, 0) if final else (self.last, self.seen)
        rate = (s.processed - seen) / max(now - since, 1e-9)
        p = percentiles(self.sink.latencies if final else self.window)
        lat = "no frame" if p["p50"] is None else f"p50 {p['p50']:.0f} ms, p95 {p['p95']:.0f} ms"
        resets = ", ".join(f"{k} {v}" for k, v in sorted(s.resets.items())) or "none"
        return (
            f"{s.received} frames received, {s.processed} processed ({rate:.1f} Hz{'' if final else ' lately'}), "
            f"{s.dropped} dropped, "
            f"{s.unposed} without a pose; latency {lat}; resets: {resets}; peak memory {max_rss_mb():.0f} MiB"
        )


class _Signals:
    """SIGINT / SIGTERM call ``stop`` (a second one raises KeyboardInterrupt); the handlers are restored on exit.
    Only in the main thread (elsewhere signals cannot be handled)."""

    def __init__(self, stop: Callable[[], None], log: Callable[[str], None]) -> None:
        self.stop, self.log = stop, log
        self.saved: dict[int, Any] = {}
        self.count = 0

    def _handle(self, signum, frame) -> None:
        self.count += 1
        if self.count > 1:
            raise KeyboardInterrupt
        self.log(f"{signal.Signals(signum).name}: stopping after the frame in progress")
        self.stop()

    def __enter__(self) -> "_Signals":
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                self.saved[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for s, h in self.saved.items():
            signal.signal(s, h)


def run_node(
    source: LiveSource,
    streamer,
    sink: TopicSink,
    *,
    max_frames: int | None = None,
    report_every: float = REPORT_EVERY,
    log: Callable[[str], None] = log_stderr,
) -> dict[str, Any]:
    """Run until stopped (a signal, :meth:`LiveSource.stop`, ``max_frames`` processed frames); returns the run's
    summary: the source's description, the counters, the latency's p50/p95 over the last frames (ms), the topics."""
    reporter = Reporter(source.stats, sink, log, report_every)
    with _Signals(source.stop, log):
        summary: dict[str, Any] = {}
        if source.start():
            summary = run(source, streamer, [sink], max_frames=max_frames, progress=reporter)
        else:
            source.close()
    lat = percentiles(sink.latencies)
    return {
        "input": source.describe(),
        **source.stats.as_dict(),
        "latency_ms": lat,
        "peak_memory_mib": max_rss_mb(),
        **summary,
        "report": reporter.line(final=True),
    }


__all__ = ["REPORT_EVERY", "Reporter", "percentiles", "run_node"]
