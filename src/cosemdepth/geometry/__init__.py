"""Camera geometry of M4Depth (design section 2): rotations, intrinsics, parallax <-> depth, flows and warping.

All functions are pure and work on batched tensors (NCHW for maps). Intrinsics are ``[B, 4] = (fx, fy, cx, cy)``
in pixels; motion is ``rot [B, 4]`` (unit quaternion w, x, y, z) and ``trans [B, 3]`` in metres, in camera axes
(x right, y down, z forward), such that ``X_prev = R(rot) @ X_curr + trans`` (design 2.2).
"""

from .camera import level_intrinsics, pixel_grid, pixel_rays
from .parallax import (
    EpipolarGeometry,
    candidate_flows,
    candidate_sample_points,
    depth_to_parallax,
    epipolar_geometry,
    parallax_to_depth,
    prev_depth_to_parallax,
)
from .rotation import quaternion_to_matrix, small_angle_to_matrix
from .warp import sample_bilinear, warp

__all__ = [
    "EpipolarGeometry",
    "candidate_flows",
    "candidate_sample_points",
    "depth_to_parallax",
    "epipolar_geometry",
    "level_intrinsics",
    "parallax_to_depth",
    "pixel_grid",
    "pixel_rays",
    "prev_depth_to_parallax",
    "quaternion_to_matrix",
    "small_angle_to_matrix",
    "sample_bilinear",
    "warp",
]
