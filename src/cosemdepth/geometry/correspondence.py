"""Where a current pixel's 3D point appears in the previous frame, given its depth (design 2.6).

With the epipolar quantities of design 2.3 (``p_rot``, ``alpha``, ``delta``, ``t_z``), the point at depth ``d`` on the
ray of a current pixel has depth ``alpha d + t_z`` in the previous camera and projects, in centred coordinates, to

    q = p_rot + delta / (alpha d + t_z)

(the correspondence of design 2.4, ``p_rot + rho delta / |delta|`` with ``rho = |delta| / (alpha d + t_z)``, written
without the division by ``|delta|``: exact at the focus of expansion and without translation too). An infinite depth
gives the point at infinity, ``q = p_rot``: the sky follows the rotation alone.
"""

from __future__ import annotations

from typing import Optional

import torch

from .parallax import EpipolarGeometry, epipolar_geometry


def previous_points(depth: Optional[torch.Tensor], geom: EpipolarGeometry) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel positions in the previous frame of the current pixels' points at ``depth``, and where they are usable.

    Args:
        depth: ``[B, 1, H, W]`` z-depth in the current camera (metres; ``inf`` allowed), or None: every point at
            infinity (the rotation alone).
        geom: :func:`~cosemdepth.geometry.parallax.epipolar_geometry` of the ``H x W`` grid, computed with
            ``guard=False`` so that ``alpha`` is the true ray component.
    Returns:
        ``(points [B, 2, H, W], ok [B, 1, H, W] bool)``: column and row (pixel centres at integers) in the previous
        frame, and ``ok`` where the depth is positive (not NaN), the ray points forward in the previous camera
        (``alpha > 0``), the point lies in front of it (``alpha d + t_z > 0``) and lands inside the previous image
        (``[-0.5, W - 0.5] x [-0.5, H - 0.5]``, the area its pixels cover). Positions where ``ok`` is False are set
        to 0 (finite, safe to sample).
    """
    h, w = geom.alpha.shape[-2:]
    alpha = geom.alpha
    if depth is None:
        q = geom.p_rot
        ok = alpha > 0
    else:
        denom = alpha * depth + geom.t_z
        q = geom.p_rot + geom.delta / denom
        ok = (alpha > 0) & (depth > 0) & (denom > 0)
    points = q + (geom.intrinsics[:, 2:4].view(-1, 2, 1, 1) - 0.5)
    x, y = points[:, 0:1], points[:, 1:2]
    ok = ok & torch.isfinite(x) & torch.isfinite(y) & (x >= -0.5) & (x <= w - 0.5) & (y >= -0.5) & (y <= h - 0.5)
    return torch.where(ok, points, torch.zeros_like(points)), ok


def previous_points_from_motion(
    depth: torch.Tensor, rot: torch.Tensor, trans: torch.Tensor, intrinsics: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`previous_points` for a motion and a camera.

    Args:
        depth: ``[B, 1, H, W]`` metres (see :func:`previous_points`).
        rot: ``[B, 4]`` quaternion (w, x, y, z) or ``[B, 3, 3]``; trans: ``[B, 3]`` metres: the motion previous ->
            current (``X_prev = R X_cur + t``).
        intrinsics: ``[B, 4]`` (fx, fy, cx, cy) of the ``H x W`` grid.
    Returns:
        ``(points [B, 2, H, W], ok [B, 1, H, W])``.
    """
    h, w = depth.shape[-2:]
    return previous_points(depth, epipolar_geometry(h, w, rot, trans, intrinsics, guard=False))


__all__ = ["previous_points", "previous_points_from_motion"]
