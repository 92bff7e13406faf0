"""The one device-name check of the package: ``resolve_device`` (training's ``train.device``, the commands'
``--device``)."""

from __future__ import annotations

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


__all__ = ["resolve_device"]
