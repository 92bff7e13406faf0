"""SynthAir renderer: camera model, exact depth, labels, against independent expectations."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from synthair_helpers import euler_matrix, matrix_to_quaternion

from cosemdepth.synthair.climate import CLIMATES, get_climate
from cosemdepth.synthair.raymarch import Lod, surface_height
from cosemdepth.synthair.render import SKY_DEPTH, render_frame
from cosemdepth.synthair.terrain import CELL, GRID

MIDAIR_IDS_USED = {0, 2, 3, 4, 5, 6, 8, 9, 10}


def _lake_centre(world) -> tuple[float, float]:
    """A point of open water at least ~64 m from any shore (3 x 3 blocks of 64 m all under water)."""
    b = 32
    h = world.terrain.height.reshape(GRID // b, b, GRID // b, b).max(axis=(1, 3))
    deep = h < world.water_level - 0.3
    ok = deep.copy()
    for a in (-1, 0, 1):
        for c in (-1, 0, 1):
            ok &= np.roll(np.roll(deep, a, 0), c, 1)
    cells = np.argwhere(ok)
    assert len(cells), "the test world has no lake wide enough for the flat-water camera test"
    i, j = cells[len(cells) // 2]
    return (i + 0.5) * b * CELL, (j + 0.5) * b * CELL


def _ray_directions(rot: np.ndarray, size: int) -> np.ndarray:
    """``[size, size, 3]`` NED directions of the pixel-centre rays of a ``size x size`` 90-degree camera whose body
    axes are rotated by ``rot``: camera ray ``(u/f, v/f, 1)`` is body ``(1, u/f, v/f)`` (camera z, x, y = body x, y,
    z), with ``f = size / 2``."""
    c = (np.arange(size) + 0.5 - size / 2) / (size / 2)
    right, down = np.meshgrid(c, c)  # [row, col]: camera x = column, camera y = row
    return np.stack([np.ones_like(right), right, down], -1) @ rot.T


def test_camera_looking_straight_down_at_a_lake_sees_constant_depth(world):
    x, y = _lake_centre(world)
    height = 20.0
    rot = euler_matrix(np.radians(37.0), np.radians(-90.0), 0.0)
    pos = np.array([x, y, -(world.water_level + height)])
    f = render_frame(world, get_climate("sunny"), matrix_to_quaternion(rot), pos, 32, 32)
    np.testing.assert_allclose(f.depth, height, rtol=1e-4)
    assert (f.labels == 8).all()


def test_depth_of_a_tilted_camera_over_flat_water_matches_the_plane_equation(world):
    """z-depth of the plane ``down = h`` for camera ray (u/f, v/f, 1): h / (R (1, u/f, v/f))_down."""
    x, y = _lake_centre(world)
    h = 12.0
    size = 48
    rot = euler_matrix(np.radians(-123.0), np.radians(-35.0), np.radians(12.0))
    pos = np.array([x, y, -(world.water_level + h)])
    frame = render_frame(world, get_climate("cloudy"), matrix_to_quaternion(rot), pos, size, size)
    ned = _ray_directions(rot, size)
    down_comp = ned[..., 2]
    expected = h / np.where(down_comp > 1e-6, down_comp, np.nan)
    horizontal = expected * np.linalg.norm(ned[..., :2], axis=-1)
    near = np.isfinite(expected) & (horizontal < 50.0)  # inside the lake
    assert near.sum() > size * size // 4
    np.testing.assert_allclose(frame.depth[near], expected[near], rtol=2e-4)
    assert (frame.labels[near] == 8).all()


def test_steep_rays_upwards_see_the_sky_at_the_sky_depth(world):
    x, y = _lake_centre(world)
    rot = euler_matrix(np.radians(10.0), np.radians(75.0), 0.0)
    pos = np.array([x, y, -(world.water_level + 10.0)])
    frame = render_frame(world, get_climate("sunset"), matrix_to_quaternion(rot), pos, 24, 24)
    ned = _ray_directions(rot, 24)
    elevation = np.degrees(np.arcsin(-ned[..., 2] / np.linalg.norm(ned, axis=-1)))
    steep = elevation > 30.0
    assert steep.sum() > 200
    assert (frame.labels[steep] == 0).all() and (frame.depth[steep] == SKY_DEPTH).all()
    assert (frame.rgb[steep].astype(int).sum(-1) > 150).all()  # a lit sky, not black


@pytest.fixture(scope="module")
def flight_frames(world):
    from cosemdepth.synthair.trajectory import make_flight

    out = []
    for k, mode in enumerate(("road", "village", "free")):
        flight = make_flight(world, np.random.default_rng(100 + k), 40, mode)
        j = 4 * 20
        frame = render_frame(world, get_climate(CLIMATES[k]), flight.attitude[j], flight.position[j], 64, 64)
        out.append((flight.attitude[j], flight.position[j], frame))
    return out


def test_frame_arrays_have_the_mid_air_types(flight_frames):
    for _, _, f in flight_frames:
        assert f.rgb.shape == (64, 64, 3) and f.rgb.dtype == np.uint8
        assert f.depth.shape == (64, 64) and f.depth.dtype == np.float32
        assert f.labels.shape == (64, 64) and f.labels.dtype == np.uint8
        assert np.isfinite(f.depth).all() and (f.depth > 0).all()
        assert set(np.unique(f.labels)) <= MIDAIR_IDS_USED
        sky = f.labels == 0
        assert (f.depth[sky] == SKY_DEPTH).all() and (f.depth[~sky] < SKY_DEPTH).all()


def test_depth_points_lie_on_the_surface(world, flight_frames):
    """Back-project every non-sky, non-building pixel with its depth and pose: along the pixel's ray the height
    above the height field changes sign at that depth (above a little before it, under a little after it; a
    little = 0.2 % of the depth, at most 3 cm, since a ray can graze a tree top)."""
    from cosemdepth.data.quaternion import qmatrix

    def clearance(pos, ned, depth):
        pts = pos + ned * depth[:, None]
        xy = torch.tensor(np.stack([pts[:, 0], pts[:, 1]]), dtype=torch.float32)
        # the renderer's level of detail for this camera (far trees morph into the canopy)
        lod = Lod(torch.tensor(pos[:2], dtype=torch.float32).reshape(2, 1), 2.0 / size)
        return -pts[:, 2] - surface_height(world, xy, lod).double().numpy()

    for att, pos, f in flight_frames:
        size = f.depth.shape[0]
        ned = _ray_directions(qmatrix(att), size)
        sel = (f.labels != 0) & (f.labels != 9)
        d = f.depth[sel].astype(np.float64)
        eps = np.minimum(0.002 * d, 0.03)
        before = clearance(pos, ned[sel], d - eps)
        after = clearance(pos, ned[sel], d + eps)
        assert (before > -0.01).mean() > 0.995
        assert (after < 0.01).mean() > 0.99
        assert np.median(np.abs(clearance(pos, ned[sel], d))) < 0.01


def test_labels_match_the_geometry(world, flight_frames):
    from cosemdepth.data.quaternion import qmatrix
    from cosemdepth.synthair.raymarch import sample_surface

    for att, pos, f in flight_frames:
        size = f.depth.shape[0]
        ned = _ray_directions(qmatrix(att), size)
        pts = pos + ned * f.depth[..., None].astype(np.float64)
        xy = torch.tensor(np.stack([pts[..., 0].ravel(), pts[..., 1].ravel()]), dtype=torch.float32)
        smp = sample_surface(world, xy, Lod(torch.tensor(pos[:2], dtype=torch.float32).reshape(2, 1), 2.0 / size))
        obj = torch.maximum(smp.tree, smp.boulder).numpy().reshape(size, size)
        lab = f.labels
        assert (obj[lab == 2] > 0.01).all() and (obj[lab == 6] > 0.01).all()
        ground = np.isin(lab, [3, 4, 5, 10])
        assert (obj[ground] < 0.05).all()
        water = lab == 8
        np.testing.assert_allclose(-pts[..., 2][water], world.water_level, atol=0.02)


def test_rendering_is_deterministic(world, flight_frames):
    att, pos, f = flight_frames[0]
    again = render_frame(world, get_climate(CLIMATES[0]), att, pos, 64, 64)
    assert np.array_equal(again.rgb, f.rgb)
    assert np.array_equal(again.depth, f.depth)
    assert np.array_equal(again.labels, f.labels)


def test_supersampling_keeps_depth_and_labels_of_the_pixel_centre(world, flight_frames):
    att, pos, f = flight_frames[1]
    ss = render_frame(world, get_climate(CLIMATES[1]), att, pos, 64, 64, supersample=3)
    # the same rays, searched from other start points (the beams differ): the same hits but for a few grazing ones
    assert (ss.labels == f.labels).mean() > 0.995
    assert (np.abs(ss.depth / f.depth - 1) < 1e-4).mean() > 0.99
    assert np.abs(ss.rgb.astype(int) - f.rgb.astype(int)).mean() < 8
    with pytest.raises(ValueError, match="supersample"):
        render_frame(world, get_climate("sunny"), att, pos, 16, 16, supersample=2)
