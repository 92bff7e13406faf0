"""geometry.overlap.view_overlap: fractions worked out by hand for turns about the camera's axes, and a dense count
of every pixel for an arbitrary rotation."""

from __future__ import annotations

import math

import pytest
import torch

from cosemdepth.geometry.overlap import view_overlap
from cosemdepth.geometry.rotation import quaternion_to_matrix

# 128 x 128 px, f = 64 px, centred: a 90 degree field of view (45 degrees either side of the optical axis)
K = torch.tensor([[64.0, 64.0, 64.0, 64.0]])


def turn(axis: int, deg: float) -> torch.Tensor:
    h = math.radians(deg) / 2
    q = [math.cos(h), 0.0, 0.0, 0.0]
    q[1 + axis] = math.sin(h)
    return torch.tensor([q])


def test_no_turn_sees_everything_and_turning_away_sees_nothing():
    assert float(view_overlap(turn(1, 0.0), K, 128, 128)) == 1.0
    assert float(view_overlap(turn(1, 180.0), K, 128, 128)) == 0.0  # looking backwards
    assert float(view_overlap(turn(0, 100.0), K, 128, 128)) == 0.0  # beyond the field of view, about x


@pytest.mark.parametrize("axis", [0, 1])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_turn_by_half_the_field_of_view(axis, sign):
    """Yaw (about y) by 45 degrees, in normalised coordinates ``x, y`` in [-1, 1]: the ray (x, y, 1) turns into
    ``((x + 1) / sqrt 2, y, (1 - x) / sqrt 2)``; it stays inside for ``x <= 0`` and ``|y| <= (1 - x) / sqrt 2``: an
    area of ``4 - 1.5 sqrt 2`` of 4, i.e. ``1 - 3 sqrt(2) / 8`` of the view (pitch: the same with x and y swapped)."""
    got = float(view_overlap(turn(axis, sign * 45.0), K, 128, 128, samples=64))
    assert got == pytest.approx(1 - 3 * math.sqrt(2) / 8, abs=2 / 64)  # the grid's sampling error: one column


def test_a_roll_keeps_the_octagon():
    # a roll about the optical axis loses the corners: at 45 degrees the view keeps the octagon common to the square
    # and the square turned, 2 (sqrt 2 - 1) of it
    got = float(view_overlap(turn(2, 45.0), K, 128, 128, samples=64))
    assert got == pytest.approx(2 * (math.sqrt(2) - 1), abs=2 / 64)


def test_matches_a_dense_count_for_an_arbitrary_rotation_and_batches():
    q = torch.nn.functional.normalize(torch.tensor([[0.97, 0.1, -0.2, 0.08], [1.0, 0.0, 0.0, 0.0]]), dim=-1)
    k = torch.tensor([[50.0, 55.0, 40.0, 30.0], [50.0, 55.0, 40.0, 30.0]])
    h, w = 60, 80
    got = view_overlap(q, k, h, w, samples=40)
    # every pixel centre of the image, by hand: rotate its ray, project, test
    R = quaternion_to_matrix(q[0].double())
    v, u = torch.meshgrid(torch.arange(h).double() + 0.5, torch.arange(w).double() + 0.5, indexing="ij")
    fx, fy, cx, cy = k[0].double().tolist()
    rays = torch.stack([(u - cx) / fx, (v - cy) / fy, torch.ones_like(u)], -1) @ R.T
    pu, pv = fx * rays[..., 0] / rays[..., 2] + cx, fy * rays[..., 1] / rays[..., 2] + cy
    dense = ((rays[..., 2] > 0) & (pu >= 0) & (pu <= w) & (pv >= 0) & (pv <= h)).double().mean()
    assert 0.3 < float(dense) < 0.9  # a partial overlap
    assert float(got[0]) == pytest.approx(float(dense), abs=0.03)  # the grid's sampling error
    assert float(got[1]) == 1.0
