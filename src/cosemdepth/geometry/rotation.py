"""Rotation representations (design 2.2)."""

from __future__ import annotations

import torch


def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Active rotation matrix of a unit quaternion, scalar first.

    Args:
        q: ``[..., 4]`` quaternions ``(w, x, y, z)``. They are used as given (not re-normalised), like the original.
    Returns:
        ``[..., 3, 3]`` rotation matrices.
    """
    w, x, y, z = q.unbind(-1)
    r00 = 1 - 2 * (y * y + z * z)
    r01 = 2 * (x * y - w * z)
    r02 = 2 * (x * z + w * y)
    r10 = 2 * (x * y + w * z)
    r11 = 1 - 2 * (x * x + z * z)
    r12 = 2 * (y * z - w * x)
    r20 = 2 * (x * z - w * y)
    r21 = 2 * (y * z + w * x)
    r22 = 1 - 2 * (x * x + y * y)
    return torch.stack([r00, r01, r02, r10, r11, r12, r20, r21, r22], dim=-1).unflatten(-1, (3, 3))


def small_angle_to_matrix(v: torch.Tensor) -> torch.Tensor:
    """First-order rotation of a small-angle vector ``(a, b, c)``: ``[[1, -c, b], [c, 1, -a], [-b, a, 1]]``.

    Args:
        v: ``[..., 3]``.
    Returns:
        ``[..., 3, 3]``.
    """
    a, b, c = v.unbind(-1)
    one = torch.ones_like(a)
    return torch.stack([one, -c, b, c, one, -a, -b, a, one], dim=-1).unflatten(-1, (3, 3))
