"""Process memory without psutil: Linux ``/proc/self/status`` and ``getrusage``; CUDA allocator statistics.

CPU method: glibc is told to serve every allocation above 64 KiB with ``mmap`` (``mallopt(M_MMAP_THRESHOLD)``, which
also stops glibc from raising that threshold after frees), so freed tensors go back to the system and the resident
set follows the live memory. Before a measurement the peak resident set (``VmHWM``) is reset through
``/proc/self/clear_refs`` (Linux >= 4.0); the peak of the measurement is ``VmHWM`` afterwards. Where the reset is
not permitted the lifetime peak (``ru_maxrss``) is all there is, and the result says so.
"""

from __future__ import annotations

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
