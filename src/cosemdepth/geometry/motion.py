"""Relative camera motions: composition, identity, size.

A motion ``(q, t)`` maps current-camera coordinates into the reference camera's, ``X_ref = R(q) X_cur + t``: it is the
pose of the current camera in the reference camera's frame, the convention of the models' inputs (camera axes x right,
y down, z forward).
"""

from __future__ import annotations

import torch

from .rotation import quaternion_to_matrix


def quaternion_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``a * b`` of quaternions ``[..., 4]`` (w, x, y, z): the rotation ``R(a) R(b)``."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


def compose_motion(
    rot_a: torch.Tensor, trans_a: torch.Tensor, rot_b: torch.Tensor, trans_b: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The motion reference -> current from reference -> previous (``a``) and previous -> current (``b``).

    With ``X_ref = R_a X_prev + t_a`` and ``X_prev = R_b X_cur + t_b``: ``X_ref = R_a R_b X_cur + R_a t_b + t_a``.

    Args:
        rot_a, rot_b: ``[B, 4]`` unit quaternions (w, x, y, z); trans_a, trans_b: ``[B, 3]`` metres.
    Returns:
        ``(rot [B, 4], trans [B, 3])``, the quaternion re-normalised.
    """
    q = quaternion_multiply(rot_a, rot_b)
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    t = torch.einsum("bij,bj->bi", quaternion_to_matrix(rot_a), trans_b) + trans_a
    return q, t


def identity_motion(batch: int, device=None, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """``(rot [B, 4], trans [B, 3])`` of no motion."""
    rot = torch.zeros(batch, 4, device=device, dtype=dtype)
    rot[:, 0] = 1
    return rot, torch.zeros(batch, 3, device=device, dtype=dtype)


def baseline(trans: torch.Tensor) -> torch.Tensor:
    """``[B]`` length ``|t|`` (metres) of the translations ``[B, 3]``."""
    return torch.linalg.vector_norm(trans, dim=-1)


__all__ = ["baseline", "compose_motion", "identity_motion", "quaternion_multiply"]
