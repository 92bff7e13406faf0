"""Bilinear backward warping with border clamping (design 2.5)."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .camera import pixel_grid


def sample_bilinear(image: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Sample ``image`` at fractional pixel positions, bilinearly, clamping positions to the image (border).

    Integer positions address pixel centres: ``(x, y) = (j, i)`` returns ``image[..., i, j]``.

    Args:
        image: ``[B, C, H, W]``.
        points: ``[B, 2, H_o, W_o]`` positions (x = column, y = row).
    Returns:
        ``[B, C, H_o, W_o]``.
    """
    h, w = image.shape[-2:]
    x, y = points[:, 0], points[:, 1]
    # align_corners=True maps -1/+1 to the centres of the first/last pixels; a size-1 axis maps everything to 0.
    xn = x * (2.0 / (w - 1)) - 1.0 if w > 1 else torch.zeros_like(x)
    yn = y * (2.0 / (h - 1)) - 1.0 if h > 1 else torch.zeros_like(y)
    grid = torch.stack([xn, yn], dim=-1)
    return F.grid_sample(image, grid, mode="bilinear", padding_mode="border", align_corners=True)


def warp(image: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """``Warp(img, flow)[i, j] = img(i + flow_y, j + flow_x)``, bilinear, border-clamped (design 2.5).

    Gradients flow to the image and to the flow (zero where the clamp is active).

    Args:
        image: ``[B, C, H, W]``.
        flow: ``[B, 2, H, W]`` (x then y) in pixels.
    Returns:
        ``[B, C, H, W]``.
    """
    h, w = flow.shape[-2:]
    i, j = pixel_grid(h, w, flow.device, flow.dtype)
    points = torch.cat([j + flow[:, 0:1], i + flow[:, 1:2]], dim=1)
    return sample_bilinear(image, points)
