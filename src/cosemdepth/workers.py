"""The bound on worker processes: data-loading workers (``--workers``, ``data.num_workers``) and SynthAir's render
processes (``synth --workers``).

Each worker is a whole process (a copy of the dataset reader, or a renderer); a count far beyond the CPU cores only
competes for them, and an absurd one (``--workers 100000``) forks until the machine stalls. Every pool the package
starts is checked here first, before anything is read or written: at most :data:`WORKERS_PER_CORE` per CPU core this
process may run on.
"""

from __future__ import annotations

import os

from .errors import ConfigError

#: Most worker processes per usable CPU core (more than one, for workers that wait on the disk).
WORKERS_PER_CORE = 4


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the system has one)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):
        return max(os.cpu_count() or 1, 1)


def max_workers() -> int:
    """The most worker processes a pool may have here."""
    return WORKERS_PER_CORE * usable_cores()


def check_workers(n, what: str = "--workers", minimum: int = 0) -> int:
    """``n`` if it is an integer in ``[minimum, max_workers()]``; else a one-line :class:`ConfigError` naming
    ``what`` and the bound."""
    if not isinstance(n, int) or isinstance(n, bool) or n < minimum:
        raise ConfigError(f"{what} must be an integer >= {minimum}, got {n!r}")
    bound = max_workers()
    if n > bound:
        cores = usable_cores()
        raise ConfigError(
            f"{what} {n}: more worker processes than this machine can run (at most {bound}: "
            f"{WORKERS_PER_CORE} per CPU core, {cores} core{'s' * (cores != 1)} here); use fewer"
        )
    return n


__all__ = ["WORKERS_PER_CORE", "check_workers", "max_workers", "usable_cores"]
