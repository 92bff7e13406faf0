"""Buildings: convex polyhedra (boxes with flat or gabled roofs) in villages along the roads and on farms.

A building is the set of points ``p = (x, y, up)`` with ``n_k . p <= d_k`` for its 7 planes (4 walls, floor, and a
flat roof or two roof slopes; a flat roof repeats its top plane).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .terrain import CELL, GRID, PERIOD, ROAD_HALF_WIDTH, Terrain

N_PLANES = 7

WALL_COLOURS = np.array(
    [
        (0.62, 0.60, 0.55),
        (0.60, 0.53, 0.44),
        (0.50, 0.29, 0.22),
        (0.46, 0.46, 0.45),
        (0.66, 0.63, 0.54),
        (0.45, 0.37, 0.29),
    ]
)
ROOF_COLOURS = np.array(
    [(0.55, 0.22, 0.15), (0.30, 0.30, 0.32), (0.42, 0.30, 0.22), (0.62, 0.32, 0.20), (0.25, 0.27, 0.30)]
)


@dataclass
class Buildings:
    planes: np.ndarray  # [B, 7, 4] (nx, ny, nz, d) in world coordinates (x, y, up); inside: n . p <= d
    roof: np.ndarray  # [B, 7] bool, the plane is a roof
    corners: np.ndarray  # [B, 8, 3] bounding box corners (for culling and screen bounds)
    center: np.ndarray  # [B, 3] bounding sphere centre
    radius: np.ndarray  # [B] bounding sphere radius
    top: np.ndarray  # [B] highest point (up), metres
    wall_colour: np.ndarray  # [B, 3] linear RGB albedo
    roof_colour: np.ndarray  # [B, 3]

    def __len__(self) -> int:
        return len(self.planes)


def _make_building(
    kind: str,
    cx: float,
    cy: float,
    yaw: float,
    length: float,
    width: float,
    wall: float,
    rise: float,
    ground_lo: float,
    ground_hi: float,
):
    a, b = length / 2, width / 2
    ux = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    uy = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    up = np.array([0.0, 0.0, 1.0])
    c = np.array([cx, cy, 0.0])
    z0, eave = ground_lo - 1.0, ground_hi + wall
    planes = [
        (ux, ux @ c + a),
        (-ux, -ux @ c + a),
        (uy, uy @ c + b),
        (-uy, -uy @ c + b),
        (-up, -z0),
    ]
    roof = [False] * 5
    if kind == "gable" and rise > 0:
        for side in (1.0, -1.0):
            n = side * uy * rise + up * b
            n = n / np.linalg.norm(n)
            p_eave = c + side * uy * b + up * eave
            planes.append((n, n @ p_eave))
            roof.append(True)
        top = eave + rise
    else:
        planes += [(up, eave), (up, eave)]
        roof += [True, True]
        top = eave
    arr = np.array([[*n, d] for n, d in planes])
    corners = np.array([c + sx * a * ux + sy * b * uy + up * z for sx in (-1, 1) for sy in (-1, 1) for z in (z0, top)])
    center = corners.mean(axis=0)
    radius = float(np.linalg.norm(corners - center, axis=1).max())
    return arr, np.array(roof), corners, center, radius, top


_TYPES = {
    # name: (roof kind, length range, width range, wall height range, roof pitch range in degrees)
    "house": ("gable", (9, 15), (7, 10), (3.0, 6.0), (28, 42)),
    "barn": ("gable", (16, 30), (10, 15), (5.0, 8.0), (20, 30)),
    "block": ("flat", (12, 24), (10, 14), (7.0, 13.0), (0, 0)),
    "tower": ("flat", (4, 6), (4, 6), (8.0, 14.0), (0, 0)),
    "shed": ("flat", (5, 9), (4, 6), (2.5, 3.5), (0, 0)),
}


class _Placer:
    def __init__(self, rng: np.random.Generator, terrain: Terrain):
        self.rng, self.terrain = rng, terrain
        self.items: list[tuple] = []
        self.disks: list[tuple[float, float, float]] = []

    def try_place(self, kind_name: str, cx: float, cy: float, yaw: float) -> bool:
        rng, t = self.rng, self.terrain
        roof_kind, lr, wr, hr, pr = _TYPES[kind_name]
        length, width = rng.uniform(*lr), rng.uniform(*wr)
        wall = rng.uniform(*hr)
        rise = width / 2 * np.tan(np.radians(rng.uniform(*pr))) if roof_kind == "gable" else 0.0
        half_diag = 0.5 * np.hypot(length, width)
        for ox, oy, r in self.disks:
            dx = (cx - ox + PERIOD / 2) % PERIOD - PERIOD / 2
            dy = (cy - oy + PERIOD / 2) % PERIOD - PERIOD / 2
            if np.hypot(dx, dy) < r + half_diag + 4.0:
                return False
        u = np.array([-0.5, 0.0, 0.5])
        sx, sy = np.meshgrid(u * length, u * width, indexing="ij")
        px = cx + sx * np.cos(yaw) - sy * np.sin(yaw)
        py = cy + sx * np.sin(yaw) + sy * np.cos(yaw)
        g = t.height_at(px, py)
        if g.max() - g.min() > 3.5 or g.min() < t.water_level + 1.0:
            return False
        road_d, _ = t.roads.distance(px, py)
        if road_d.min() < ROAD_HALF_WIDTH + 2.5:
            return False
        self.items.append(
            (_make_building(roof_kind, cx, cy, yaw, length, width, wall, rise, g.min(), g.max()), kind_name)
        )
        self.disks.append((cx, cy, half_diag))
        return True


def build_buildings(rng: np.random.Generator, terrain: Terrain, villages: int = 40, farms: int = 90) -> Buildings:
    """Place villages along the roads and farms in the open; clears trees and boulders around every building."""
    placer = _Placer(rng, terrain)
    roads = terrain.roads
    for _ in range(villages):
        k = int(rng.integers(len(roads.axis)))
        s0 = rng.uniform(0, PERIOD)
        for _ in range(int(rng.integers(10, 22))):
            s = s0 + rng.uniform(-110, 110)
            x, y = roads.point(k, s)
            tx, ty = roads.tangent(k, s)
            side = rng.choice([-1.0, 1.0])
            setback = rng.uniform(14, 34)
            cx, cy = x - side * ty * setback, y + side * tx * setback
            yaw = np.arctan2(ty, tx) + (np.pi / 2 if rng.uniform() < 0.3 else 0.0) + rng.normal(0, 0.05)
            kind = rng.choice(
                ["house", "house", "house", "barn", "block", "shed", "tower"],
            )
            placer.try_place(str(kind), cx, cy, yaw)
    for _ in range(farms):
        cx, cy = rng.uniform(0, PERIOD, 2)
        yaw0 = rng.uniform(0, np.pi)
        for j in range(int(rng.integers(1, 4))):
            kind = "house" if j == 0 else str(rng.choice(["barn", "shed", "tower"]))
            ang = rng.uniform(0, 2 * np.pi)
            dist = 0.0 if j == 0 else rng.uniform(20, 45)
            placer.try_place(kind, cx + dist * np.cos(ang), cy + dist * np.sin(ang), yaw0 + rng.choice([0, np.pi / 2]))

    b = len(placer.items)
    planes = np.zeros((b, N_PLANES, 4))
    roof = np.zeros((b, N_PLANES), dtype=bool)
    corners = np.zeros((b, 8, 3))
    center = np.zeros((b, 3))
    radius = np.zeros(b)
    top = np.zeros(b)
    for i, ((arr, rf, cr, ce, ra, tp), _kind) in enumerate(placer.items):
        planes[i], roof[i], corners[i], center[i], radius[i], top[i] = arr, rf, cr, ce, ra, tp
    wall_colour = WALL_COLOURS[rng.integers(len(WALL_COLOURS), size=b)] * rng.uniform(0.9, 1.1, (b, 1))
    roof_colour = ROOF_COLOURS[rng.integers(len(ROOF_COLOURS), size=b)] * rng.uniform(0.85, 1.15, (b, 1))
    out = Buildings(planes, roof, corners, center, radius, top, np.clip(wall_colour, 0, 1), np.clip(roof_colour, 0, 1))
    _clear_around(terrain, out)
    return out


def _clear_around(terrain: Terrain, buildings: Buildings, margin: float = 7.0) -> None:
    """No trees or boulders within ``margin`` metres of a building's footprint."""
    for i in range(len(buildings)):
        cx, cy = buildings.center[i, :2]
        r = float(np.linalg.norm(buildings.corners[i, 0, :2] - buildings.center[i, :2])) + margin
        n = int(np.ceil(r / CELL)) + 1
        ii = (np.arange(-n, n + 1) + int(round(cx / CELL))) % GRID
        jj = (np.arange(-n, n + 1) + int(round(cy / CELL))) % GRID
        gx = (np.arange(-n, n + 1) + int(round(cx / CELL))) * CELL - cx
        gy = (np.arange(-n, n + 1) + int(round(cy / CELL))) * CELL - cy
        d = np.hypot(gx[:, None], gy[None, :])
        keep = np.clip((d - (r - margin)) / margin, 0.0, 1.0)
        sub = np.ix_(ii, jj)
        terrain.tree_density[sub] *= keep
        terrain.boulder_density[sub] *= keep
