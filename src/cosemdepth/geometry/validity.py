"""Which pixels of a depth map estimated from parallax can be trusted: the conditioning of parallax -> depth.

M4Depth predicts the parallax ``rho`` and converts it with ``d = (|delta| / rho - t_z) / alpha`` (design 3.4). In
inverse depth ``w = 1 / d = alpha rho / (|delta| - t_z rho)``, a parallax error ``e`` (pixels) moves ``w`` by
``eta * e`` with, using the parallax that the depth implies (``rho = |delta| / (alpha d + t_z)``),

    eta = dw / drho = (alpha d + t_z)^2 / (alpha d^2 |delta|)        [1 / (metre pixel)]

``eta`` grows without bound at the focus of expansion (``|delta| -> 0``) and for a vanishing translation (``|delta|``
is proportional to ``|t|``: hover, yaw in place), and like ``1 / d^2`` where the two terms of the conversion nearly
cancel (``alpha d`` small against ``t_z``: the too-near depths of the focus of expansion); far points are well
conditioned in inverse depth (``eta -> alpha / |delta|``), so the sky stays valid. The error is measured in inverse
depth because that is what parallax determines and what a consumer avoiding obstacles needs: how near a point is.
A pixel is valid when its depth is finite and positive and ``eta`` is at most a threshold (calibrated on SynthAir,
docs/motion.md).
"""

from __future__ import annotations

import torch

from .parallax import epipolar_geometry

#: Default largest ``eta`` (inverse-depth error in 1/m per pixel of parallax error, pixels of the network input) of a
#: valid pixel; calibrated on held-out SynthAir flights with the shipped weights (``benchmarks/motion_robustness.py``).
MAX_CONDITIONING = 0.11


def parallax_conditioning(
    depth: torch.Tensor, rot: torch.Tensor, trans: torch.Tensor, intrinsics: torch.Tensor
) -> torch.Tensor:
    """``eta = (alpha d + t_z)^2 / (alpha d^2 |delta|)`` of every pixel (see the module docstring).

    Args:
        depth: ``[B, 1, H, W]`` metres (z-depth in the current frame).
        rot: ``[B, 4]`` quaternion (w, x, y, z); trans: ``[B, 3]`` metres: the motion used to estimate ``depth``
            (``X_ref = R X_cur + t``).
        intrinsics: ``[B, 4]`` (fx, fy, cx, cy) of the ``H x W`` grid.
    Returns:
        ``[B, 1, H, W]``, +inf where the conversion is undefined (``|delta| = 0``, ``alpha d <= 0``) or the depth is
        not finite.
    """
    h, w = depth.shape[-2:]
    geom = epipolar_geometry(h, w, rot.to(depth.dtype), trans.to(depth.dtype), intrinsics.to(depth.dtype), guard=False)
    ad = geom.alpha * depth
    eta = (ad + geom.t_z) ** 2 / (ad * depth * geom.delta_norm)
    bad = ~torch.isfinite(eta) | (ad <= 0) | (geom.delta_norm <= 0) | ~torch.isfinite(depth)
    return eta.masked_fill(bad, float("inf"))


def depth_validity(
    depth: torch.Tensor,
    rot: torch.Tensor,
    trans: torch.Tensor,
    intrinsics: torch.Tensor,
    reset: torch.Tensor | None = None,
    max_conditioning: float = MAX_CONDITIONING,
) -> torch.Tensor:
    """``[B, 1, H, W]`` bool: finite, positive depth whose parallax -> depth conversion is well conditioned
    (``eta <= max_conditioning``); every pixel of a sample that ``reset`` (``[B]`` bool) is invalid."""
    valid = torch.isfinite(depth) & (depth > 0)
    valid &= parallax_conditioning(depth, rot, trans, intrinsics) <= max_conditioning
    if reset is not None:
        valid &= ~reset.view(-1, 1, 1, 1).to(valid.device)
    return valid


__all__ = ["MAX_CONDITIONING", "depth_validity", "parallax_conditioning"]
