import math

import pytest
import torch

from cosemdepth.geometry import (
    candidate_flows,
    candidate_sample_points,
    depth_to_parallax,
    epipolar_geometry,
    level_intrinsics,
    parallax_to_depth,
    pixel_rays,
    prev_depth_to_parallax,
    quaternion_to_matrix,
    small_angle_to_matrix,
    warp,
)
from cosemdepth.geometry.camera import centred_coordinates


def random_motion(b, dtype=torch.float64, seed=0):
    g = torch.Generator().manual_seed(seed)
    axis = torch.nn.functional.normalize(torch.randn(b, 3, generator=g, dtype=dtype), dim=-1)
    angle = 0.1 * torch.rand(b, 1, generator=g, dtype=dtype)
    q = torch.cat([torch.cos(angle / 2), axis * torch.sin(angle / 2)], dim=-1)
    t = torch.tensor([0.3, -0.2, 1.5], dtype=dtype) + 0.2 * torch.randn(b, 3, generator=g, dtype=dtype)
    return q, t


def test_quaternion_matrix_is_rotation_and_matches_axis_angle():
    q, _ = random_motion(5)
    R = quaternion_to_matrix(q)
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3, dtype=q.dtype).expand(5, 3, 3))
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(5, dtype=q.dtype))
    # 90 degrees about z: x -> y
    s = math.sqrt(0.5)
    Rz = quaternion_to_matrix(torch.tensor([s, 0, 0, s], dtype=torch.float64))
    torch.testing.assert_close(
        Rz @ torch.tensor([1.0, 0, 0], dtype=torch.float64), torch.tensor([0.0, 1, 0], dtype=torch.float64)
    )


def test_small_angle_matrix():
    R = small_angle_to_matrix(torch.tensor([0.1, 0.2, 0.3]))
    torch.testing.assert_close(R, torch.tensor([[1, -0.3, 0.2], [0.3, 1, -0.1], [-0.2, 0.1, 1]]))


def test_level_intrinsics_and_rays():
    K = torch.tensor([[192.0, 192.0, 192.0, 192.0]])
    assert level_intrinsics(K, 1).tolist() == [[96.0] * 4]
    assert level_intrinsics(K, 5).tolist() == [[6.0] * 4]
    rays = pixel_rays(4, 4, torch.tensor([[2.0, 2.0, 2.0, 2.0]]))
    # pixel (0, 0): u = 0.5 - 2 = -1.5 -> x = -0.75
    assert rays[0, :, 0, 0].tolist() == [-0.75, -0.75, 1.0]


def project_prev(depth, geom_inputs):
    """Direct 3D projection of current pixels with depth into the previous frame (independent of the formulas)."""
    h, w, q, t, K = geom_inputs
    rays = pixel_rays(h, w, K)
    X = rays * depth
    Xp = torch.einsum("bij,bjhw->bihw", quaternion_to_matrix(q), X) + t.view(-1, 3, 1, 1)
    f = K[:, :2].view(-1, 2, 1, 1)
    return f * Xp[:, :2] / Xp[:, 2:3], Xp[:, 2:3]


def test_parallax_formulas_against_direct_projection():
    b, h, w = 3, 6, 8
    q, t = random_motion(b)
    K = torch.tensor([[4.0, 3.0, 4.0, 3.0]], dtype=torch.float64).expand(b, 4)
    depth = 2.0 + 30 * torch.rand(b, 1, h, w, dtype=torch.float64)
    geom = epipolar_geometry(h, w, q, t, K)
    rho = depth_to_parallax(depth, geom)
    proj, z_prev = project_prev(depth, (h, w, q, t, K))
    # rho is the distance between p_rot and the projection; the projection lies on the epipolar ray
    torch.testing.assert_close(rho, torch.linalg.vector_norm(proj - geom.p_rot, dim=1, keepdim=True))
    flow = candidate_flows(rho, geom)[:, 0]
    u, v = centred_coordinates(h, w, K)
    torch.testing.assert_close(flow, proj - torch.cat([u, v], 1))
    # round trip
    torch.testing.assert_close(parallax_to_depth(rho, geom), depth)
    # previous-depth -> parallax evaluated at the previous pixel gives the same parallax
    torch.testing.assert_close(geom.alpha * depth + geom.t_z, z_prev)


