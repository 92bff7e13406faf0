"""The one device-name check of the package: ``resolve_device`` (training's ``train.device``, the commands'
``--device``); what a device can compute in (:func:`onednn_enabled`, :func:`bf16_convolutions`); and
:func:`retain_freed_host_memory`, the host allocator setting of CPU training."""

from __future__ import annotations

import ctypes
import sys

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
    return (f"oneDNN has no bfloat16 convolutions on this CPU ({cpu_capability()}; they need AVX-512 or "
            "AVX-NE-CONVERT)")


def cpu_capability() -> str:
    """The vector extension PyTorch's CPU kernels use here (``"AVX2"``, ``"AVX512"``...), for messages."""
    try:
        return torch.backends.cpu.get_cpu_capability()
    except (AttributeError, RuntimeError):  # pragma: no cover - exotic builds
        return "unknown"


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


__all__ = ["bf16_convolutions", "cpu_capability", "no_bf16_reason", "onednn_enabled", "resolve_device",
           "retain_freed_host_memory"]
