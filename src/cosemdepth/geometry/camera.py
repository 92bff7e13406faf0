"""Pinhole camera helpers (design 2.1)."""

from __future__ import annotations

import torch


def level_intrinsics(intrinsics: torch.Tensor, level: int) -> torch.Tensor:
    """Intrinsics of decoder level ``level`` (1 = half resolution): ``f / 2^l`` and ``c / 2^l``.

    Args:
        intrinsics: ``[B, 4]`` = ``(fx, fy, cx, cy)`` in pixels of the network input.
        level: absolute level index ``l >= 0``.
    Returns:
        ``[B, 4]``.
    """
    return intrinsics / float(2**level)


def pixel_grid(height: int, width: int, device=None, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """Row and column indices of a ``height x width`` grid.

    Returns:
        ``(i, j)``, each ``[1, 1, H, W]``: the row index and the column index of every pixel.
    """
    i = torch.arange(height, device=device, dtype=dtype).view(1, 1, height, 1).expand(1, 1, height, width)
    j = torch.arange(width, device=device, dtype=dtype).view(1, 1, 1, width).expand(1, 1, height, width)
    return i, j


def centred_coordinates(height: int, width: int, intrinsics: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Centred pixel coordinates ``u = j + 0.5 - cx``, ``v = i + 0.5 - cy`` (design 2.1).

    Args:
        intrinsics: ``[B, 4]`` of this grid.
    Returns:
        ``(u, v)``, each ``[B, 1, H, W]``.
    """
    i, j = pixel_grid(height, width, intrinsics.device, intrinsics.dtype)
    cx = intrinsics[:, 2].view(-1, 1, 1, 1)
    cy = intrinsics[:, 3].view(-1, 1, 1, 1)
    return j + 0.5 - cx, i + 0.5 - cy


def pixel_rays(height: int, width: int, intrinsics: torch.Tensor) -> torch.Tensor:
    """Normalised rays ``(u / fx, v / fy, 1)`` of every pixel.

    Args:
        intrinsics: ``[B, 4]`` of this grid.
    Returns:
        ``[B, 3, H, W]``.
    """
    u, v = centred_coordinates(height, width, intrinsics)
    fx = intrinsics[:, 0].view(-1, 1, 1, 1)
    fy = intrinsics[:, 1].view(-1, 1, 1, 1)
    x = u / fx
    y = v / fy
    return torch.cat([x, y, torch.ones_like(x)], dim=1)
