"""The SynthAir world: determinism, content and the invariants the ray marcher relies on."""

from __future__ import annotations

import numpy as np
import torch

from cosemdepth.synthair.raymarch import Lod, surface_height
from cosemdepth.synthair.terrain import CELL, GRID, PERIOD
from cosemdepth.synthair.world import LEVELS, build_world


def test_the_same_seed_builds_the_same_world_bit_for_bit(world):
    again = build_world(world.seed)
    assert np.array_equal(again.terrain.height, world.terrain.height)
    assert np.array_equal(again.tile.height, world.tile.height)
    assert np.array_equal(again.buildings.planes, world.buildings.planes)
    for name in ("surf", "shade", "tile_surf", "tile_shade", "env_max", "env_dilated", "env_min0"):
        assert torch.equal(getattr(again, name), getattr(world, name)), name


def test_the_world_has_lakes_roads_forests_rocks_and_buildings(world):
    t = world.terrain
    water = (t.height < t.water_level).mean()
    assert 0.03 < water < 0.2
    assert (t.road_distance < 3.5).mean() > 0.005
    assert 0.2 < (t.tree_density > 0.5).mean() < 0.7
    assert 0.03 < (t.rock > 0.5).mean() < 0.3 and 0.05 < (t.dirt > 0.5).mean() < 0.4
    assert len(world.buildings) > 100
    relief = np.ptp(t.height)
    assert 80 < relief < 400  # hills, not a plain nor the Alps


def _random_points(rng, n):
    return torch.tensor(rng.uniform(0, PERIOD, (2, n)), dtype=torch.float32)


def test_the_max_pyramid_bounds_the_surface_from_above_and_the_min_from_below(world):
    rng = np.random.default_rng(1)
    xy = _random_points(rng, 200_000)
    cam = torch.tensor([[1000.0], [2000.0]])
    for lod in (None, Lod(cam, 1 / 192), Lod(cam, 1 / 16)):  # full detail and two levels of detail
        s = surface_height(world, xy, lod)
        ij = torch.floor(xy / CELL).long() % GRID
        cell = ij[0] * GRID + ij[1]
        assert (s <= world.env_max[cell]).all()
        assert (s >= world.env_min0[cell]).all()
    # every level bounds the level below it
    for k in range(LEVELS):
        n, off = int(world.level_cells[k]), int(world.level_offset[k])
        child = world.env_max[off : off + n * n].view(n // 2, 2, n // 2, 2).amax(dim=(1, 3))
        parent_off = int(world.level_offset[k + 1])
        parent = world.env_max[parent_off : parent_off + (n // 2) ** 2].view(n // 2, n // 2)
        assert torch.equal(parent, child)


def test_the_world_repeats_every_period(world):
    rng = np.random.default_rng(2)
    xy = _random_points(rng, 1000)
    shifted = xy + torch.tensor([[PERIOD], [-2 * PERIOD]])
    diff = np.abs(surface_height(world, shifted).numpy() - surface_height(world, xy).numpy())
    # equal up to float32 rounding of the larger coordinates (a few mm on steep tree sides)
    assert np.median(diff) < 1e-3 and diff.max() < 0.05
