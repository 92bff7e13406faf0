"""Parallax conditioning and validity, motion composition and the held-frame depth carry, on hand-computed cases."""

import math

import torch

from cosemdepth.geometry.motion import baseline, compose_motion, identity_motion, quaternion_multiply
from cosemdepth.geometry.reproject import carry_depth
from cosemdepth.geometry.rotation import quaternion_to_matrix
from cosemdepth.geometry.validity import depth_validity, parallax_conditioning

F64 = torch.float64


def _intr(size, f=None, b=1):
    f = size / 2 if f is None else f
    return torch.tensor([[f, f, size / 2, size / 2]] * b, dtype=F64)


def _quat(axis, angle):
    axis = torch.tensor(axis, dtype=F64)
    axis = axis / axis.norm()
    return torch.cat([torch.tensor([math.cos(angle / 2)], dtype=F64), axis * math.sin(angle / 2)]).view(1, 4)


ID = torch.tensor([[1.0, 0, 0, 0]], dtype=F64)


def test_sideways_translation_conditioning_is_one_over_focal_baseline():
    # t = (t_x, 0, 0), R = I: delta = (f t_x, 0), alpha = 1, t_z = 0 -> eta = d^2 / (d^2 f t_x) = 1 / (f t_x), any depth
    depth = 5.0 + torch.arange(64, dtype=F64).view(1, 1, 8, 8)
    eta = parallax_conditioning(depth, ID, torch.tensor([[1.0, 0, 0]], dtype=F64), _intr(64))
    torch.testing.assert_close(eta, torch.full_like(depth, 1 / 32))
    assert depth_validity(depth, ID, torch.tensor([[1.0, 0, 0]], dtype=F64), _intr(64), max_conditioning=0.05).all()
    # half the baseline: eta = 1 / 16 = 0.0625 > 0.05
    assert not depth_validity(depth, ID, torch.tensor([[0.5, 0, 0]], dtype=F64), _intr(64), max_conditioning=0.05).any()


def test_focus_of_expansion_is_invalid_forward_flight():
    # t = (0, 0, 1), R = I: |delta| = t_z * r (r: pixel distance from the principal point), eta = (d + 1)^2 / (d^2 r)
    size, d = 128, 10.0
    depth = torch.full((1, 1, size, size), d, dtype=F64)
    eta = parallax_conditioning(depth, ID, torch.tensor([[0.0, 0, 1]], dtype=F64), _intr(size))
    j = torch.arange(size, dtype=F64) + 0.5 - size / 2
    r = torch.sqrt(j.view(-1, 1) ** 2 + j.view(1, -1) ** 2)
    torch.testing.assert_close(eta[0, 0], (d + 1) ** 2 / (d**2 * r))
    valid = depth_validity(depth, ID, torch.tensor([[0.0, 0, 1]], dtype=F64), _intr(size), max_conditioning=0.05)
    # valid iff r >= 1.21 / 0.05 = 24.2 px
    torch.testing.assert_close(valid[0, 0], r >= 24.2, rtol=0, atol=0)
    # a too-near estimate at the same pixels is worse conditioned: d = 0.5 -> eta = 2.25 / (0.25 r) = 9 / r
    near = parallax_conditioning(depth * 0.05, ID, torch.tensor([[0.0, 0, 1]], dtype=F64), _intr(size))
    torch.testing.assert_close(near[0, 0], 9 / r)


def test_no_translation_negative_depth_and_reset_are_invalid():
    depth = torch.full((2, 1, 4, 4), 5.0, dtype=F64)
    depth[1, 0, 0, 0] = -1.0
    depth[1, 0, 0, 1] = float("nan")
    intr = _intr(4, b=2)
    assert not depth_validity(depth, ID.repeat(2, 1), torch.zeros(2, 3, dtype=F64), intr).any()  # hover
    t = torch.tensor([[1.0, 0, 0], [1.0, 0, 0]], dtype=F64)
    v = depth_validity(depth, ID.repeat(2, 1), t, intr, max_conditioning=1.0)
    assert v[0].all() and not v[1, 0, 0, 0] and not v[1, 0, 0, 1] and v[1, 0, 1:].all()
    v = depth_validity(depth, ID.repeat(2, 1), t, intr, reset=torch.tensor([True, False]), max_conditioning=1.0)
    assert not v[0].any() and v[1, 0, 1:].all()


