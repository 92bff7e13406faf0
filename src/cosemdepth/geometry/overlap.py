"""How much of the current view another camera of the same intrinsics also sees, for distant points (rotation only).

A motion ``(q, t)`` maps current-camera coordinates into the other camera's, ``X_ref = R(q) X_cur + t`` (the models'
convention, :mod:`cosemdepth.geometry.motion`). For points far away the translation does not matter: the current
pixel with ray ``x~`` is seen by the other camera where ``R x~`` projects, if that lies in front of it and inside its
image.
"""

from __future__ import annotations

import torch

from .rotation import quaternion_to_matrix


def view_overlap(
    rot: torch.Tensor, intrinsics: torch.Tensor, height: int, width: int, samples: int = 16
) -> torch.Tensor:
    """The fraction of the current view whose distant points the other camera sees.

    Measured on a ``samples x samples`` grid of points evenly spread over the image (the centres of equal cells of
    the ``height x width`` image); a point counts when its ray, rotated into the other camera, is in front of it and
    projects inside its image (``0 <= u <= W``, ``0 <= v <= H``, pixel edges; continuous coordinates).

    Args:
        rot: ``[B, 4]`` unit quaternion (w, x, y, z): the rotation of the motion other -> current (``X_ref = R
            X_cur + t``).
        intrinsics: ``[B, 4]`` (fx, fy, cx, cy) of the ``height x width`` image, shared by both cameras.
        height, width: image size in pixels.
        samples: grid points per side.
    Returns:
        ``[B]`` in ``[0, 1]``: 1 for no rotation, 0 when the other camera looks the other way.
    """
    dtype = torch.float64
    intr = intrinsics.to(dtype)
    fx, fy, cx, cy = (intr[:, k].view(-1, 1, 1) for k in range(4))
    steps = (torch.arange(samples, device=rot.device, dtype=dtype) + 0.5) / samples
    v, u = torch.meshgrid(steps * height, steps * width, indexing="ij")  # [S, S] continuous pixel coordinates
    rays = torch.stack([(u - cx) / fx, (v - cy) / fy, torch.ones_like(u - cx)], dim=1)  # [B, 3, S, S]
    r = torch.einsum("bij,bjhw->bihw", quaternion_to_matrix(rot.to(dtype)), rays)
    z = r[:, 2]
    front = z > 0
    zs = torch.where(front, z, torch.ones_like(z))
    pu = fx * r[:, 0] / zs + cx
    pv = fy * r[:, 1] / zs + cy
    seen = front & (pu >= 0) & (pu <= width) & (pv >= 0) & (pv <= height)
    return seen.to(dtype).mean(dim=(1, 2)).to(torch.float32)


__all__ = ["view_overlap"]
