"""The one device-name check of the package: ``resolve_device`` (training's ``train.device``, the commands'
``--device``); what a device can compute in (:func:`onednn_enabled`, :func:`bf16_convolutions`); how much memory it
has free (:func:`available_memory`); and :func:`retain_freed_host_memory`, the host allocator setting of CPU
training."""

from __future__ import annotations

import ctypes
import os
import resource
import sys
from pathlib import Path

import torch

from .errors import ConfigError


def resolve_device(name: str, what: str = "--device") -> torch.device:
    """``"auto"`` (CUDA when available, else the CPU), ``"cpu"``, ``"cuda"``, ``"cuda:N"`` or ``"mps"`` -> a device
    that exists here; else a one-line :class:`ConfigError` naming the argument ``what``."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except (RuntimeError, TypeError, ValueError):
        raise ConfigError(f"{what}: not a device name: {name!r} (auto, cpu, cuda[:N] or mps)") from None
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError(f"{what} {name}: CUDA is not available on this machine (use 'auto' or 'cpu')")
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise ConfigError(f"{what} {name}: only {torch.cuda.device_count()} CUDA device(s) here")
    elif device.type == "mps":
        if not (getattr(torch.backends, "mps", None) and torch.backends.mps.is_available()):
            raise ConfigError(f"{what} {name}: MPS is not available on this machine")
    elif device.type != "cpu":
        raise ConfigError(f"{what}: unsupported device {name!r} (auto, cpu, cuda[:N] or mps)")
    return device


def onednn_enabled() -> bool:
    """Whether CPU convolutions go through oneDNN: built in and not switched off (``torch.backends.mkldnn.flags``)."""
    try:
        return bool(torch.backends.mkldnn.is_available() and torch.backends.mkldnn.enabled)
    except (AttributeError, RuntimeError):  # pragma: no cover - exotic builds
        return False


def bf16_convolutions(device: torch.device | str = "cpu") -> bool:
    """Whether bfloat16 convolutions run on ``device``: on CUDA, yes; on the CPU, where oneDNN has bf16 kernels
    (AVX-512 BW/VL/DQ, AVX512-BF16, AMX or AVX-NE-CONVERT; not an AVX2-only CPU), or where oneDNN is switched off
    (PyTorch's own kernels, slow). ``train.bf16`` and the fast path's ``bf16`` ask this first."""
    device = torch.device(device)
    if device.type == "cuda":
        return True
    if device.type != "cpu":
        return False
    return _onednn_bf16() if onednn_enabled() else True


def _onednn_bf16() -> bool:
    """oneDNN's own answer: bf16 convolution kernels for this CPU."""
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):  # pragma: no cover - exotic builds
        return False


def no_bf16_reason() -> str:
    """Why bf16 is refused on this CPU, for the one-line errors of the commands that take bf16."""
    return f"oneDNN has no bfloat16 convolutions on this CPU ({cpu_capability()}; they need AVX-512 or AVX-NE-CONVERT)"


def cpu_capability() -> str:
    """The vector extension PyTorch's CPU kernels use here (``"AVX2"``, ``"AVX512"``...), for messages."""
    try:
        return torch.backends.cpu.get_cpu_capability()
    except (AttributeError, RuntimeError):  # pragma: no cover - exotic builds
        return "unknown"


#: Where Linux reports the memory a process may still take (module constants: tests point them at their own files).
MEMINFO = Path("/proc/meminfo")
PROC_STATUS = Path("/proc/self/status")
CGROUP_ROOT = Path("/sys/fs/cgroup")


