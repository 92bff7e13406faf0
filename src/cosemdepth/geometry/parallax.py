"""Parallax geometry of M4Depth (design 2.3-2.4).

For a current-frame pixel with normalised ray ``x~`` and the relative motion ``(R, t)`` (``X_prev = R X_curr + t``):

* ``r = R x~``, ``alpha = r_z``, ``p_rot = (fx r_x / alpha, fy r_y / alpha)``: the image in the previous frame (centred
  coordinates) of the point at infinity on the ray;
* ``delta = (fx t_x - t_z p_rot_x, fy t_y - t_z p_rot_y)``: direction and scale of the epipolar displacement;
* parallax ``rho = |delta| / (alpha d + t_z)`` for a point at depth ``d``; its projection in the previous frame is
  ``p_rot + rho * delta / |delta|``.

Degenerate cases (none guarded in the original) are guarded with tiny epsilons that leave normal inputs unchanged:
``|delta| = 0`` (focus of expansion, zero translation), ``alpha <= 0``, a previous depth ``d' <= t_z`` and non-positive
parallax. Every function returns finite values for finite inputs.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .camera import centred_coordinates, pixel_rays
from .rotation import quaternion_to_matrix

#: Smallest |delta| (pixel-metres) used as a divisor. |delta| ~ f |t| is ~1..1000 in practice.
DELTA_EPS = 1e-6
#: Smallest ray z-component after rotation (rays rotated to or behind the image plane are degenerate).
ALPHA_EPS = 1e-6
#: Smallest depth in the previous frame (d' - t_z) and smallest parallax used as divisors.
DEPTH_EPS = 1e-6
PARALLAX_EPS = 1e-6


@dataclass
class EpipolarGeometry:
    """Per-pixel epipolar quantities of one level.

    Attributes:
        p_rot: ``[B, 2, H, W]`` derotated position (centred coordinates, x then y) in the previous frame.
        alpha: ``[B, 1, H, W]`` z-component of the rotated ray.
        delta: ``[B, 2, H, W]`` epipolar displacement ``(fx t_x - t_z p_rot_x, fy t_y - t_z p_rot_y)``.
        delta_norm: ``[B, 1, H, W]`` its Euclidean norm (guarded, >= ``DELTA_EPS``).
        t_z: ``[B, 1, 1, 1]`` forward translation.
        intrinsics: ``[B, 4]`` of this level.
    """

    p_rot: torch.Tensor
    alpha: torch.Tensor
    delta: torch.Tensor
    delta_norm: torch.Tensor
    t_z: torch.Tensor
    intrinsics: torch.Tensor

    @property
    def direction(self) -> torch.Tensor:
        """``[B, 2, H, W]`` unit epipolar direction ``delta / |delta|``."""
        return self.delta / self.delta_norm


def epipolar_geometry(
    height: int,
    width: int,
    rot: torch.Tensor,
    trans: torch.Tensor,
    intrinsics: torch.Tensor,
    guard: bool = True,
    hypot: bool = False,
) -> EpipolarGeometry:
    """Epipolar quantities of every pixel of a ``height x width`` grid (design 2.3).

    Args:
        rot: ``[B, 4]`` quaternion (w, x, y, z) or ``[B, 3, 3]`` rotation matrix.
        trans: ``[B, 3]`` translation in metres.
        intrinsics: ``[B, 4]`` of this grid.
        guard: clamp the degenerate divisors (default); ``False`` reproduces the unguarded original.
        hypot: compute ``|delta|`` with ``torch.hypot`` (faster than a norm over a size-2 axis; equal up to the last
            bit). Used by the fast inference path.
    """
    R = quaternion_to_matrix(rot) if rot.shape[-1] == 4 else rot
    rays = pixel_rays(height, width, intrinsics)  # [B,3,H,W]
    r = torch.einsum("bij,bjhw->bihw", R, rays)
    alpha = r[:, 2:3]
    if guard:
        alpha = alpha.clamp_min(ALPHA_EPS)
    f = intrinsics[:, 0:2].view(-1, 2, 1, 1)
    p_rot = f * r[:, 0:2] / alpha
    t_xy = trans[:, 0:2].view(-1, 2, 1, 1)
    t_z = trans[:, 2].view(-1, 1, 1, 1)
    delta = f * t_xy - t_z * p_rot
    if hypot:
        norm = torch.hypot(delta[:, 0:1], delta[:, 1:2])
    else:
        norm = torch.linalg.vector_norm(delta, dim=1, keepdim=True)
    if guard:
        norm = norm.clamp_min(DELTA_EPS)
    return EpipolarGeometry(p_rot, alpha, delta, norm, t_z, intrinsics)


def depth_to_parallax(depth: torch.Tensor, geom: EpipolarGeometry, guard: bool = True) -> torch.Tensor:
    """``rho = |delta| / (alpha d + t_z)`` (``alpha d + t_z`` is the depth in the previous frame).

    Args:
        depth: ``[B, 1, H, W]`` metres.
    Returns:
        ``[B, 1, H, W]`` parallax in pixels of this grid.
    """
    denom = geom.alpha * depth + geom.t_z
    if guard:
        denom = denom.clamp_min(DEPTH_EPS)
    return geom.delta_norm / denom


def parallax_to_depth(parallax: torch.Tensor, geom: EpipolarGeometry, guard: bool = True) -> torch.Tensor:
    """``d = (|delta| / rho - t_z) / alpha``. Can be negative near the focus of expansion, as in the original.

    Args:
        parallax: ``[B, 1, H, W]`` pixels of this grid.
    Returns:
        ``[B, 1, H, W]`` metres.
    """
    if guard:
        parallax = parallax.clamp_min(PARALLAX_EPS)
    return (geom.delta_norm / parallax - geom.t_z) / geom.alpha


def prev_depth_to_parallax(
    prev_depth: torch.Tensor, trans: torch.Tensor, intrinsics: torch.Tensor, guard: bool = True
) -> torch.Tensor:
    """Parallax, with respect to the current frame, of the points seen by the previous frame (design 2.4).

    Evaluated on the previous frame's own grid: ``rho' = |(fx t_x - t_z u', fy t_y - t_z v')| / |d' - t_z|``.
    The caller applies stop-gradient.

    The original computes the norm of the vector divided by ``d' - t_z``, hence the absolute value of the denominator:
    a previous depth below ``t_z`` (e.g. the negative depths an untrained network gives near the focus of expansion)
    gives a positive parallax, not a negative one (design 2.4: the geometry alone gives ``d' - t_z``; the
    reference outputs of the original confirm the absolute value).

    Args:
        prev_depth: ``[B, 1, H, W]`` depth ``d'`` of the previous frame (metres).
        trans: ``[B, 3]`` current relative translation.
        intrinsics: ``[B, 4]`` of this grid.
        guard: keep ``|d' - t_z|`` above a small positive value (a previous depth equal to ``t_z``).
    Returns:
        ``[B, 1, H, W]``.
    """
    h, w = prev_depth.shape[-2:]
    u, v = centred_coordinates(h, w, intrinsics)
    t_x = trans[:, 0].view(-1, 1, 1, 1)
    t_y = trans[:, 1].view(-1, 1, 1, 1)
    t_z = trans[:, 2].view(-1, 1, 1, 1)
    fx = intrinsics[:, 0].view(-1, 1, 1, 1)
    fy = intrinsics[:, 1].view(-1, 1, 1, 1)
    num = torch.sqrt((fx * t_x - t_z * u) ** 2 + (fy * t_y - t_z * v) ** 2)
    denom = torch.abs(prev_depth - t_z)
    if guard:
        denom = denom.clamp_min(DEPTH_EPS)
    return num / denom


def candidate_flows(parallax: torch.Tensor, geom: EpipolarGeometry) -> torch.Tensor:
    """Flows to the previous frame for parallax hypotheses (design 2.4): ``p_rot + rho * delta/|delta| - (u, v)``.

    Args:
        parallax: ``[B, K, H, W]`` K hypotheses per pixel.
    Returns:
        ``[B, K, 2, H, W]`` flows (x then y) in pixels of this grid.
    """
    h, w = parallax.shape[-2:]
    u, v = centred_coordinates(h, w, geom.intrinsics)
    uv = torch.cat([u, v], dim=1)  # [B,2,H,W]
    q = geom.p_rot.unsqueeze(1) + parallax.unsqueeze(2) * geom.direction.unsqueeze(1)
    return q - uv.unsqueeze(1)


def candidate_sample_points(parallax: torch.Tensor, geom: EpipolarGeometry) -> torch.Tensor:
    """Where the hypotheses land in the previous frame, as (column, row) pixel indices.

    ``j + flow_x = q_x + c_x - 0.5`` and ``i + flow_y = q_y + c_y - 0.5``, with ``q = p_rot + rho delta/|delta|``.

    Args:
        parallax: ``[B, K, H, W]``.
    Returns:
        ``[B, K, 2, H, W]`` (x = column, y = row).
    """
    c = geom.intrinsics[:, 2:4].view(-1, 1, 2, 1, 1)
    q = geom.p_rot.unsqueeze(1) + parallax.unsqueeze(2) * geom.direction.unsqueeze(1)
    return q + (c - 0.5)
