"""Resampling primitives that reproduce TensorFlow's resize rules exactly (design 3).

All functions take NCHW tensors (any leading batch/channel layout with the last two axes spatial) and a target
``size = (H_out, W_out)``.

=====  ==============================================  ===========================================
name   TensorFlow op                                   used for
=====  ==============================================  ===========================================
BL1    legacy bilinear (no half-pixel, no corners)     depth decoder: upsampling rho, O, D
BL2    TF2 bilinear (half-pixel, no antialias)         RGB/depth 1024->384, GT log-depth pyramids
NN1    legacy nearest (floor(k*s))                     semantic decoder upsampling; OpenCV nearest
NN2    TF2 nearest (half-pixel, floor((k+.5)*s))       GT label pyramids, output upsampling
=====  ==============================================  ===========================================
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

Size = tuple[int, int]


def _legacy_axis(n_in: int, n_out: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Source indices (k0, k1) and weights a of the legacy TF bilinear rule along one axis.

    ``x = k * n_in / n_out`` (computed in float32 as TF does), ``k0 = floor(x)``, ``k1 = min(k0 + 1, n_in - 1)``,
    ``a = x - k0``.
    """
    scale = torch.tensor(n_in / n_out, dtype=torch.float32)
    x = torch.arange(n_out, dtype=torch.float32) * scale
    k0 = torch.floor(x)
    a = x - k0
    k0 = k0.long().clamp_(max=n_in - 1)
    k1 = (k0 + 1).clamp_(max=n_in - 1)
    return k0.to(device), k1.to(device), a.to(device)


def resize_bl1(x: torch.Tensor, size: Size) -> torch.Tensor:
    """Legacy TF1 bilinear resize (``align_corners=False``, ``half_pixel_centers=False``), design 3.1.

    For an exact x2 upsampling: ``out[2m] = in[m]``, ``out[2m+1] = (in[m] + in[m+1]) / 2`` and the last output
    repeats the last input. Interpolates along W first, then along H, with TF's ``a + (b - a) * t`` form.

    Args:
        x: ``[..., H_in, W_in]``.
        size: ``(H_out, W_out)``.
    Returns:
        ``[..., H_out, W_out]``.
    """
    h_in, w_in = x.shape[-2:]
    h_out, w_out = size
    if (h_in, w_in) == (h_out, w_out):
        return x
    x0, x1, ax = _legacy_axis(w_in, w_out, x.device)
    y0, y1, ay = _legacy_axis(h_in, h_out, x.device)
    ax = ax.to(x.dtype)
    ay = ay.to(x.dtype)
    left = x.index_select(-1, x0)
    right = x.index_select(-1, x1)
    rows = left + (right - left) * ax
    top = rows.index_select(-2, y0)
    bottom = rows.index_select(-2, y1)
    return top + (bottom - top) * ay.unsqueeze(-1)


def resize_bl2(x: torch.Tensor, size: Size) -> torch.Tensor:
    """TF2 bilinear resize (half-pixel centres, no antialias), design 3.2. ``x`` is ``[B,C,H,W]``."""
    if tuple(x.shape[-2:]) == tuple(size):
        return x
    return F.interpolate(x, size=tuple(size), mode="bilinear", align_corners=False, antialias=False)


def resize_nn1(x: torch.Tensor, size: Size) -> torch.Tensor:
    """Legacy TF1 / OpenCV nearest resize, ``src = min(floor(k * n_in / n_out), n_in - 1)``, design 3.3.

    Works for float and integer tensors of shape ``[..., H, W]``.
    """
    return _gather_nearest(x, size, half_pixel=False)


def resize_nn2(x: torch.Tensor, size: Size) -> torch.Tensor:
    """TF2 nearest resize (half-pixel), ``src = min(floor((k + 0.5) * n_in / n_out), n_in - 1)``, design 3.4.

    Works for float and integer tensors of shape ``[..., H, W]``.
    """
    return _gather_nearest(x, size, half_pixel=True)


def _nearest_index(n_in: int, n_out: int, half_pixel: bool, device: torch.device) -> torch.Tensor:
    k = torch.arange(n_out, dtype=torch.float64)
    if half_pixel:
        k = k + 0.5
    idx = torch.floor(k * (n_in / n_out)).long().clamp_(max=n_in - 1)
    return idx.to(device)


def _gather_nearest(x: torch.Tensor, size: Size, half_pixel: bool) -> torch.Tensor:
    h_in, w_in = x.shape[-2:]
    h_out, w_out = size
    if (h_in, w_in) == (h_out, w_out):
        return x
    if h_out % h_in == 0 and w_out % w_in == 0:
        # Integer upsampling factor: both rules reduce to pixel replication.
        return x.repeat_interleave(h_out // h_in, dim=-2).repeat_interleave(w_out // w_in, dim=-1)
    iy = _nearest_index(h_in, h_out, half_pixel, x.device)
    ix = _nearest_index(w_in, w_out, half_pixel, x.device)
    return x.index_select(-2, iy).index_select(-1, ix)
