"""SynthAir terrain: a periodic fractal height field with lakes, roads and the ground-cover fields.

World coordinates are metres ``(x, y, up)`` with ``x`` north and ``y`` east (the horizontal axes of NED; ``up`` is
``-z`` of NED). Grid cell ``[i, j]`` holds the value at ``(i * CELL, j * CELL)`` and the world repeats every
``PERIOD`` metres in ``x`` and ``y``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .noise import bilinear_periodic, blur_periodic_2d, fractal_field, smooth_periodic_1d, smoothstep

#: Grid cells per side, metres per cell, and the world period in metres.
GRID = 2048
CELL = 2.0
PERIOD = GRID * CELL

#: Road half width (asphalt), and the width over which the terrain blends back from the road level.
ROAD_HALF_WIDTH = 3.5
ROAD_EMBANKMENT = 22.0
#: Half width (cells) of the band around a road where the terrain is levelled and road distances are exact.
ROAD_BAND = 80


@dataclass
class Roads:
    """Roads as periodic curves. Road ``k`` runs along axis ``axis[k]`` (0: x, 1: y); at along-road coordinate
    ``s = k * CELL`` its centre line has lateral coordinate ``lateral[k, s]`` (y for axis 0, x for axis 1)."""

    axis: np.ndarray  # [K] int
    lateral: np.ndarray  # [K, GRID] metres
    slope: np.ndarray  # [K, GRID] d lateral / d s
    height: np.ndarray  # [K, GRID] road surface height (up), metres

    def distance(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance of points to the nearest road centre line, and that road's index. Shapes follow ``x``."""
        best = np.full(np.shape(x), np.inf)
        which = np.zeros(np.shape(x), dtype=np.int64)
        for k in range(len(self.axis)):
            d = self.distance_to(k, x, y)
            closer = d < best
            best = np.where(closer, d, best)
            which = np.where(closer, k, which)
        return best, which

    def distance_to(self, k: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        s, lat = (x, y) if self.axis[k] == 0 else (y, x)
        c = _interp_periodic(self.lateral[k], s)
        g = _interp_periodic(self.slope[k], s)
        dl = np.mod(lat - c + PERIOD / 2, PERIOD) - PERIOD / 2
        return np.abs(dl) / np.sqrt(1.0 + g * g)

    def height_at(self, k: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        s = x if self.axis[k] == 0 else y
        return _interp_periodic(self.height[k], s)

    def point(self, k: int, s: float) -> tuple[float, float]:
        """World ``(x, y)`` of the centre line of road ``k`` at along-road coordinate ``s``."""
        lat = float(_interp_periodic(self.lateral[k], np.array(s)))
        return (s, lat) if self.axis[k] == 0 else (lat, s)

    def tangent(self, k: int, s: float) -> tuple[float, float]:
        g = float(_interp_periodic(self.slope[k], np.array(s)))
        n = np.hypot(1.0, g)
        return (1.0 / n, g / n) if self.axis[k] == 0 else (g / n, 1.0 / n)


def _interp_periodic(table: np.ndarray, s: np.ndarray) -> np.ndarray:
    g = np.asarray(s, dtype=np.float64) / CELL
    i0 = np.floor(g)
    f = g - i0
    i0 = i0.astype(np.int64) % len(table)
    return table[i0] * (1 - f) + table[(i0 + 1) % len(table)] * f


@dataclass
class Terrain:
    height: np.ndarray  # [GRID, GRID] terrain height (up), metres, roads blended in
    water_level: float
    roads: Roads
    road_distance: np.ndarray  # [GRID, GRID] metres to the nearest road centre line
    rock: np.ndarray  # [GRID, GRID] rockiness in [0, 1]; > 0.5 is rocky ground
    dirt: np.ndarray  # [GRID, GRID] dirtiness in [0, 1]; > 0.5 is dirt (unless rocky)
    tree_density: np.ndarray  # [GRID, GRID] in [0, 1]
    boulder_density: np.ndarray  # [GRID, GRID] in [0, 1]
    forest_shade: np.ndarray  # [GRID, GRID] in [0, 1], blurred canopy cover (darkens the forest floor)
    tint: np.ndarray  # [GRID, GRID] large-scale colour variation in [-1, 1]

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return bilinear_periodic(self.height, x, y, CELL)

    def surface_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Terrain or water surface height (objects and buildings excluded)."""
        return np.maximum(self.height_at(x, y), self.water_level)


def gradient(field: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central differences of a periodic grid field, per metre: ``(d/dx, d/dy)``."""
    gx = (np.roll(field, -1, 0) - np.roll(field, 1, 0)) / (2 * CELL)
    gy = (np.roll(field, -1, 1) - np.roll(field, 1, 1)) / (2 * CELL)
    return gx, gy


def _make_roads(rng: np.random.Generator, height: np.ndarray, water_level: float) -> Roads:
    n_x, n_y = 3, 3
    axis, lateral, slope, road_h = [], [], [], []
    s = np.arange(GRID) * CELL
    for a, n_roads in ((0, n_x), (1, n_y)):
        offsets = (np.arange(n_roads) + rng.uniform(0.15, 0.85, n_roads)) * PERIOD / n_roads
        for off in offsets:
            lat = np.full(GRID, off)
            d_lat = np.zeros(GRID)
            for m in range(1, 7):
                amp = rng.uniform(0.2, 1.0) * 220.0 / m**1.3
                ph = rng.uniform(0, 2 * np.pi)
                w = 2 * np.pi * m / PERIOD
                lat += amp * np.sin(w * s + ph)
                d_lat += amp * w * np.cos(w * s + ph)
            x, y = (s, lat) if a == 0 else (lat, s)
            h = bilinear_periodic(height, x, y, CELL)
            h = smooth_periodic_1d(h, sigma_cells=25.0)
            h = np.maximum(h, water_level + 1.2)
            h = smooth_periodic_1d(h, sigma_cells=6.0)
            axis.append(a)
            lateral.append(lat)  # periodic in s (integer harmonics); distances wrap the lateral offset
            slope.append(d_lat)
            road_h.append(h)
    return Roads(np.array(axis), np.array(lateral), np.array(slope), np.array(road_h))


def _blend_roads(height: np.ndarray, roads: Roads) -> tuple[np.ndarray, np.ndarray]:
    """Level the terrain along the roads (embankments and cuttings no steeper than about 1:1.5), and the distance
    of every grid cell to the nearest road centre line (capped at ``ROAD_BAND`` cells)."""
    f32 = np.float32
    blend_w = np.zeros_like(height)
    blend_h = np.zeros_like(height)
    road_distance = np.full(height.shape, f32(ROAD_BAND * CELL))
    rows = np.arange(GRID)[:, None]
    offsets = np.arange(-ROAD_BAND, ROAD_BAND + 1)[None, :]
    e0 = ROAD_HALF_WIDTH + 1.5
    for k in range(len(roads.axis)):
        # the cells of a band around the road: along-road index = grid row (axis 0) or column (axis 1)
        lat = roads.lateral[k][:, None]
        centre = np.round(lat / CELL).astype(np.int64)
        lat_idx = centre + offsets  # [GRID, band]
        dl = lat_idx * CELL - lat
        d = (np.abs(dl) / np.sqrt(1.0 + roads.slope[k][:, None] ** 2)).astype(f32)
        ii, jj = (rows, lat_idx % GRID) if roads.axis[k] == 0 else (lat_idx % GRID, rows)
        rh = roads.height[k][:, None].astype(f32)
        width = np.maximum(f32(ROAD_EMBANKMENT), f32(1.5) * np.abs(height[ii, jj] - rh))
        a = f32(1.0) - np.clip((d - f32(e0)) / width, 0.0, 1.0)
        a = a * a * (f32(3.0) - f32(2.0) * a)
        blend_w[ii, jj] += a
        blend_h[ii, jj] += a * rh
        road_distance[ii, jj] = np.minimum(road_distance[ii, jj], d)
    on_road = blend_w > 0
    mix_h = np.where(on_road, blend_h / np.maximum(blend_w, f32(1e-9)), f32(0.0))
    height = np.where(on_road, height + (mix_h - height) * np.minimum(blend_w, f32(1.0)), height)
    return height, road_distance


def build_terrain(rng: np.random.Generator) -> Terrain:
    """Generate the terrain, lakes, roads and ground-cover fields (a few seconds)."""
    hills = fractal_field(rng, GRID, CELL, beta=2.3, cutoff=1400.0)
    detail = fractal_field(rng, GRID, CELL, beta=1.6, cutoff=120.0)
    mountain_mask = smoothstep(0.7, 1.8, fractal_field(rng, GRID, CELL, beta=2.6, cutoff=2500.0, upsample=4))
    ridge = np.clip(1.0 - np.abs(fractal_field(rng, GRID, CELL, beta=2.0, cutoff=500.0, upsample=2)), 0.0, 1.0)
    height = 32.0 * hills + 1.5 * detail + 40.0 * mountain_mask * ridge**2
    # Valleys flatter than hill tops (lakes and fields in the lows).
    low = np.float32(np.quantile(height, 0.35))
    height = np.where(height < low, low - np.float32(0.55) * (low - height), height).astype(np.float32)
    water_level = float(np.quantile(height, 0.075))

    roads = _make_roads(rng, height, water_level)
    height, road_distance = _blend_roads(height, roads)
    gx, gy = gradient(height)
    slope = np.hypot(gx, gy)
    wet = height < water_level + 0.05
    shore = smoothstep(water_level + 2.5, water_level + 0.3, height) * (~wet)

    rock_noise = fractal_field(rng, GRID, CELL, beta=1.9, cutoff=300.0, upsample=2)
    rock = np.clip(
        smoothstep(0.55, 0.85, slope)
        + 0.6 * mountain_mask * smoothstep(0.0, 1.0, rock_noise)
        + 0.3 * smoothstep(1.4, 2.2, rock_noise),
        0.0,
        1.0,
    )
    dirt_noise = fractal_field(rng, GRID, CELL, beta=1.8, cutoff=200.0, upsample=2)
    shoulder = 1.0 - smoothstep(ROAD_HALF_WIDTH + 1.0, ROAD_HALF_WIDTH + 3.0, road_distance)
    dirt = np.clip(smoothstep(0.7, 1.1, dirt_noise) + shore + shoulder, 0.0, 1.0)

    forest = fractal_field(rng, GRID, CELL, beta=2.1, cutoff=700.0, upsample=2)
    tree_density = smoothstep(-0.35, 0.35, forest) * (1.0 - 0.8 * rock)
    tree_density *= smoothstep(ROAD_HALF_WIDTH + 3.0, ROAD_HALF_WIDTH + 9.0, road_distance)
    tree_density *= smoothstep(water_level + 0.8, water_level + 2.5, height)
    tree_density *= 1.0 - smoothstep(0.9, 1.3, slope)

    boulder_noise = fractal_field(rng, GRID, CELL, beta=1.8, cutoff=250.0, upsample=2)
    boulder_density = 0.25 + 0.55 * rock + 0.5 * smoothstep(0.2, 1.1, boulder_noise)
    boulder_density *= smoothstep(ROAD_HALF_WIDTH + 1.0, ROAD_HALF_WIDTH + 4.0, road_distance)
    boulder_density *= smoothstep(water_level - 0.2, water_level + 0.6, height)
    boulder_density = np.clip(boulder_density, 0.0, 1.0)

    tint = np.tanh(fractal_field(rng, GRID, CELL, beta=2.0, cutoff=400.0, upsample=4))

    return Terrain(
        height=height,
        water_level=water_level,
        roads=roads,
        road_distance=road_distance,
        rock=rock,
        dirt=dirt,
        tree_density=tree_density,
        boulder_density=boulder_density,
        forest_shade=np.zeros_like(height),
        tint=tint,
    )


def finish_forest_shade(terrain: Terrain) -> None:
    """Blurred tree cover, computed once the densities are final (after the building clearings)."""
    terrain.forest_shade = np.clip(blur_periodic_2d(terrain.tree_density, sigma_cells=1.5), 0.0, 1.0)
