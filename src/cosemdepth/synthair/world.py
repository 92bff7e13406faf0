"""The SynthAir world: terrain + object tile + buildings, and the tables the renderer samples.

``build_world(seed)`` is deterministic: the same seed gives the same world, bit for bit.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import torch

from .buildings import Buildings, build_buildings
from .noise import blur_periodic_2d, max_filter_periodic
from .objects import TILE, TILE_PERIOD, ObjectTile, build_object_tile
from .terrain import CELL, GRID, PERIOD, Terrain, build_terrain, finish_forest_shade, gradient

#: Coarsest level of the max pyramid (cells of CELL * 2**LEVELS metres).
LEVELS = 7

#: Margin added to the envelopes so that float32 rounding never makes them non-conservative.
ENV_MARGIN = 0.02

#: Gaussian smoothing (grid cells) of the terrain for the shading normals of growing pixel footprints.
NORMAL_SMOOTHING = (0.0, 1.0, 2.5, 6.0)
#: Height of the smooth canopy of dense forests (level of detail of far trees), metres.
CANOPY_HEIGHT = 9.0


@dataclass
class World:
    """The world of a seed: terrain, object tile and buildings, and the renderer's tables built from them."""

    seed: int
    terrain: Terrain
    tile: ObjectTile
    buildings: Buildings
    # renderer tables, channel first ([C, cells]; cell (i, j) is column i * side + j):
    surf: torch.Tensor  # [4, GRID*GRID] float32: terrain height, tree density, boulder density, canopy height
    shade: torch.Tensor  # [13, GRID*GRID] float32: dT/dx, dT/dy at the 4 smoothings of NORMAL_SMOOTHING, rock,
    #                      dirt, forest shade, tint, road distance
    tile_surf: torch.Tensor  # [4, TILE*TILE] float32: tree h, tree gate, boulder h, boulder gate
    tile_shade: torch.Tensor  # [8, TILE*TILE] float32: tree grad x, y, boulder grad x, y, tree id, boulder id,
    #                                                  tree full height, boulder full height
    env_max: torch.Tensor  # [sum of level sizes] float32 max pyramid of the surface (level 0 first)
    env_dilated: torch.Tensor  # like env_max, each cell holding the max over itself and its 8 neighbours
    env_min0: torch.Tensor  # [GRID*GRID] float32 min of the terrain/water surface per level-0 cell
    env_objects: torch.Tensor  # [GRID*GRID] bool: trees or boulders may rise in the level-0 cell
    level_offset: torch.Tensor  # [LEVELS + 1] int64
    level_cells: torch.Tensor  # [LEVELS + 1] int64 cells per side
    level_size: torch.Tensor  # [LEVELS + 1] float32 cell size, metres
    water_level: float
    max_height: float  # highest point of the surface (buildings excluded)
    road_lateral: torch.Tensor  # [K, GRID] float32
    road_slope: torch.Tensor  # [K, GRID] float32
    road_axis: tuple[int, ...]


def _corner_max(a: np.ndarray) -> np.ndarray:
    m = np.maximum(a, np.roll(a, -1, 0))
    return np.maximum(m, np.roll(m, -1, 1))


def _corner_min(a: np.ndarray) -> np.ndarray:
    m = np.minimum(a, np.roll(a, -1, 0))
    return np.minimum(m, np.roll(m, -1, 1))


def canopy_height(tree_density: np.ndarray) -> np.ndarray:
    """The smooth canopy that far trees morph into (level of detail): CANOPY_HEIGHT where the forest is dense,
    nothing where trees are sparse. ``[GRID, GRID]`` float32, metres above the terrain."""
    dens = blur_periodic_2d(tree_density.astype(np.float64), 2.0)
    t = np.clip((dens - 0.25) / 0.6, 0.0, 1.0)
    return (CANOPY_HEIGHT * t * t * (3 - 2 * t)).astype(np.float32)


