"""Process memory without psutil: Linux ``/proc/self/status`` and ``getrusage``; CUDA allocator statistics.

CPU method: before a measurement, garbage is collected and glibc hands its free heap pages back to the system
(``malloc_trim``), so the resident set is the live memory; the peak resident set (``VmHWM``) is then reset through
``/proc/self/clear_refs`` (Linux >= 4.0), and the peak of the measurement is ``VmHWM`` afterwards. Where the reset
is not permitted the lifetime peak (``ru_maxrss``) is all there is, and the result says so.

:func:`use_mmap_for_large_allocations` makes glibc return every freed block above 64 KiB at once, so that the
resident set follows the live memory at every instant (``benchmarks/memory_flat.py`` uses it). Do not use it while
timing: every large tensor then costs an ``mmap``, page faults and an ``munmap`` (it made a 384x384 step 1.7x
slower here).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import gc
import resource
import sys
from pathlib import Path

import torch

_M_MMAP_THRESHOLD = -3
_STATUS = Path("/proc/self/status")
_CLEAR_REFS = Path("/proc/self/clear_refs")


def _libc():
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    except OSError:  # pragma: no cover
        return None


def use_mmap_for_large_allocations(threshold: int = 64 * 1024) -> bool:
    """Make glibc return freed large blocks to the system at once (see the module doc); True if it took effect."""
    libc = _libc()
    if libc is None or not hasattr(libc, "mallopt"):
        return False
    return bool(libc.mallopt(_M_MMAP_THRESHOLD, threshold))


#: glibc's largest dynamic mmap threshold on 64-bit systems (its steady state after large frees).
_GLIBC_MMAP_THRESHOLD_MAX = 32 * 1024 * 1024


@contextlib.contextmanager
def exact_rss():
    """Within the block, freed blocks above 64 KiB go back to the system at once (slow: for memory passes only);
    afterwards the threshold is 32 MiB, glibc's usual steady state."""
    use_mmap_for_large_allocations(64 * 1024)
    try:
        yield
    finally:
        use_mmap_for_large_allocations(_GLIBC_MMAP_THRESHOLD_MAX)


def trim() -> None:
    """Collect garbage and hand free heap memory back to the system (``malloc_trim``)."""
    gc.collect()
    libc = _libc()
    if libc is not None and hasattr(libc, "malloc_trim"):
        libc.malloc_trim(0)


def _status_kib(field: str) -> int | None:
    try:
        for line in _STATUS.read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def rss_bytes() -> int:
    """Current resident set size in bytes (``VmRSS``; ``ru_maxrss`` where /proc is missing)."""
    kib = _status_kib("VmRSS")
    if kib is None:
        kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return kib * 1024


def peak_rss_bytes() -> int:
    """Peak resident set size in bytes since the last :func:`reset_peak_rss` (or process start)."""
    kib = _status_kib("VmHWM")
    if kib is None:
        kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return kib * 1024


def reset_peak_rss() -> bool:
    """Reset ``VmHWM`` to the current RSS; False if this kernel/container does not allow it."""
    try:
        _CLEAR_REFS.write_text("5")
        return True
    except OSError:
        return False


class PeakMemory:
    """Context manager measuring the peak memory of a block above the memory in use when it starts.

    ``device`` "cpu": resident set of the process (see module doc); "cuda": ``torch.cuda.max_memory_allocated``.
    Attributes after exit: ``baseline`` (bytes in use at entry), ``peak`` (largest bytes in use during the block),
    ``extra`` (= peak - baseline), ``method`` (a short description), ``exact`` (False if the peak could not be reset).
    """

    def __init__(self, device: str | torch.device = "cpu"):
        self.device = torch.device(device)
        self.baseline = self.peak = self.extra = 0
        self.exact = True
        self.method = ""

    def __enter__(self) -> "PeakMemory":
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
            torch.cuda.empty_cache()
            torch.cuda.reset_peak_memory_stats(self.device)
            self.baseline = torch.cuda.memory_allocated(self.device)
            self.method = "torch.cuda.max_memory_allocated"
        else:
            trim()
            self.exact = reset_peak_rss()
            self.baseline = rss_bytes()
            self.method = "VmHWM after clear_refs" if self.exact else "ru_maxrss (lifetime peak)"
        return self

    def __exit__(self, *exc) -> None:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
            self.peak = torch.cuda.max_memory_allocated(self.device)
        else:
            self.peak = peak_rss_bytes()
        self.extra = max(self.peak - self.baseline, 0)
