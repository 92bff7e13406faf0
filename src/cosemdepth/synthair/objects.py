"""Trees and boulders: a periodic tile of object height fields, repeated over the world and thinned by densities.

The tile holds two layers (trees, boulders). Every object has a gate value ``u`` in ``[0, 1)``; at a world point
with density ``d`` (from the terrain's density fields) the object's height is scaled by
``clamp((d - u) * GATE_SHARPNESS, 0, 1)``, so an object exists where ``d > u`` and shrinks smoothly to nothing at the
edge of a forest or of a boulder field (no vertical cuts in the height field).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .terrain import CELL

#: Texels per tile side and metres per texel (the tile is TILE * TEXEL = 256 m wide).
TILE = 1024
TEXEL = 0.25
TILE_PERIOD = TILE * TEXEL
GATE_SHARPNESS = 8.0
#: Density levels of the per-cell object envelope.
ENVELOPE_LEVELS = 17

#: Object kinds (layers).
TREE, BOULDER = 0, 1


@dataclass
class ObjectTile:
    height: np.ndarray  # [2, TILE, TILE] object height above the terrain, metres (layer 0 trees, 1 boulders)
    gate: np.ndarray  # [2, TILE, TILE] gate value of the object covering the texel (2.0 where none)
    ident: np.ndarray  # [2, TILE, TILE] random value in [0, 1) of the covering object (colour variation)
    top: np.ndarray  # [2, TILE, TILE] full height of the covering object (for self-shading), metres
    grad: np.ndarray  # [2, 2, TILE, TILE] d height / d (x, y) per layer
    cell_envelope: np.ndarray  # [2, Q, C, C] per world cell (C = TILE_PERIOD / CELL): max gated object height
    #                            over the texels a bilinear sample in the cell touches, for density q / (Q - 1)


def _rasterize(layer_h, layer_g, layer_id, layer_top, cx, cy, radius, profile, gate, ident, top):
    """Max-composite one object (a radial profile) into the periodic tile layers (texel grid)."""
    r_tex = int(np.ceil(radius / TEXEL)) + 1
    ci, cj = cx / TEXEL, cy / TEXEL
    ii = np.arange(int(np.floor(ci)) - r_tex, int(np.floor(ci)) + r_tex + 2)
    jj = np.arange(int(np.floor(cj)) - r_tex, int(np.floor(cj)) + r_tex + 2)
    di = (ii - ci)[:, None] * TEXEL
    dj = (jj - cj)[None, :] * TEXEL
    h = profile(di, dj)
    ii %= TILE
    jj %= TILE
    sub = np.ix_(ii, jj)
    old = layer_h[sub]
    win = h > old
    layer_h[sub] = np.where(win, h, old)
    layer_g[sub] = np.where(win, gate, layer_g[sub])
    layer_id[sub] = np.where(win, ident, layer_id[sub])
    layer_top[sub] = np.where(win, top, layer_top[sub])


def _jittered(rng, cells: int):
    """One point per cell of a ``cells x cells`` grid over the tile, and each point's nearest-neighbour distance
    (periodic)."""
    step = TILE_PERIOD / cells
    gi, gj = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
    px = ((gi + rng.uniform(0.1, 0.9, gi.shape)) * step).ravel()
    py = ((gj + rng.uniform(0.1, 0.9, gj.shape)) * step).ravel()
    dx = np.abs(px[:, None] - px[None, :])
    dy = np.abs(py[:, None] - py[None, :])
    dx = np.minimum(dx, TILE_PERIOD - dx)
    dy = np.minimum(dy, TILE_PERIOD - dy)
    d = np.hypot(dx, dy)
    np.fill_diagonal(d, np.inf)
    return px, py, d.min(axis=1)


def build_object_tile(rng: np.random.Generator) -> ObjectTile:
    h = np.zeros((2, TILE, TILE))
    g = np.full((2, TILE, TILE), 2.0)
    ident = np.zeros((2, TILE, TILE))
    top = np.zeros((2, TILE, TILE))

    # Trees: conifers (cones) and broadleaves (domes), 4.6 m apart on average.
    px, py, nn = _jittered(rng, 56)
    for x, y, d in zip(px, py, nn):
        conifer = rng.uniform() < 0.6
        if conifer:
            height = rng.uniform(7.0, 17.0)
            radius = min(rng.uniform(2.0, 3.4), 0.6 * d)
        else:
            height = rng.uniform(6.0, 13.0)
            radius = min(rng.uniform(2.6, 4.4), 0.6 * d)
        radius = max(radius, 1.2)
        lobes = rng.integers(4, 8)
        phase = rng.uniform(0, 2 * np.pi)
        wobble = rng.uniform(0.04, 0.12)

        def profile(di, dj, H=height, R=radius, con=conifer, k=lobes, ph=phase, w=wobble):
            r = np.hypot(di, dj) / (R * (1.0 + w * np.sin(k * np.arctan2(dj, di) + ph)))
            inside = np.clip(1.0 - r, 0.0, 1.0)
            if con:
                return H * inside**0.8
            return H * np.sqrt(np.clip(1.0 - r * r, 0.0, 1.0)) ** 0.7

        _rasterize(
            h[TREE], g[TREE], ident[TREE], top[TREE], x, y, radius * 1.15, profile, rng.uniform(), rng.uniform(), height
        )

    # Boulders: irregular flattened domes, 0.6 to 3.2 m in radius, 7.3 m apart on average.
    px, py, nn = _jittered(rng, 35)
    for x, y, d in zip(px, py, nn):
        radius = min(0.6 + 2.6 * rng.uniform() ** 1.4, 0.45 * d)
        height = radius * rng.uniform(0.55, 0.95)
        ph1, ph2 = rng.uniform(0, 2 * np.pi, 2)

        def profile(di, dj, H=height, R=radius, a=ph1, b=ph2):
            ang = np.arctan2(dj, di)
            rr = np.hypot(di, dj) / (R * (1.0 + 0.16 * np.sin(3 * ang + a) + 0.08 * np.sin(5 * ang + b)))
            return np.maximum(H * (np.sqrt(np.clip(1.0 - rr * rr, 0.0, 1.0)) * 1.2 - 0.2), 0.0)

        _rasterize(
            h[BOULDER],
            g[BOULDER],
            ident[BOULDER],
            top[BOULDER],
            x,
            y,
            radius * 1.3,
            profile,
            rng.uniform(),
            rng.uniform(),
            height,
        )

    grad = np.stack(
        [
            np.stack(
                [
                    (np.roll(layer, -1, 0) - np.roll(layer, 1, 0)) / (2 * TEXEL),
                    (np.roll(layer, -1, 1) - np.roll(layer, 1, 1)) / (2 * TEXEL),
                ]
            )
            for layer in h
        ]
    )

    # Per world cell (CELL metres) and density level: the largest gated height a sample in the cell can reach
    # (the gate grows with the density, so the envelope of density d is the value at the next level above d).
    per = int(round(CELL / TEXEL))
    c = TILE // per
    envelope = np.zeros((2, ENVELOPE_LEVELS, c, c))
    for layer in range(2):
        for q in range(ENVELOPE_LEVELS):
            dens = q / (ENVELOPE_LEVELS - 1)
            gated = h[layer] * np.clip((dens - g[layer]) * GATE_SHARPNESS, 0.0, 1.0)
            # include the far-corner texel row/column of each cell
            gated = np.maximum(gated, np.roll(gated, -1, 0))
            gated = np.maximum(gated, np.roll(gated, -1, 1))
            envelope[layer, q] = gated.reshape(c, per, c, per).max(axis=(1, 3))
    return ObjectTile(
        height=h.astype(np.float32),
        gate=g.astype(np.float32),
        ident=ident.astype(np.float32),
        top=top.astype(np.float32),
        grad=grad.astype(np.float32),
        cell_envelope=envelope,
    )
