"""previous_points: where a current pixel's point was in the previous frame (design 2.6)."""

import math

import numpy as np
import torch

from cosemdepth.geometry.correspondence import previous_points_from_motion
from cosemdepth.geometry.rotation import quaternion_to_matrix

IDENTITY = torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=torch.float64)


def grid(h, w):
    rows, cols = torch.meshgrid(
        torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij"
    )
    return cols, rows


def test_a_sideways_step_shifts_by_focal_times_baseline_over_depth():
    # camera 1 m to the right of the previous one (X_prev = X_cur + t, t_x = 1): f t_x / d = 4 * 1 / 2 = 2 pixels
    h, w = 3, 6
    K = torch.tensor([[4.0, 4.0, w / 2, h / 2]], dtype=torch.float64)
    depth = torch.full((1, 1, h, w), 2.0, dtype=torch.float64)
    points, ok = previous_points_from_motion(depth, IDENTITY, torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64), K)
    cols, rows = grid(h, w)
    inside = cols + 2 <= w - 0.5
    assert torch.equal(ok[0, 0], inside)
    assert torch.equal(points[0, 0][inside], (cols + 2)[inside]) and torch.equal(points[0, 1][inside], rows[inside])
    assert torch.equal(points[:, :, ~inside], torch.zeros_like(points[:, :, ~inside]))  # invalid: 0, safe to sample


def test_rotation_and_translation_agree_with_direct_projection():
    h, w = 5, 7
    K = torch.tensor([[6.0, 5.0, 3.3, 2.6]], dtype=torch.float64)
    angle = 0.05
    q = torch.tensor(
        [[math.cos(angle / 2), 0.3 * math.sin(angle / 2), math.sqrt(1 - 0.09) * math.sin(angle / 2), 0]],
        dtype=torch.float64,
    )
    t = torch.tensor([[0.2, -0.1, 0.8]], dtype=torch.float64)
    g = np.random.default_rng(0)
    depth = torch.from_numpy(g.uniform(3.0, 30.0, (1, 1, h, w)))
    points, ok = previous_points_from_motion(depth, q, t, K)
    # independent: back-project with numpy, move, project
    R = quaternion_to_matrix(q)[0].numpy()
    fx, fy, cx, cy = K[0].numpy()
    cols, rows = (a.numpy() for a in grid(h, w))
    X = np.stack([(cols + 0.5 - cx) / fx, (rows + 0.5 - cy) / fy, np.ones_like(cols)]) * depth[0, 0].numpy()
    Xp = np.einsum("ij,jhw->ihw", R, X) + t[0].numpy()[:, None, None]
    col = fx * Xp[0] / Xp[2] + cx - 0.5
    row = fy * Xp[1] / Xp[2] + cy - 0.5
    inside = (col >= -0.5) & (col <= w - 0.5) & (row >= -0.5) & (row <= h - 0.5)
    assert np.array_equal(ok[0, 0].numpy(), inside) and inside.sum() > h * w // 2
    np.testing.assert_allclose(points[0, 0].numpy()[inside], col[inside], atol=1e-9)
    np.testing.assert_allclose(points[0, 1].numpy()[inside], row[inside], atol=1e-9)


def test_infinite_depth_follows_the_rotation_alone_and_bad_depths_are_invalid():
    h, w = 2, 4
    K = torch.tensor([[2.0, 2.0, 2.0, 1.0]], dtype=torch.float64)
    t = torch.tensor([[0.5, 0.0, 1.0]], dtype=torch.float64)
    depth = torch.tensor([[[[math.inf, math.nan, 0.0, -3.0], [math.inf, 5.0, math.inf, 1e9]]]], dtype=torch.float64)
    points, ok = previous_points_from_motion(depth, IDENTITY, t, K)
    cols, rows = grid(h, w)
    far = torch.isinf(depth[0, 0])
    assert torch.equal(points[0, 0][far], cols[far]) and torch.equal(points[0, 1][far], rows[far])  # no rotation
    assert ok[0, 0].tolist() == [[True, False, False, False], [True, True, True, True]]


def test_a_point_behind_the_previous_camera_is_invalid():
    # the previous camera is 5 m in front of the current one: a point 2 m ahead is behind it (alpha d + t_z < 0), one
    # 30 m ahead is 25 m in front of it
    K = torch.tensor([[2.0, 2.0, 1.0, 1.0]], dtype=torch.float64)
    depth = torch.tensor([[[[2.0, 30.0], [2.0, 30.0]]]], dtype=torch.float64)
    _, ok = previous_points_from_motion(depth, IDENTITY, torch.tensor([[0.0, 0.0, -5.0]], dtype=torch.float64), K)
    assert ok[0, 0].tolist() == [[False, True], [False, True]]
