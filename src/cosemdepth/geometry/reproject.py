"""A depth map carried from a reference camera into the current view (frames that are held, not estimated).

The current pixel ``p`` with ray ``x~`` sees the point ``X_cur = z x~``, which the reference camera sees at
``X_ref = R X_cur + t`` (``X_ref = R X_cur + t`` is the models' motion convention). ``z`` is unknown, so it is found by
fixed-point iteration: start from the point at infinity (``p_ref`` = the rotated ray's projection), read the
reference depth there, back-project it, move it into the current camera, take its z, project again. The reference
depth is read at the nearest pixel, so depth edges are not blended. For the small translations of a held frame
(below the streaming policy's baseline) one or two iterations converge.
"""

from __future__ import annotations

import torch

from .camera import pixel_rays
from .rotation import quaternion_to_matrix


def _project(X: torch.Tensor, intrinsics: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Column and row (float pixel indices, centres at integers) of points ``X [B, 3, H, W]``."""
    fx, fy, cx, cy = (intrinsics[:, k].view(-1, 1, 1) for k in range(4))
    z = X[:, 2]
    return fx * X[:, 0] / z + cx - 0.5, fy * X[:, 1] / z + cy - 0.5


def _ray(col: torch.Tensor, row: torch.Tensor, intrinsics: torch.Tensor) -> torch.Tensor:
    """Normalised rays ``[B, 3, H, W]`` (z = 1) through pixel positions ``col, row`` ``[B, H, W]``."""
    fx, fy, cx, cy = (intrinsics[:, k].view(-1, 1, 1) for k in range(4))
    x = (col + 0.5 - cx) / fx
    y = (row + 0.5 - cy) / fy
    return torch.stack([x, y, torch.ones_like(x)], dim=1)


def _gather_nearest(maps: torch.Tensor, col: torch.Tensor, row: torch.Tensor):
    """``maps [B, C, H, W]`` at the nearest pixels of ``col, row`` ``[B, H, W]``; ``(values [B, C, H, W], inside
    [B, H, W], col_i, row_i)``."""
    b, c, h, w = maps.shape
    ci = torch.round(col)
    ri = torch.round(row)
    inside = (ci >= 0) & (ci <= w - 1) & (ri >= 0) & (ri <= h - 1) & torch.isfinite(col) & torch.isfinite(row)
    ci = torch.where(inside, ci, torch.zeros_like(ci)).long()
    ri = torch.where(inside, ri, torch.zeros_like(ri)).long()
    index = (ri * w + ci).view(b, 1, -1).expand(b, c, -1)
    values = maps.reshape(b, c, -1).gather(2, index).view(b, c, *col.shape[1:])
    return values, inside, ci.to(col.dtype), ri.to(row.dtype)


def carry_depth(
    depth: torch.Tensor,
    valid: torch.Tensor,
    rot: torch.Tensor,
    trans: torch.Tensor,
    intrinsics: torch.Tensor,
    iterations: int = 2,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The reference camera's depth seen from the current camera (same intrinsics, same grid).

    Args:
        depth: ``[B, 1, H, W]`` z-depth of the reference frame (metres); valid: ``[B, 1, H, W]`` bool, its validity.
        rot: ``[B, 4]`` quaternion (w, x, y, z); trans: ``[B, 3]`` metres: the motion reference -> current
            (``X_ref = R X_cur + t``, the pose of the current camera in the reference one).
        intrinsics: ``[B, 4]`` (fx, fy, cx, cy) of the ``H x W`` grid.
        iterations: fixed-point iterations after the point-at-infinity start.
    Returns:
        ``(depth [B, 1, H, W], valid [B, 1, H, W])`` in the current view: a pixel is valid when it lands inside the
        reference image on a valid pixel and the carried point is in front of both cameras; the depth is the carried
        value wherever the pixel lands inside the reference image (valid or not), 0 elsewhere.
    """
    h, w = depth.shape[-2:]
    dtype = depth.dtype
    intr = intrinsics.to(dtype)
    R = quaternion_to_matrix(rot.to(dtype))
    t = trans.to(dtype).view(-1, 3, 1, 1)
    r = torch.einsum("bij,bjhw->bihw", R, pixel_rays(h, w, intr))  # current rays in the reference camera
    X_ref = r  # the point at infinity on each ray
    for k in range(iterations + 1):
        col, row = _project(X_ref, intr)
        d_ref, inside, ci, ri = _gather_nearest(torch.cat([depth, valid.to(dtype)], dim=1), col, row)
        seen = d_ref[:, 0:1] * _ray(ci, ri, intr)  # the point the reference pixel sees
        X_cur = torch.einsum("bji,bjhw->bihw", R, seen - t)  # R^T (X_ref - t)
        z = X_cur[:, 2:3]
        if k < iterations:
            X_ref = z.clamp_min(1e-6) * r + t
    landed = inside.unsqueeze(1) & torch.isfinite(z)
    ok = landed & (d_ref[:, 1:2] > 0.5) & (X_ref[:, 2:3] > 0) & (z > 0) & (d_ref[:, 0:1] > 0)
    return torch.where(landed, z, torch.zeros_like(z)), ok


__all__ = ["carry_depth"]