def _envelopes(
    terrain: Terrain, tile: ObjectTile, height32: np.ndarray, dens_t: np.ndarray, dens_b: np.ndarray, canopy: np.ndarray
):
    w = np.float32(terrain.water_level)
    q_levels = tile.cell_envelope.shape[1]
    c = tile.cell_envelope.shape[2]
    ii = (np.arange(GRID) % c)[:, None]
    jj = (np.arange(GRID) % c)[None, :]
    obj = np.zeros((GRID, GRID), dtype=np.float64)
    for layer, dens in ((0, dens_t), (1, dens_b)):
        # conservative: the density level at or above the cell's largest corner density
        q = np.clip(np.ceil(_corner_max(dens.astype(np.float64)) * (q_levels - 1) - 1e-9), 0, q_levels - 1)
        obj = np.maximum(obj, tile.cell_envelope[layer][q.astype(np.int64), ii, jj])
    obj = np.maximum(obj, _corner_max(canopy.astype(np.float64)))  # far trees morph into the canopy
    env0 = np.maximum(_corner_max(height32.astype(np.float64)) + obj, w) + ENV_MARGIN
    envmin = np.maximum(_corner_min(height32.astype(np.float64)), w) - ENV_MARGIN
    levels = [env0]
    for _ in range(LEVELS):
        a = levels[-1]
        n = a.shape[0] // 2
        levels.append(a.reshape(n, 2, n, 2).max(axis=(1, 3)))
    sizes = [lv.shape[0] for lv in levels]
    offsets = np.concatenate([[0], np.cumsum([s * s for s in sizes])[:-1]])
    flat = np.concatenate([lv.ravel() for lv in levels]).astype(np.float32)
    # the same pyramid dilated by one cell (max over 3 x 3 cells), for beams (see raymarch.beam_start)
    dil = np.concatenate([max_filter_periodic(lv, 1).ravel() for lv in levels]).astype(np.float32)
    return flat, dil, envmin.astype(np.float32).ravel(), (obj > 0).ravel(), offsets, sizes, float(env0.max())


def build_world(seed: int) -> World:
    """Generate the world for ``seed`` (a few seconds; cached per process by :func:`get_world`)."""
    ss = np.random.SeedSequence([seed, 0x5A17A1])
    r_terrain, r_tile, r_build = (np.random.default_rng(s) for s in ss.spawn(3))
    terrain = build_terrain(r_terrain)
    tile = build_object_tile(r_tile)
    buildings = build_buildings(r_build, terrain)
    finish_forest_shade(terrain)

    h32 = terrain.height.astype(np.float32)
    dt32 = terrain.tree_density.astype(np.float32)
    db32 = terrain.boulder_density.astype(np.float32)
    canopy = canopy_height(terrain.tree_density)
    surf = np.stack([h32, dt32, db32, canopy]).reshape(4, -1)
    # terrain gradients at increasing smoothing (shading normals are band-limited by the pixel footprint)
    grads = []
    for sigma in NORMAL_SMOOTHING:
        smooth = terrain.height if sigma == 0 else blur_periodic_2d(terrain.height.astype(np.float64), sigma)
        grads.extend(gradient(smooth))
    shade = (
        np.stack(
            [
                *grads,
                terrain.rock,
                terrain.dirt,
                terrain.forest_shade,
                terrain.tint,
                np.minimum(terrain.road_distance, 1e4),
            ]
        )
        .astype(np.float32)
        .reshape(len(grads) + 5, -1)
    )
    tile_surf = np.stack([tile.height[0], tile.gate[0], tile.height[1], tile.gate[1]]).reshape(4, -1)
    tile_shade = np.stack(
        [
            tile.grad[0, 0],
            tile.grad[0, 1],
            tile.grad[1, 0],
            tile.grad[1, 1],
            tile.ident[0],
            tile.ident[1],
            tile.top[0],
            tile.top[1],
        ]
    ).reshape(8, -1)
    env, env_dil, envmin, env_obj, offsets, sizes, max_h = _envelopes(terrain, tile, h32, dt32, db32, canopy)
    return World(
        seed=seed,
        terrain=terrain,
        tile=tile,
        buildings=buildings,
        surf=torch.from_numpy(np.ascontiguousarray(surf)),
        shade=torch.from_numpy(np.ascontiguousarray(shade)),
        tile_surf=torch.from_numpy(np.ascontiguousarray(tile_surf.astype(np.float32))),
        tile_shade=torch.from_numpy(np.ascontiguousarray(tile_shade.astype(np.float32))),
        env_max=torch.from_numpy(env),
        env_dilated=torch.from_numpy(env_dil),
        env_min0=torch.from_numpy(envmin),
        env_objects=torch.from_numpy(env_obj),
        level_offset=torch.tensor(offsets, dtype=torch.int64),
        level_cells=torch.tensor(sizes, dtype=torch.int64),
        level_size=torch.tensor([CELL * 2**k for k in range(LEVELS + 1)], dtype=torch.float32),
        water_level=float(terrain.water_level),
        max_height=max_h,
        road_lateral=torch.from_numpy(terrain.roads.lateral.astype(np.float32)),
        road_slope=torch.from_numpy(terrain.roads.slope.astype(np.float32)),
        road_axis=tuple(int(a) for a in terrain.roads.axis),
    )


@functools.lru_cache(maxsize=2)
def get_world(seed: int) -> World:
    """The world of ``seed``, built once per process."""
    return build_world(seed)


__all__ = ["World", "build_world", "get_world", "PERIOD", "CELL", "GRID", "TILE", "TILE_PERIOD"]