def available_memory(device: torch.device | str = "cpu") -> tuple[int | None, str]:
    """``(bytes, where)``: the memory a new allocation on ``device`` may still take, and where that figure comes
    from (for messages); ``(None, "unknown")`` when the system does not say.

    CUDA: the device's free memory (``cudaMemGetInfo``). Otherwise the host's: the smallest of the kernel's
    ``MemAvailable``, the room left under the cgroup's memory limit (v2 ``memory.max`` or v1
    ``memory.limit_in_bytes``; reclaimable page cache counted as free) and under the process's ``ulimit -v``
    (``RLIMIT_AS``) and ``RLIMIT_DATA``.
    """
    device = torch.device(device)
    if device.type == "cuda":
        try:
            free, _ = torch.cuda.mem_get_info(device)
            return int(free), f"free memory of {device}"
        except (RuntimeError, AssertionError):  # pragma: no cover - a CUDA build without a usable device
            return None, "unknown"
    candidates: list[tuple[int, str]] = []
    kib = _kib_field(MEMINFO, "MemAvailable")
    if kib is not None:
        candidates.append((kib * 1024, "MemAvailable"))
    cgroup = _cgroup_room()
    if cgroup is not None:
        candidates.append((cgroup, "the cgroup's memory limit"))
    for limit, field, name in (
        (resource.RLIMIT_AS, "VmSize", "ulimit -v"),
        (resource.RLIMIT_DATA, "VmData", "RLIMIT_DATA"),
    ):
        soft = resource.getrlimit(limit)[0]
        used = _kib_field(PROC_STATUS, field)
        if soft != resource.RLIM_INFINITY and used is not None:
            candidates.append((max(soft - used * 1024, 0), f"the process's {name}"))
    if not candidates:
        try:
            pages = os.sysconf("SC_AVPHYS_PAGES") if hasattr(os, "sysconf") else -1
            if pages > 0:
                candidates.append((pages * os.sysconf("SC_PAGE_SIZE"), "free physical memory"))
        except (ValueError, OSError):  # pragma: no cover - a system without these names
            pass
    if not candidates:
        return None, "unknown"
    return min(candidates)


def _kib_field(path: Path, field: str) -> int | None:
    """The kB value of ``field:`` in a ``/proc`` file (``MemAvailable:  20457596 kB``), or None."""
    try:
        for line in path.read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return None


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None  # "max" (v2: no limit) is None


def _stat_field(path: Path, names: tuple[str, ...]) -> int:
    try:
        for line in path.read_text().splitlines():
            key, _, value = line.partition(" ")
            if key in names and value.strip().isdigit():
                return int(value)
    except OSError:
        pass
    return 0


def _cgroup_room() -> int | None:
    """Bytes left under this process's cgroup memory limit (v2, else v1), or None without a limit."""
    v2 = CGROUP_ROOT / "memory.max"
    if v2.exists():
        limit, usage = _read_int(v2), _read_int(CGROUP_ROOT / "memory.current")
        cache = _stat_field(CGROUP_ROOT / "memory.stat", ("inactive_file",))
    else:
        v1 = CGROUP_ROOT / "memory"
        limit, usage = _read_int(v1 / "memory.limit_in_bytes"), _read_int(v1 / "memory.usage_in_bytes")
        cache = _stat_field(v1 / "memory.stat", ("total_inactive_file", "inactive_file"))
    if limit is None or usage is None or limit >= 1 << 60:  # v1 writes "no limit" as a huge number
        return None
    return max(limit - max(usage - cache, 0), 0)


#: glibc's ``mallopt`` parameters (``malloc.h``).
_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3


def retain_freed_host_memory(limit_bytes: int = 1 << 30) -> bool:
    """Keep freed host memory in the process for reuse (glibc only); returns whether the setting took effect.

    A CPU training step allocates and frees the same few hundred activation buffers every step, many of several MB.
    By default glibc serves blocks above its mmap threshold (128 KiB, raised dynamically up to 32 MiB) with fresh
    ``mmap`` pages and returns them, and trims the heap's free top, so every step faults its activations in again
    (15,000-25,000 page faults a step at 128 px, batch 3, seq 4; each fault zero-fills a page, dearer on a VM).
    This raises the mmap threshold to ``limit_bytes`` and the trim threshold far above it, so that blocks up to
    ``limit_bytes`` are reused from the heap (about 1,000 faults a step). The process keeps its peak heap instead of
    returning it between steps. Elsewhere than glibc (macOS, Windows, musl) nothing changes and False is returned.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library the interpreter is linked with
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    limit = int(min(limit_bytes, 2**31 - 1))
    ok = mallopt(_M_MMAP_THRESHOLD, limit) == 1
    ok = mallopt(_M_TRIM_THRESHOLD, 2**31 - 1) == 1 and ok
    ok = mallopt(_M_TOP_PAD, 64 << 20) == 1 and ok
    return ok


__all__ = [
    "available_memory",
    "bf16_convolutions",
    "cpu_capability",
    "no_bf16_reason",
    "onednn_enabled",
    "resolve_device",
    "retain_freed_host_memory",
]