def test_compose_motion_matches_matrices():
    qa, qb = _quat([0.2, 1.0, 0.1], 0.3), _quat([1.0, -0.3, 0.5], -0.2)
    ta, tb = torch.tensor([[0.5, -0.2, 1.5]], dtype=F64), torch.tensor([[0.1, 0.3, 0.9]], dtype=F64)
    q, t = compose_motion(qa, ta, qb, tb)
    Ra, Rb = quaternion_to_matrix(qa)[0], quaternion_to_matrix(qb)[0]
    torch.testing.assert_close(quaternion_to_matrix(q)[0], Ra @ Rb)
    torch.testing.assert_close(t[0], Ra @ tb[0] + ta[0])
    one, zero = identity_motion(1, dtype=F64)
    torch.testing.assert_close(compose_motion(one, zero, qb, tb)[1], tb)
    torch.testing.assert_close(quaternion_multiply(qa, one), qa)
    torch.testing.assert_close(baseline(torch.tensor([[3.0, 4.0, 0.0]])), torch.tensor([5.0]))


def test_carry_identity_is_exact_copy():
    g = torch.Generator().manual_seed(0)
    depth = 5 + 20 * torch.rand(2, 1, 16, 20, generator=g, dtype=F64)
    valid = torch.rand(2, 1, 16, 20, generator=g) > 0.3
    intr = torch.tensor([[10.0, 10.0, 10.0, 8.0]] * 2, dtype=F64)
    one, zero = identity_motion(2, dtype=F64)
    d, v = carry_depth(depth, valid, one, zero, intr)
    torch.testing.assert_close(d, depth)
    assert torch.equal(v, valid)


def test_carry_plane_under_yaw_and_small_translation():
    # reference: the fronto-parallel plane z_ref = D. Current pixel ray x~ at depth z lands at X_ref = z R x~ + t, on
    # the plane when z = (D - t_z) / (R x~)_z (hand-derived); nearest-pixel sampling keeps the error small
    size, D = 96, 20.0
    depth = torch.full((1, 1, size, size), D, dtype=F64)
    valid = torch.ones_like(depth, dtype=torch.bool)
    q = _quat([0, 1, 0], math.radians(20))  # yaw about the camera's vertical axis
    t = torch.tensor([[0.15, -0.05, 0.2]], dtype=F64)
    intr = _intr(size)
    d, v = carry_depth(depth, valid, q, t, intr)
    R = quaternion_to_matrix(q)[0]
    from cosemdepth.geometry.camera import pixel_rays

    rays = pixel_rays(size, size, intr)[0]  # [3, H, W]
    rz = torch.einsum("j,jhw->hw", R[2], rays)
    expected = (D - t[0, 2]) / rz
    # which pixels stay in view: the exact landing position of each current pixel on the plane
    X = expected * torch.einsum("ij,jhw->ihw", R, rays) + t[0].view(3, 1, 1)
    col = (size / 2) * X[0] / X[2] + size / 2 - 0.5
    row = (size / 2) * X[1] / X[2] + size / 2 - 0.5
    inside = (col >= 0.5) & (col <= size - 1.5) & (row >= 0.5) & (row <= size - 1.5)  # away from the borders
    outside = (col < -0.5) | (col > size - 0.5) | (row < -0.5) | (row > size - 0.5)
    assert v[0, 0][inside].all()
    assert not v[0, 0][outside].any()
    rel = ((d[0, 0] - expected).abs() / expected)[inside]
    assert rel.max() < 0.02, rel.max()
    frac_out = 1 - v.double().mean().item()  # a 20-degree yaw and the translation take about 30% out of view
    lo, hi = outside.double().mean().item(), 1 - inside.double().mean().item()
    assert lo - 1e-9 <= frac_out <= hi + 1e-9, (lo, frac_out, hi)
    assert 0.2 < frac_out < 0.4