def test_prev_depth_to_parallax_identity():
    # A point seen by the previous frame at integer pixel (i, j) with depth d' has, w.r.t. the current frame, the
    # parallax rho' of design 2.4; check it against depth_to_parallax of the same point seen from the current frame.
    b, h, w = 2, 5, 7
    q, t = random_motion(b, seed=3)
    K = torch.tensor([[3.5, 2.5, 3.5, 2.5]], dtype=torch.float64).expand(b, 4)
    d_prev = 5 + 20 * torch.rand(b, 1, h, w, dtype=torch.float64)
    rho_prev = prev_depth_to_parallax(d_prev, t, K)
    u, v = centred_coordinates(h, w, K)
    Xp = torch.cat([u / K[:, 0].view(-1, 1, 1, 1), v / K[:, 1].view(-1, 1, 1, 1), torch.ones_like(u)], 1) * d_prev
    R = quaternion_to_matrix(q)
    Xc = torch.einsum("bji,bjhw->bihw", R, Xp - t.view(-1, 3, 1, 1))  # X_curr = R^T (X_prev - t)
    # parallax of that point w.r.t. the current camera: |q - p_rot| where q is its previous projection
    r = torch.einsum("bij,bjhw->bihw", R, Xc / Xc[:, 2:3])
    p_rot = K[:, :2].view(-1, 2, 1, 1) * r[:, :2] / r[:, 2:3]
    expected = torch.linalg.vector_norm(torch.cat([u, v], 1) - p_rot, dim=1, keepdim=True)
    torch.testing.assert_close(rho_prev, expected)


def test_prev_depth_below_tz_gives_positive_parallax_like_the_original():
    t = torch.tensor([[0.0, 0.0, 2.0]])
    K = torch.tensor([[2.0, 2.0, 2.0, 2.0]])
    d = torch.full((1, 1, 4, 4), 1.0)  # 1 - 2 = -1 -> |.| = 1
    rho = prev_depth_to_parallax(d, t, K)
    u, v = centred_coordinates(4, 4, K)
    torch.testing.assert_close(rho, 2.0 * torch.sqrt(u**2 + v**2))


def test_degenerate_inputs_stay_finite():
    h, w = 4, 4
    K = torch.tensor([[2.0, 2.0, 2.0, 2.0]])
    q = torch.tensor([[1.0, 0, 0, 0]])
    for t in (torch.zeros(1, 3), torch.tensor([[0.0, 0.0, 1.0]])):  # zero translation; FoE on a pixel corner
        geom = epipolar_geometry(h, w, q, t, K)
        rho = torch.tensor([[[[0.0, 1.0, 2.0, 3.0]]]]).expand(1, 1, h, w)
        for out in (
            geom.direction,
            candidate_flows(rho + 1, geom),
            parallax_to_depth(rho, geom),
            depth_to_parallax(torch.zeros(1, 1, h, w), geom),
            prev_depth_to_parallax(t[:, 2].view(1, 1, 1, 1).expand(1, 1, h, w), t, K),
        ):
            assert torch.isfinite(out).all()
    # unguarded original: 0/0 at zero translation
    geom = epipolar_geometry(h, w, q, torch.zeros(1, 3), K, guard=False)
    assert torch.isnan(geom.direction).any()


def test_guards_do_not_change_normal_inputs():
    b, h, w = 2, 6, 6
    q, t = random_motion(b, dtype=torch.float32)
    K = torch.tensor([[3.0, 3.0, 3.0, 3.0]]).expand(b, 4)
    d = 1 + 50 * torch.rand(b, 1, h, w)
    g1 = epipolar_geometry(h, w, q, t, K, guard=True)
    g0 = epipolar_geometry(h, w, q, t, K, guard=False)
    assert torch.equal(depth_to_parallax(d, g1), depth_to_parallax(d, g0, guard=False))
    assert torch.equal(prev_depth_to_parallax(d + 5, t, K), prev_depth_to_parallax(d + 5, t, K, guard=False))


