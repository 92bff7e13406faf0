"""Ray casting against the SynthAir world (torch, CPU, float32, vectorised over rays).

The surface is the height field ``S(x, y) = max(T + obj, W)`` (terrain ``T``, gated tree/boulder heights ``obj``,
water level ``W``). Rays traverse a max pyramid of ``S`` (cells of 2 m to 256 m): a ray skips a cell whenever its
lowest point in the cell is above the cell's maximum, goes up a level when it leaves the parent cell and down a
level when it cannot skip. In a 2 m cell that it cannot skip, the ray is sampled between the heights of the cell's
maximum and minimum, and the first sign change of ``ray height - S`` is refined by bisection and a false-position
step. Rays start where cones traced for 8 x 8 pixel blocks (:func:`beam_start`) prove them clear, and the few rays
still searching after ``TAIL_ITERATION`` steps (long grazing ones) are finished by dense sampling. Trees far from
the camera morph into a smooth canopy (:class:`Lod`). Buildings are convex polyhedra intersected analytically.

Every ray's result depends on that ray alone (not on the other rays of the call), so frames can be batched.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .objects import GATE_SHARPNESS, TEXEL, TILE
from .terrain import CELL, GRID
from .world import LEVELS, World

#: Rays stop at this distance (metres); the world repeats every 4096 m, so this stays below half of it.
T_MAX = 2000.0
#: Samples per 2 m cell where a ray may hit, and bisection steps.
FINE_SAMPLES = 3
BISECTIONS = 5
_NUDGE = 2e-3
_MAX_ITERATIONS = 4000
_START_LEVEL = 3
#: Rays still searching after this many steps are finished by dense sampling (see _scan_tail).
TAIL_ITERATION = 100
SCAN_CHUNK = 32
SCAN_MIN_STEP = 0.5
SCAN_PIXEL_FRACTION = 0.5
#: Level of detail (see Lod): pixel footprints (metres) where trees start to morph into the canopy, and over which.
LOD_START, LOD_WIDTH = 0.6, 1.8


def bilinear_corners(table: torch.Tensor, n: int, g: torch.Tensor):
    """Gather the 4 corner columns of a periodic grid table around grid coordinates.

    Args:
        table: ``[C, n * n]`` (channel-first; cell ``(i, j)`` is column ``i * n + j``).
        n: cells per side, a power of two.
        g: ``[2, R]`` grid coordinates (cell units, any real values; the grid wraps).
    Returns:
        ``(values [C, 4, R], weights [4, R])``, corners in the order (i0, j0), (i1, j0), (i0, j1), (i1, j1).
    """
    fl = torch.floor(g)
    frac = g - fl
    mask = n - 1  # n is a power of two: & wraps negative indices too
    i0 = fl.long() & mask  # [2, R]
    i1 = (i0 + 1) & mask
    rows = torch.stack([i0[0], i1[0]]) * n  # [2, R] (i0 n, i1 n)
    cols = torch.stack([i0[1], i1[1]])  # [2, R] (j0, j1)
    idx = (rows.unsqueeze(0) + cols.unsqueeze(1)).reshape(-1)  # order (j0: i0, i1), (j1: i0, i1)
    vals = table.index_select(1, idx).view(table.shape[0], 4, -1)
    a = torch.stack([1 - frac[0], frac[0]])  # weights along i
    b = torch.stack([1 - frac[1], frac[1]])  # along j
    w = (b.unsqueeze(1) * a.unsqueeze(0)).reshape(4, -1)
    return vals, w


@dataclass
class SurfaceSample:
    """The height field at points ``[R]``, with what the shader needs."""

    terrain: torch.Tensor  # terrain height T
    tree: torch.Tensor  # gated tree height above T (level of detail applied)
    boulder: torch.Tensor  # gated boulder height above T (level of detail applied)
    tree_density: torch.Tensor
    boulder_density: torch.Tensor
    lod: torch.Tensor  # level-of-detail weight in [0, 1] (0: every tree and boulder, 1: smooth canopy only)
    gate_tree: torch.Tensor  # [4, R] per tile corner
    gate_boulder: torch.Tensor  # [4, R]
    tile_values: torch.Tensor  # [4, 4, R] tile surface values (tree h, tree gate, boulder h, boulder gate) per corner
    tile_weights: torch.Tensor  # [4, R]
    tile_coords: torch.Tensor  # [2, R] tile texel coordinates


@dataclass(frozen=True)
class Lod:
    """Level of detail of the trees and boulders for one camera.

    Where a pixel covers more than ``LOD_START`` metres (at horizontal distance ``r`` from the camera a pixel
    covers ``r * pixel_angle``), trees morph into a smooth canopy, fully at ``LOD_START + LOD_WIDTH``. Far trees
    thus have no silhouettes smaller than a pixel to alias from frame to frame (boulders keep their shape; their
    colour is averaged in the far field, see shading).
    The surface never rises above its full-detail envelope (the canopy is part of it).
    """

    camera_xy: torch.Tensor  # [2, R] (or [2, 1]) wrapped camera position of each sample
    pixel_angle: float  # radians per pixel

    def weight(self, xy: torch.Tensor) -> torch.Tensor:
        dxy = xy - self.camera_xy
        r = (dxy * dxy).sum(0).sqrt()
        return ((r * self.pixel_angle - LOD_START) / LOD_WIDTH).clamp_(0.0, 1.0)


def sample_surface(world: World, xy: torch.Tensor, lod: Lod | None = None) -> SurfaceSample:
    """Sample the height field at world points ``xy [2, R]`` (with ``lod``: as seen from that camera)."""
    vals, w = bilinear_corners(world.surf, GRID, xy / CELL)
    terrain, dens_t, dens_b, canopy = (vals * w).sum(1)
    tc = xy / TEXEL
    tv, tw = bilinear_corners(world.tile_surf, TILE, tc)
    gate_t = ((dens_t - tv[1]) * GATE_SHARPNESS).clamp_(0.0, 1.0)
    gate_b = ((dens_b - tv[3]) * GATE_SHARPNESS).clamp_(0.0, 1.0)
    tree = (tv[0] * gate_t * tw).sum(0)
    boulder = (tv[2] * gate_b * tw).sum(0)
    if lod is None:
        lw = torch.zeros_like(tree)
    else:
        lw = lod.weight(xy)
        tree = tree + (canopy - tree) * lw
    return SurfaceSample(terrain, tree, boulder, dens_t, dens_b, lw, gate_t, gate_b, tv, tw, tc)


def surface_height(world: World, xy: torch.Tensor, lod: Lod | None = None) -> torch.Tensor:
    """``S(x, y) = max(T + max(tree, boulder), W)`` at world points ``xy [2, R]`` (with ``lod``: as seen from
    that camera)."""
    vals, w = bilinear_corners(world.surf, GRID, xy / CELL)
    terrain, dens_t, dens_b, canopy = (vals * w).sum(1)
    tv, tw = bilinear_corners(world.tile_surf, TILE, xy / TEXEL)
    tree = (tv[0] * ((dens_t - tv[1]) * GATE_SHARPNESS).clamp_(0.0, 1.0) * tw).sum(0)
    boulder = (tv[2] * ((dens_b - tv[3]) * GATE_SHARPNESS).clamp_(0.0, 1.0) * tw).sum(0)
    if lod is not None:
        lw = lod.weight(xy)
        tree = tree + (canopy - tree) * lw
    return (terrain + torch.maximum(tree, boulder)).clamp_(min=world.water_level)


def beam_start(world: World, origins: torch.Tensor, d: torch.Tensor, block: int = 8, exact_cone: bool = False):
    """Conservative start distances for blocks of rays (cone tracing through the dilated max pyramid).

    The rays of a ``block x block`` pixel block have unit directions within ``kappa`` of the block's axis ``a``
    (chord length), so at any ray parameter ``t`` all their points lie in the ball of radius ``kappa t`` around
    ``o + t a``. The axis is traversed like a ray, but a cell is skipped only if the ball stays above the maximum
    of the cell *and its 8 neighbours* (valid while the ball radius is at most the cell size). Where that fails
    at the finest usable level, every ray of the block is known to be clear of the surface before the axis
    parameter reached so far.

    Args:
        origins: ``[B, 3]`` ray origin (x, y, up) of each image, x and y wrapped.
        d: ``[B, H, W, 3]`` unit ray directions of the images.
        exact_cone: measure ``kappa`` over every ray of a block instead of its 4 corners (a pinhole block's rays
            are farthest from the axis at its corners; a distorting lens's need not be).
    Returns:
        ``(t_start [B, H, W], level_start [B, H, W] float)``.
    """
    nbatch, h, w, _ = d.shape
    hb, wb = -(-h // block), -(-w // block)
    pad = torch.nn.functional.pad(d.permute(0, 3, 1, 2), (0, wb * block - w, 0, hb * block - h), mode="replicate")
    pad = pad.permute(1, 0, 2, 3)  # [3, B, H', W']
    corners = pad.reshape(3, nbatch, hb, block, wb, block)[:, :, :, [0, -1]][:, :, :, :, :, [0, -1]]
    axis = corners.sum(dim=(3, 5))
    axis = axis / axis.norm(dim=0, keepdim=True)  # [3, B, hb, wb]
    if exact_cone:
        rays = pad.reshape(3, nbatch, hb, block, wb, block)
        chord = (rays - axis[:, :, :, None, :, None]).norm(dim=0).amax(dim=(2, 4))  # [B, hb, wb]
    else:
        chord = (corners - axis[:, :, :, None, :, None]).norm(dim=0).amax(dim=(2, 4))  # [B, hb, wb]
    kappa = (chord * 1.05 + 1e-4).reshape(-1)
    a = axis.reshape(3, -1)
    nb = a.shape[1]
    org = origins.float().T.repeat_interleave(hb * wb, dim=1)  # [3, nb]
    o_xy, oz = org[:2], org[2]
    tiny = 1e-9
    axy = torch.where(a[:2].abs() < tiny, torch.full_like(a[:2], tiny), a[:2])
    az = a[2]
    inv = 1.0 / axy
    step = (axy > 0).float()
    nudge = torch.where(axy > 0, _NUDGE, -_NUDGE)
    t = torch.zeros(nb)
    lev = torch.full((nb,), float(LEVELS))
    t_out = torch.zeros(nb)
    lev_out = torch.zeros(nb)
    active = torch.arange(nb)
    top = world.max_height + 1.0
    sizes = world.level_size
    for _ in range(_MAX_ITERATIONS):
        if active.numel() == 0:
            break
        li = lev.long()
        cs = sizes[li]
        n = world.level_cells[li]
        ixy = torch.floor((o_xy + t * axy + nudge) / cs)
        txy = ((ixy + step) * cs - o_xy) * inv
        te = torch.minimum(txy.min(0).values, torch.full_like(t, T_MAX))
        rho = kappa * te
        fits = rho + 4 * _NUDGE <= cs
        z_low = oz + torch.minimum(t * az, te * az) - rho
        cij = ixy.long() & (n - 1)
        m = world.env_dilated[world.level_offset[li] + cij[0] * n + cij[1]]
        clear = fits & (z_low > m)
        finer_ok = (li > 0) & (rho + 4 * _NUDGE <= sizes[(li - 1).clamp(min=0)])
        go_down = (~clear) & fits & finer_ok
        go_up = (~clear) & (~fits) & (li < LEVELS)
        stop = (~clear) & ~go_down & ~go_up
        new_t = torch.where(clear, torch.maximum(te, t + 1e-4), t)
        new_lev = torch.where(clear, lev, torch.where(go_down, lev - 1, torch.where(go_up, lev + 1, lev)))
        finished = stop | (new_t >= T_MAX) | ((az >= 0) & (oz + new_t * az - kappa * new_t > top))
        t_out[active] = new_t
        lev_out[active] = new_lev
        keep = (~finished).nonzero().squeeze(1)
        active = active[keep]
        t, lev, kappa = new_t[keep], new_lev[keep], kappa[keep]
        axy, az, inv, step, nudge = axy[:, keep], az[keep], inv[:, keep], step[:, keep], nudge[:, keep]
        o_xy, oz = o_xy[:, keep], oz[keep]

    def to_image(v):
        v = v.reshape(nbatch, hb, 1, wb, 1).expand(nbatch, hb, block, wb, block)
        return v.reshape(nbatch, hb * block, wb * block)[:, :h, :w]

    return to_image(t_out), to_image(lev_out)


# rows of the per-ray state of march_heightfield
_O, _OZ, _D, _INV, _STEP, _NUDGE_ROWS = slice(0, 2), 2, slice(3, 5), slice(5, 7), slice(7, 9), slice(9, 11)
_DZ, _TLIM, _T, _LEV = 11, 12, 13, 14


def march_heightfield(
    world: World,
    origin: torch.Tensor,
    d: torch.Tensor,
    t_limit: torch.Tensor,
    t_start: torch.Tensor | None = None,
    level_start: torch.Tensor | None = None,
    pixel_angle: float | None = None,
) -> torch.Tensor:
    """First intersection of rays with the height field.

    Args:
        origin: ``[3]`` or ``[R, 3]`` float32 ray origins ``(x, y, up)``, with ``x, y`` wrapped into
            ``[0, PERIOD)`` (one per ray lets several cameras share one call).
        d: ``[R, 3]`` float32 unit directions.
        t_limit: ``[R]`` the search stops there (``T_MAX`` or a nearer building).
        t_start, level_start: ``[R]`` where to start (no hit before ``t_start``; see :func:`beam_start`).
        pixel_angle: radians per pixel, for the level of detail (:class:`Lod`); None: full detail everywhere.
    Returns:
        ``[R]`` hit distance along the ray, ``inf`` where there is none before ``t_limit``.
    """
    n_rays = d.shape[0]
    org = origin.float().reshape(-1, 3).expand(n_rays, 3).T  # [3, R]
    tiny = 1e-9
    dxy = d[:, :2].T.contiguous()
    dxy = torch.where(dxy.abs() < tiny, torch.full_like(dxy, tiny), dxy)
    positive = dxy > 0
    # per-ray state, one row per quantity (x and y rows side by side), so that dropping finished rays is a single
    # indexing operation and x/y work is a single [2, R] operation
    state = torch.cat(
        [
            org,
            dxy,
            1.0 / dxy,
            positive.float(),
            torch.where(positive, _NUDGE, -_NUDGE),
            d[:, 2].reshape(1, -1),
            t_limit.reshape(1, -1).float(),
            torch.zeros(1, n_rays) if t_start is None else t_start.reshape(1, -1).float(),
            torch.full((1, n_rays), float(_START_LEVEL)) if level_start is None else level_start.reshape(1, -1),
        ]
    )
    # rays already past their limit (a nearer building) or starting beyond it are done
    alive = (state[_T] < state[_TLIM]).nonzero().squeeze(1)
    ids = alive
    state = state[:, alive]
    top = world.max_height + 1.0
    bracket = torch.full((2, n_rays), float("inf"))
    stats.update(iterations=0, ray_steps=0, fine_rays=0)

    for it in range(_MAX_ITERATIONS):
        if ids.numel() == 0:
            break
        if it >= TAIL_ITERATION:
            # the last rays (long grazing ones): per-iteration overhead would dominate, so sample them densely. The
            # switch depends on the iteration only (every live ray takes one step per iteration), so a ray's result
            # does not depend on the other rays of the batch.
            _scan_tail(world, state, ids, bracket, pixel_angle)
            break
        stats["iterations"] += 1
        stats["ray_steps"] += ids.numel()
        o_xy, oz, dxy, inv = state[_O], state[_OZ], state[_D], state[_INV]
        step, nudge = state[_STEP], state[_NUDGE_ROWS]
        dz, tlim, t, lev = state[_DZ], state[_TLIM], state[_T], state[_LEV]
        li = lev.long()
        cs = world.level_size[li]
        n = world.level_cells[li]
        ixy = torch.floor((o_xy + t * dxy + nudge) / cs)  # [2, R] cell indices
        txy = ((ixy + step) * cs - o_xy) * inv  # [2, R] exit distances through the x and y faces
        te, exit_axis = txy.min(0)
        te = torch.minimum(te, tlim)
        z_low = oz + torch.where(dz < 0, te, t) * dz
        ij = ixy.long()
        cell_ij = ij & (n - 1)  # level sizes are powers of two
        cell = world.level_offset[li] + cell_ij[0] * n + cell_ij[1]
        m = world.env_max[cell]
        above = z_low > m

        advanced = torch.maximum(te, t + 1e-4)
        # after an advance go up a level only if the ray left the parent cell (else the parent, which could not
        # be skipped, would be tested again for nothing)
        odd = (ij & 1).float() == step  # [2, R] the exit face is also a face of the parent cell
        leaves_parent = odd.gather(0, exit_axis.unsqueeze(0)).squeeze(0)
        lev_after = torch.where(leaves_parent, (lev + 1).clamp_(max=float(LEVELS)), lev)
        new_t = torch.where(above, advanced, t)
        new_lev = torch.where(above, lev_after, lev - 1)
        done = torch.zeros_like(above)
        f_idx = ((~above) & (li == 0)).nonzero().squeeze(1)
        if f_idx.numel():
            stats["fine_rays"] += f_idx.numel()
            fs = state[:, f_idx]
            fc = cell[f_idx]
            lod = None if pixel_angle is None else Lod(fs[_O], float(pixel_angle))
            lo, hi = _fine_test(
                world,
                fs[_O],
                fs[_OZ],
                fs[_D],
                fs[_DZ],
                fs[_T],
                te[f_idx],
                m[f_idx],
                world.env_min0[fc],
                world.env_objects[fc],
                lod,
            )
            got = torch.isfinite(hi)
            gi = f_idx[got]
            bracket[0, ids[gi]] = lo[got]
            bracket[1, ids[gi]] = hi[got]
            new_t[f_idx] = advanced[f_idx]
            new_lev[f_idx] = lev_after[f_idx]
            done[gi] = True

        done |= new_t >= tlim
        done |= (dz >= 0) & (oz + new_t * dz > top)
        state[_T] = new_t
        state[_LEV] = new_lev
        keep = (~done).nonzero().squeeze(1)
        ids = ids[keep]
        state = state[:, keep]

    return _refine(world, org, d, bracket, pixel_angle)


def _refine(world, org, d, bracket, pixel_angle):
    """Refine brackets ``f(lo) > 0 >= f(hi)`` of ``f(t) = ray height - S``: bisection, then one false-position
    step between the last two evaluated points."""
    t_hit = torch.full((d.shape[0],), float("inf"))
    h = torch.isfinite(bracket[1]).nonzero().squeeze(1)
    if h.numel() == 0:
        return t_hit
    lo, hi = bracket[0, h], bracket[1, h]
    hd = d[h].T.contiguous()
    dxy, dz = hd[:2], hd[2]
    o_xy, oz = org[:2, h], org[2, h]
    lod = None if pixel_angle is None else Lod(o_xy, float(pixel_angle))
    nan = torch.full_like(lo, float("nan"))
    f_lo, f_hi = nan, nan
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        fm = (oz + mid * dz) - surface_height(world, o_xy + mid * dxy, lod)
        under = fm <= 0
        hi = torch.where(under, mid, hi)
        lo = torch.where(under, lo, mid)
        f_hi = torch.where(under, fm, f_hi)
        f_lo = torch.where(under, f_lo, fm)
    # evaluate the ends that no bisection step landed on, then one false-position step
    miss = torch.isnan(f_lo) | torch.isnan(f_hi)
    m = miss.nonzero().squeeze(1)
    if m.numel():
        ends = torch.cat([lo[m], hi[m]])
        mm = torch.cat([m, m])
        lod_m = None if lod is None else Lod(lod.camera_xy[:, mm], lod.pixel_angle)
        fe = (oz[mm] + ends * dz[mm]) - surface_height(world, o_xy[:, mm] + ends * dxy[:, mm], lod_m)
        f_lo[m] = torch.where(torch.isnan(f_lo[m]), fe[: m.numel()], f_lo[m])
        f_hi[m] = torch.where(torch.isnan(f_hi[m]), fe[m.numel() :], f_hi[m])
    both = (f_lo > 0) & (f_hi <= 0)
    frac = torch.where(both, f_lo / torch.where(both, f_lo - f_hi, torch.ones_like(f_lo)), torch.ones_like(lo))
    t_hit[h] = lo + (hi - lo) * frac.clamp(0.0, 1.0)
    return t_hit


def _first_true(b: torch.Tensor) -> torch.Tensor:
    """Index of the first True of each row of ``b [R, K]`` (``K`` where none); cheaper than a reduction for small K."""
    k = b.shape[1]
    first = torch.full((b.shape[0],), k, dtype=torch.int64)
    for j in range(k - 1, -1, -1):
        first = torch.where(b[:, j], j, first)
    return first


#: Counters of the last march_heightfield call (iterations, ray steps, fine tests), for benchmarks and tuning.
stats: dict[str, int] = {}


def _scan_tail(world, state, ids, bracket, pixel_angle):
    """Find the first crossing of the remaining rays by dense sampling from their current distance to their limit.

    Samples are ``max(SCAN_MIN_STEP, SCAN_PIXEL_FRACTION * t * pixel_angle)`` apart (at most half a pixel
    footprint), so only surface features smaller than about half a pixel can be missed. Writes ``bracket``.
    """
    angle = pixel_angle if pixel_angle is not None else 1.0 / 192.0
    frac = SCAN_PIXEL_FRACTION * angle
    o_xy, oz, dxy, dz = state[_O], state[_OZ], state[_D], state[_DZ]
    tlim, t = state[_TLIM], state[_T].clone()
    lod = None if pixel_angle is None else Lod(o_xy, float(pixel_angle))
    top = world.max_height + 1.0
    live = torch.arange(ids.numel())
    prev = t
    for _ in range(_MAX_ITERATIONS):
        if live.numel() == 0:
            break
        ts = []
        cur = prev
        for _k in range(SCAN_CHUNK):
            cur = cur + torch.clamp(cur * frac, min=SCAN_MIN_STEP)
            ts.append(cur)
        ts = torch.stack(ts, 1)  # [L, K]
        ts = torch.minimum(ts, tlim[live].unsqueeze(1))
        k = ts.shape[1]
        rows = live.repeat_interleave(k)
        flat = ts.reshape(-1)
        lod_rows = None if lod is None else Lod(o_xy[:, rows], lod.pixel_angle)
        f = (oz[rows] + flat * dz[rows]) - surface_height(world, o_xy[:, rows] + flat * dxy[:, rows], lod_rows)
        below = (f <= 0).view(-1, k)
        first = _first_true(below)
        hit = first < k
        if bool(hit.any()):
            hr = hit.nonzero().squeeze(1)
            kk = first[hr]
            hi_t = ts[hr, kk]
            lo_t = torch.where(kk > 0, ts[hr, (kk - 1).clamp(min=0)], prev[hr])
            bracket[0, ids[live[hr]]] = lo_t
            bracket[1, ids[live[hr]]] = hi_t
        last = ts[:, -1]
        gone = hit | (last >= tlim[live]) | ((dz[live] >= 0) & (oz[live] + last * dz[live] > top))
        keep = (~gone).nonzero().squeeze(1)
        live = live[keep]
        prev = last[keep]


def _fine_test(world, o_xy, oz, dxy, dz, t0, t1, m_max, m_min, has_obj, lod):
    # o_xy [2, F], oz [F]: per-ray origins
    """Search one 2 m cell for the first crossing of the ray below the surface.

    The ray is clipped to the part of the cell between the heights of the cell's maximum and minimum surface. In a
    cell without trees or boulders (a bilinear terrain patch or water) one sample at the end of that part decides;
    with objects, the part is sampled ``FINE_SAMPLES`` times.
    Returns the bracket ``(lo, hi)`` (``f(lo) > 0 >= f(hi)``), ``inf`` where there is no crossing.
    """
    falling = dz < 0
    rising = dz > 0
    safe_dz = torch.where(dz == 0, torch.ones_like(dz), dz)
    t_at_max = (m_max - oz) / safe_dz
    t_at_min = (m_min - oz) / safe_dz  # oz: [F]
    lo_t = torch.where(falling, torch.maximum(t0, t_at_max), t0)
    hi_t = torch.where(falling, torch.minimum(t1, t_at_min), t1)
    hi_t = torch.where(rising, torch.minimum(hi_t, t_at_max), hi_t)
    # a ray under the cell's minimum surface already (impossible for a consistent traversal) hits at once
    forced = falling & (t_at_min <= lo_t)
    hi_t = torch.where(forced, lo_t, hi_t)
    valid = (hi_t > lo_t) | forced
    # falling below the cell's minimum inside the cell: certainly under the surface there
    sure = falling & (t_at_min <= t1) & valid

    lo = torch.full_like(t0, float("inf"))
    hi = torch.full_like(t0, float("inf"))
    terrain_sure = sure & ~has_obj
    lo[terrain_sure] = lo_t[terrain_sure]
    hi[terrain_sure] = hi_t[terrain_sure]

    one = (valid & ~has_obj & ~sure).nonzero().squeeze(1)
    many = (valid & has_obj).nonzero().squeeze(1)
    k = torch.arange(1, FINE_SAMPLES + 1, dtype=torch.float32) / FINE_SAMPLES
    ts_many = lo_t[many].unsqueeze(1) + (hi_t[many] - lo_t[many]).unsqueeze(1) * k  # [Fm, K]
    ts = torch.cat([hi_t[one], ts_many.reshape(-1)])
    if ts.numel() == 0:
        return lo, hi
    rows = torch.cat([one, many.repeat_interleave(FINE_SAMPLES)])
    lod_rows = None if lod is None else Lod(lod.camera_xy[:, rows], lod.pixel_angle)
    f = (oz[rows] + ts * dz[rows]) - surface_height(world, o_xy[:, rows] + ts * dxy[:, rows], lod_rows)
    below = f <= 0
    n_one = one.numel()
    g1 = one[below[:n_one]]
    lo[g1] = lo_t[g1]
    hi[g1] = hi_t[g1]
    if many.numel():
        bm = below[n_one:].view(-1, FINE_SAMPLES)
        first = _first_true(bm)
        hit_rows = (first < FINE_SAMPLES).nonzero().squeeze(1)
        kk = first[hit_rows]
        gm = many[hit_rows]
        hi[gm] = ts_many[hit_rows, kk]
        lo[gm] = torch.where(kk > 0, ts_many[hit_rows, (kk - 1).clamp(min=0)], lo_t[gm])
    return lo, hi


def intersect_buildings(world: World, origin: torch.Tensor, d: torch.Tensor, rects, t_max: float = T_MAX):
    """Nearest building hit per ray.

    Args:
        origin: ``[3]`` ray origin (wrapped, as for :func:`march_heightfield`).
        d: ``[H, W, 3]`` unit directions.
        rects: list of ``(building index, shift [3], (r0, r1, c0, c1))``: the buildings to test, the periodic copy
            offset, and the pixel rectangle where the building may appear.
    Returns:
        ``t [H, W]`` (``inf`` for none), ``building [H, W]`` int64 (-1 for none), ``plane [H, W]`` int64.
    """
    h, w, _ = d.shape
    t_best = torch.full((h, w), float("inf"))
    b_best = torch.full((h, w), -1, dtype=torch.int64)
    p_best = torch.zeros((h, w), dtype=torch.int64)
    planes = torch.as_tensor(world.buildings.planes, dtype=torch.float32)
    for b, shift, (r0, r1, c0, c1) in rects:
        if r1 <= r0 or c1 <= c0:
            continue
        dd = d[r0:r1, c0:c1].reshape(-1, 3)
        pl = planes[b]  # [7, 4]
        n = pl[:, :3]
        # the copy of the building nearest the camera is the original moved by -shift
        off = pl[:, 3] - (n * shift).sum(1) - (n * origin).sum(1)  # [7] d - n . shift - n . o
        denom = dd[:, 0:1] * n[:, 0] + dd[:, 1:2] * n[:, 1] + dd[:, 2:3] * n[:, 2]  # [M, 7]
        with torch.no_grad():
            tp = off / torch.where(denom == 0, torch.full_like(denom, 1e-12), denom)
            entering = denom < 0
            exiting = denom > 0
            t_in = torch.where(entering, tp, torch.full_like(tp, -float("inf")))
            t_out = torch.where(exiting, tp, torch.full_like(tp, float("inf")))
            outside_parallel = ((denom == 0) & (off < 0)).any(1)
            t_enter, which = t_in.max(1)
            t_exit = t_out.min(1).values
            ok = (t_enter <= t_exit) & (t_enter > 0) & (~outside_parallel) & (t_enter < t_max)
            cur = t_best[r0:r1, c0:c1].reshape(-1)
            better = ok & (t_enter < cur)
            if bool(better.any()):
                tb = t_best[r0:r1, c0:c1].reshape(-1).clone()
                bb = b_best[r0:r1, c0:c1].reshape(-1).clone()
                pb = p_best[r0:r1, c0:c1].reshape(-1).clone()
                tb[better] = t_enter[better]
                bb[better] = b
                pb[better] = which[better]
                t_best[r0:r1, c0:c1] = tb.view(r1 - r0, c1 - c0)
                b_best[r0:r1, c0:c1] = bb.view(r1 - r0, c1 - c0)
                p_best[r0:r1, c0:c1] = pb.view(r1 - r0, c1 - c0)
    return t_best, b_best, p_best
