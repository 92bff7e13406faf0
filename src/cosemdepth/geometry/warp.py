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
    if torch.onnx.is_in_onnx_export():
        return sample_bilinear_rows(image, points)
    h, w = image.shape[-2:]
    x, y = points[:, 0], points[:, 1]
    # align_corners=True maps -1/+1 to the centres of the first/last pixels; a size-1 axis maps everything to 0.
    xn = x * (2.0 / (w - 1)) - 1.0 if w > 1 else torch.zeros_like(x)
    yn = y * (2.0 / (h - 1)) - 1.0 if h > 1 else torch.zeros_like(y)
    grid = torch.stack([xn, yn], dim=-1)
    return F.grid_sample(image, grid, mode="bilinear", padding_mode="border", align_corners=True)


def sample_bilinear_rows(image: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """:func:`sample_bilinear` as :func:`sample_bilinear_pixels` (same arguments and result layout)."""
    b, c = image.shape[:2]
    ho, wo = points.shape[-2:]
    return sample_bilinear_pixels(image, points).reshape(b, ho, wo, c).permute(0, 3, 1, 2)


def sample_bilinear_pixels(image: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """:func:`sample_bilinear` (same arguments, same result up to float rounding) as gathers of whole pixels: the
    image channels-last as rows of C values, the four taps of every position gathered as rows and blended with
    their bilinear weights. The exported graph takes this form: ONNX Runtime's CPU GridSample kernel is many times
    slower than four row gathers, and row gathers map onto every runtime's plain Gather.

    Args:
        image: ``[B, C, H, W]``.
        points: ``[B, 2, H_o, W_o]`` positions (x = column, y = row).
    Returns:
        ``[B, H_o * W_o, C]``: the samples channels-last, positions in row-major order.
    """
    b, c, h, w = image.shape
    ho, wo = points.shape[-2:]
    x = points[:, 0].reshape(b, ho * wo).clamp(0, w - 1)  # border padding = positions clamped to the pixel centres
    y = points[:, 1].reshape(b, ho * wo).clamp(0, h - 1)
    x0 = x.floor().clamp(max=max(w - 2, 0))
    y0 = y.floor().clamp(max=max(h - 2, 0))
    fx = (x - x0).unsqueeze(2)  # [B, N, 1]
    fy = (y - y0).unsqueeze(2)
    xi, yi = x0.long(), y0.long()
    dx, dy = (1 if w > 1 else 0), (w if h > 1 else 0)
    base = yi * w + xi + (torch.arange(b, device=image.device) * (h * w)).unsqueeze(1)  # [B, N] rows of pixel (x0, y0)
    rows = image.permute(0, 2, 3, 1).reshape(b * h * w, c)
    tap = lambda off: rows[(base + off).reshape(-1)].reshape(b, ho * wo, c)  # noqa: E731
    top = tap(0) + fx * (tap(dx) - tap(0)) if dx else tap(0)
    bottom = tap(dy) + fx * (tap(dy + dx) - tap(dy)) if dx else tap(dy)
    out = top + fy * (bottom - top) if dy else top
    return out.reshape(b, ho * wo, c)


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