def test_gradcheck_geometry_float64():
    b, h, w = 1, 3, 4
    q, t = random_motion(b)
    K = torch.tensor([[2.0, 1.5, 2.0, 1.5]], dtype=torch.float64)
    q.requires_grad_(True)
    t.requires_grad_(True)
    d = (3 + 10 * torch.rand(b, 1, h, w, dtype=torch.float64)).requires_grad_(True)

    def f(q, t, d):
        geom = epipolar_geometry(h, w, q, t, K)
        rho = depth_to_parallax(d, geom)
        return rho, parallax_to_depth(rho + 0.1, geom), candidate_flows(rho.expand(b, 2, h, w), geom)

    assert torch.autograd.gradcheck(f, (q, t, d))
    assert torch.autograd.gradcheck(lambda d, t: prev_depth_to_parallax(d, t, K), (d, t))


def test_warp_integer_flow_and_border_clamp():
    img = torch.arange(20.0).view(1, 1, 4, 5)
    flow = torch.zeros(1, 2, 4, 5)
    flow[:, 0] = 1.0  # sample one column to the right
    out = warp(img, flow)
    assert out[0, 0, :, :4].tolist() == img[0, 0, :, 1:].tolist()
    assert out[0, 0, :, 4].tolist() == img[0, 0, :, 4].tolist()  # clamped at the border
    flow[:, 0] = 0.25
    flow[:, 1] = 0.5
    out = warp(img, flow)
    # bilinear: value = 5*(i+0.5) + (j+0.25) inside
    assert out[0, 0, 1, 2].item() == pytest.approx(5 * 1.5 + 2.25)


def test_warp_gradcheck_float64():
    img = torch.rand(1, 2, 5, 6, dtype=torch.float64, requires_grad=True)
    flow = (0.7 * torch.randn(1, 2, 5, 6, dtype=torch.float64)).requires_grad_(True)
    assert torch.autograd.gradcheck(warp, (img, flow))


def test_candidate_sample_points_match_flows():
    b, h, w = 2, 4, 6
    q, t = random_motion(b, dtype=torch.float32)
    K = torch.tensor([[3.0, 2.0, 3.0, 2.0]]).expand(b, 4)
    geom = epipolar_geometry(h, w, q, t, K)
    rho = 1 + torch.rand(b, 3, h, w)
    flows = candidate_flows(rho, geom)
    pts = candidate_sample_points(rho, geom)
    i = torch.arange(h, dtype=torch.float32).view(1, 1, h, 1)
    j = torch.arange(w, dtype=torch.float32).view(1, 1, 1, w)
    torch.testing.assert_close(pts[:, :, 0], j + flows[:, :, 0])
    torch.testing.assert_close(pts[:, :, 1], i + flows[:, :, 1])


def test_row_gather_sampling_matches_grid_sample_on_every_edge_case():
    from cosemdepth.geometry.warp import sample_bilinear, sample_bilinear_rows

    # a linear image is reproduced exactly by bilinear sampling: value = 5 * row + column, positions clamped
    img = (5 * torch.arange(4.0).view(4, 1) + torch.arange(5.0)).expand(2, 3, 4, 5).contiguous()
    pts = torch.tensor([[0.25, 4.0, 9.0, -3.0], [0.5, 3.0, 1.0, 2.75]]).view(1, 2, 1, 4).expand(2, 2, 1, 4)
    out = sample_bilinear_rows(img, pts)
    assert out.shape == (2, 3, 1, 4)
    assert out[0, 0, 0].tolist() == pytest.approx([5 * 0.5 + 0.25, 5 * 3 + 4, 5 * 1 + 4, 5 * 2.75 + 0])
    torch.manual_seed(0)
    for b, c, h, w, ho, wo in [(2, 5, 7, 9, 4, 6), (1, 3, 1, 5, 3, 3), (1, 2, 6, 1, 2, 2), (1, 1, 1, 1, 2, 2)]:
        img = torch.randn(b, c, h, w, dtype=torch.float64)
        pts = torch.stack([torch.rand(b, ho, wo) * (w + 4) - 2, torch.rand(b, ho, wo) * (h + 4) - 2], 1).double()
        pts[0, :, 0, 0] = torch.tensor([w - 1.0, h - 1.0])  # the last pixel centre exactly
        torch.testing.assert_close(sample_bilinear_rows(img, pts), sample_bilinear(img, pts), rtol=1e-12, atol=1e-12)
