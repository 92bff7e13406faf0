"""Speed and memory measurement of the models (used by ``cosemdepth benchmark`` and ``benchmarks/``).

Attributes are imported lazily (importing the package does not load torch)."""

from __future__ import annotations

from .._lazy import lazy_getattr as _lazy_getattr

_LAZY = {
    "make_report": ".harness",
    "write_report": ".harness",
    "run_meta": ".harness",
    "time_calls": ".harness",
    "command_line": ".harness",
    "rss_bytes": ".memory",
    "trim": ".memory",
    "use_mmap_for_large_allocations": ".memory",
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = sorted(_LAZY)
