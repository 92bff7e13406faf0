"""Materials, textures, lighting, sky and fog.

Every colour is a function of the world point that a ray hits (plus the light of the climate), not of the viewing
direction: no reflections or highlights. What depends on the camera does so smoothly with the distance: the fog,
the band limiting (texture octaves finer than about 4 pixel footprints fade out, so that surfaces do not shimmer
from frame to frame) and the far field (trees, boulders and ground averaged by coverage where they are smaller
than a pixel, in step with the level of detail of the geometry, ``raymarch.Lod``). The sky depends on the
direction only (it is infinitely far).
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from .climate import Climate
from .objects import TILE
from .raymarch import Lod, bilinear_corners, sample_surface
from .terrain import CELL, GRID, PERIOD, ROAD_HALF_WIDTH
from .world import World

#: Mid-Air label IDs used by SynthAir (design 10.5).
SKY, TREES, DIRT, VEGETATION, ROCKY, BOULDERS, WATER, CONSTRUCTION, ROAD = 0, 2, 3, 4, 5, 6, 8, 9, 10

_NOISE_N = 256
#: An octave is gone once the pixel footprint reaches this fraction of its wavelength (it starts fading at half).
BAND_LIMIT = 0.25
#: Without a camera position (no level of detail), the pixel size (metres) where the far-field averaging of trees and
#: boulders starts, and over which it fades in. With one, the averaging follows the level of detail (raymarch.Lod).
FAR_START, FAR_WIDTH = 0.3, 0.9


@functools.lru_cache(maxsize=1)
def _noise_table() -> torch.Tensor:
    rng = np.random.default_rng(0x7E47)
    return torch.from_numpy(rng.uniform(-1.0, 1.0, _NOISE_N * _NOISE_N).astype(np.float32))


def value_noise(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """C1 value noise in ``[-1, 1]``, one random value per unit lattice point (periodic, 256 units)."""
    table = _noise_table()
    uv = torch.stack([u, v])
    fl = torch.floor(uv)
    f = uv - fl
    f = f * f * (3 - 2 * f)
    i0 = fl.long() & (_NOISE_N - 1)
    i1 = (i0 + 1) & (_NOISE_N - 1)
    r0, r1 = i0[0] * _NOISE_N, i1[0] * _NOISE_N
    idx = torch.stack([r0 + i0[1], r1 + i0[1], r0 + i1[1], r1 + i1[1]])
    c = table[idx]  # [4, R]
    a, b = f[0], f[1]
    return (c[0] + (c[1] - c[0]) * a) * (1 - b) + (c[2] + (c[3] - c[2]) * a) * b


def fbm(
    u: torch.Tensor,
    v: torch.Tensor,
    footprint: torch.Tensor,
    wavelength: float,
    octaves: int,
    salt: int = 0,
    gain: float = 0.55,
) -> torch.Tensor:
    """Band-limited fractal noise of world coordinates ``(u, v)`` (metres); standard deviation about 0.5.

    Octave ``k`` has wavelength ``wavelength / 2**k`` and amplitude ``gain**k``; it fades out as the pixel ``footprint`` (metres) grows
    from 1/8 to 1/4 of its wavelength, i.e. detail finer than about 4 pixels is removed (an octave that is faded
    out everywhere is not evaluated).
    """
    total = torch.zeros_like(u)
    power = 0.0
    amp = 1.0
    fp_min = float(footprint.min()) if footprint.numel() else 0.0
    for k in range(octaves):
        freq = (2.0**k) / wavelength
        power += amp * amp
        amp_k = amp
        amp *= gain
        if fp_min * freq >= BAND_LIMIT:
            continue  # faded out everywhere
        weight = (2.0 - footprint * (freq * 2.0 / BAND_LIMIT)).clamp(0.0, 1.0)
        # rotate each octave (3-4-5 rotation) and shift it so that lattices do not line up
        uu, vv = u * freq, v * freq
        if k % 2:
            uu, vv = 0.8 * uu - 0.6 * vv, 0.6 * uu + 0.8 * vv
        off = 17.31 * (k + 1) + 53.7 * salt
        total = total + amp_k * weight * value_noise(uu + off, vv + 0.61 * off)
    # value noise has a standard deviation of about 0.35: scale the full sum to about 0.5
    return total * (1.4 / power**0.5)


def box_coverage(dist: torch.Tensor, half_width: float, footprint: torch.Tensor) -> torch.Tensor:
    """Fraction of a footprint-wide box centred at signed distance ``dist`` that lies inside ``[-hw, hw]``."""
    fp = footprint.clamp(min=1e-3)
    lo = torch.maximum(dist - fp / 2, torch.full_like(dist, -half_width))
    hi = torch.minimum(dist + fp / 2, torch.full_like(dist, half_width))
    return ((hi - lo) / fp).clamp(0.0, 1.0)


def periodic_coverage(coord: torch.Tensor, period: float, half_width: float, footprint: torch.Tensor):
    """Box-filtered coverage of stripes ``|coord - k * period| <= half_width``, fading to the mean coverage when
    the footprint approaches the period."""
    d = torch.remainder(coord + period / 2, period) - period / 2
    cov = box_coverage(d, half_width, footprint)
    mean = 2 * half_width / period
    fade = (footprint / period * 2 - 0.5).clamp(0.0, 1.0)
    return cov * (1 - fade) + mean * fade


def _rgb(c) -> torch.Tensor:
    return torch.tensor(c, dtype=torch.float32)


def _mod(x: torch.Tensor) -> torch.Tensor:
    """Brightness multiplier ``1 + x`` (kept positive), shaped ``[R, 1]``."""
    return (1.0 + x).clamp(min=0.3).unsqueeze(-1)


def _mix(a, b, w):
    return a + (b - a) * w.unsqueeze(-1)


def sky_colour(climate: Climate, d: torch.Tensor, pixel_angle: float, clouds: bool = True) -> torch.Tensor:
    """Colour of the sky in directions ``d [R, 3]`` (x, y, up); depends on the direction only."""
    e = d[:, 2].clamp(min=0.0)
    zen, hor = _rgb(climate.zenith), _rgb(climate.horizon)
    col = _mix(hor, zen, e.sqrt())
    sun = torch.tensor(climate.sun_direction(), dtype=torch.float32)
    cosang = (d * sun).sum(1).clamp(-1.0, 1.0)
    glow = 0.35 * torch.exp((cosang - 1.0) * 6.0) + 0.6 * torch.exp((cosang - 1.0) * 90.0)
    col = col + _rgb(climate.sun_glow) * glow.unsqueeze(-1)
    disk = ((cosang - 0.99985) / 0.00005).clamp(0.0, 1.0)
    col = col + _rgb(climate.sun_colour) * 3.0 * disk.unsqueeze(-1)
    if clouds and climate.cloud_cover > 0:
        ez = d[:, 2].clamp(min=0.02)
        height = 1500.0
        u = d[:, 0] / ez * height
        v = d[:, 1] / ez * height
        fp = height * pixel_angle / (ez * ez)
        n = fbm(u, v, fp, 2400.0, 5, salt=7)
        thr = 0.8 - 1.6 * climate.cloud_cover
        dens = ((n - thr) / 0.35).clamp(0.0, 1.0) * ((d[:, 2] - 0.01) / 0.12).clamp(0.0, 1.0)
        shade = 0.85 + 0.15 * fbm(u * 1.7, v * 1.7, fp * 1.7, 900.0, 3, salt=9)
        cloud = _rgb(climate.cloud_colour) * shade.unsqueeze(-1) + _rgb(climate.sun_glow) * (0.3 * glow).unsqueeze(-1)
        col = _mix(col, cloud, dens * 0.9)
    return col


def fog_colour(climate: Climate, d: torch.Tensor) -> torch.Tensor:
    """Colour that distant surfaces fade to: the cloudless sky just above the horizon in that direction."""
    flat = torch.stack([d[:, 0], d[:, 1], torch.full_like(d[:, 0], 0.03)], 1)
    flat = flat / flat.norm(dim=1, keepdim=True)
    return sky_colour(climate, flat, 1.0, clouds=False)


def apply_fog(climate: Climate, colour: torch.Tensor, d: torch.Tensor, dist: torch.Tensor) -> torch.Tensor:
    """Fade to the fog colour with the fraction ``1 - exp(-(dist / fog_distance)^2)``: the Gaussian fall-off keeps
    the near field clear, where a distance-dependent fog would change the most from frame to frame."""
    r = dist / climate.fog_distance
    f = 1.0 - torch.exp(-r * r)
    return _mix(colour, fog_colour(climate, d), f)


def tone_map(linear: torch.Tensor, exposure: float) -> np.ndarray:
    """Linear radiance ``[..., 3]`` -> sRGB-ish uint8 (filmic shoulder, gamma 2.2)."""
    x = 1.0 - torch.exp(-linear.clamp(min=0.0) * exposure)
    x = x.clamp(0.0, 1.0) ** (1.0 / 2.2)
    return (x * 255.0 + 0.5).floor().clamp(0, 255).to(torch.uint8).numpy()


def _lighting(climate: Climate, normal: torch.Tensor, direct_occ: torch.Tensor, ambient_occ: torch.Tensor):
    sun = torch.tensor(climate.sun_direction(), dtype=torch.float32)
    ndl = (normal * sun).sum(1).clamp(min=0.0)
    up = normal[:, 2]
    amb = _rgb(climate.sky_light) * (0.5 + 0.5 * up).unsqueeze(-1) + _rgb(climate.ground_light) * (
        0.5 - 0.5 * up
    ).unsqueeze(-1)
    return _rgb(climate.sun_colour) * (ndl * direct_occ).unsqueeze(-1) + amb * ambient_occ.unsqueeze(-1)


def shade_heightfield(
    world: World,
    climate: Climate,
    p: torch.Tensor,
    d: torch.Tensor,
    dist: torch.Tensor,
    pixel_angle: float,
    camera_xy: torch.Tensor | None = None,
    lod_angle: float | None = None,
):
    # camera_xy: [2, R] (or [2, 1]) wrapped camera position of each hit, and lod_angle (default pixel_angle):
    # the level of detail of the geometry (raymarch.Lod)
    """Colour (linear, fog not applied) and Mid-Air label of height-field hits.

    Args:
        p: ``[R, 3]`` hit points (x, y, up); d: ``[R, 3]`` unit ray directions; dist: ``[R]`` distances.
        pixel_angle: angular size of a pixel (radians), for the texture footprint.
    Returns:
        ``(rgb [R, 3] float32, labels [R] uint8)``.
    """
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    xy = p[:, :2].T.contiguous()
    lod = None if camera_xy is None else Lod(camera_xy.reshape(2, -1), lod_angle or pixel_angle)
    s = sample_surface(world, xy, lod)
    vals, w = bilinear_corners(world.shade, GRID, xy / CELL)
    f = (vals * w).sum(1)
    grads, (rock, dirt, fshade, tint, road_d) = f[:8].view(4, 2, -1), f[8:]
    tv, tw = s.tile_values, s.tile_weights
    sv, _ = bilinear_corners(world.tile_shade, TILE, s.tile_coords)  # [8, 4, R]
    wg_t = tw * s.gate_tree
    wg_b = tw * s.gate_boulder
    tree_grad_x = (wg_t * sv[0]).sum(0)
    tree_grad_y = (wg_t * sv[1]).sum(0)
    bould_grad_x = (wg_b * sv[2]).sum(0)
    bould_grad_y = (wg_b * sv[3]).sum(0)
    pick_t = torch.argmax(wg_t * tv[0], dim=0).unsqueeze(0)
    pick_b = torch.argmax(wg_b * tv[2], dim=0).unsqueeze(0)
    tree_id, tree_top = sv[4].gather(0, pick_t)[0], sv[6].gather(0, pick_t)[0]
    bould_id, bould_top = sv[5].gather(0, pick_b)[0], sv[7].gather(0, pick_b)[0]

    w_level = world.water_level
    obj = torch.maximum(s.tree, s.boulder)
    is_water = w_level > s.terrain + obj + 1e-4
    is_obj = (~is_water) & (obj > 0.02)
    is_tree = is_obj & (s.tree >= s.boulder)
    is_boulder = is_obj & ~is_tree
    is_ground = ~(is_water | is_obj)
    is_road = is_ground & (road_d < ROAD_HALF_WIDTH)

    up = torch.ones_like(x)
    fp0 = dist * pixel_angle
    # terrain normal from the gradient smoothed to the footprint: level k of NORMAL_SMOOTHING from footprint
    # NORMAL_FOOTPRINT[k] (metres), linearly in between
    n_coarse = torch.stack([-grads[0, 0], -grads[0, 1], up], 1)
    cos_inc = (-(d * n_coarse).sum(1) / n_coarse.norm(dim=1)).clamp(min=0.05)
    # footprint: geometric mean of the pixel's extent across (fp0) and along (fp0 / cos) the view direction
    fp = fp0 / cos_inc.sqrt()
    level = _footprint_level(fp)
    gtx, gty = _blend_levels(grads, level)
    n_terrain = torch.stack([-gtx, -gty, up], 1)
    n_terrain = n_terrain / n_terrain.norm(dim=1, keepdim=True)
    # object normals lose their detail as the footprint grows past the crown scale (level of detail)
    lod = (1.5 - fp / 0.6).clamp(0.25, 1.0)
    ogx = torch.where(is_tree, tree_grad_x, bould_grad_x) * lod
    ogy = torch.where(is_tree, tree_grad_y, bould_grad_y) * lod
    n_obj = torch.stack([-(gtx + ogx), -(gty + ogy), up], 1)
    n_obj = n_obj / n_obj.norm(dim=1, keepdim=True)
    normal = torch.where(is_obj.unsqueeze(1), n_obj, n_terrain)
    normal = torch.where(is_water.unsqueeze(1), torch.tensor([0.0, 0.0, 1.0]), normal)
    fp = torch.where(is_obj, fp0 / (-(d * normal).sum(1)).clamp(min=0.05).sqrt(), fp)

    # albedos, each computed only where it is needed (the ground also under trees and boulders: far field)
    n = x.shape[0]
    ground = torch.zeros((n, 3))
    land = (~is_water).nonzero().squeeze(1)
    n_lo = torch.zeros(n)
    if land.numel():
        ground[land], n_lo[land] = _ground_albedo(
            world, x[land], y[land], z[land], fp[land], tint[land], dirt[land], rock[land], road_d[land], fshade[land]
        )
    albedo = ground.clone()
    ti = is_tree.nonzero().squeeze(1)
    if ti.numel():
        albedo[ti] = _tree_albedo(x[ti], y[ti], z[ti], fp[ti], tree_id[ti], normal[ti], n_lo[ti])
    bi = is_boulder.nonzero().squeeze(1)
    if bi.numel():
        albedo[bi] = _boulder_albedo(x[bi], y[bi], z[bi], fp[bi], bould_id[bi], normal[bi])
    wi = is_water.nonzero().squeeze(1)
    if wi.numel():
        albedo[wi] = _water_albedo(climate, x[wi], y[wi], fp[wi], w_level - s.terrain[wi])
    tree_rel = (s.tree / tree_top.clamp(min=0.5)).clamp(0.0, 1.0)
    bould_rel = (s.boulder / bould_top.clamp(min=0.2)).clamp(0.0, 1.0)

    direct_occ = torch.ones_like(x) - 0.75 * fshade
    ambient_occ = torch.ones_like(x) - 0.5 * fshade
    direct_occ = torch.where(is_tree, 0.5 + 0.5 * tree_rel, direct_occ)
    ambient_occ = torch.where(is_tree, 0.45 + 0.55 * tree_rel, ambient_occ)
    direct_occ = torch.where(is_boulder, 0.6 + 0.4 * bould_rel, direct_occ)
    ambient_occ = torch.where(is_boulder, 0.55 + 0.45 * bould_rel, ambient_occ)
    light = _lighting(climate, normal, direct_occ, ambient_occ)
    rgb = albedo * light

    # far field: trees and boulders shrink below a pixel and would sparkle from frame to frame; there every
    # sample returns the mean colour of the ground, trees and boulders around (pre-filtering by coverage)
    far = s.lod if camera_xy is not None else ((fp0 - FAR_START) / FAR_WIDTH).clamp(0.0, 1.0)
    if bool((far > 0).any()):
        cov_t = (0.7 * fshade).clamp(0.0, 0.9)
        cov_b = torch.minimum((0.06 * s.boulder_density).clamp(min=0.0), 1.0 - cov_t)
        ground_lit = ground * _lighting(climate, n_terrain, 1.0 - 0.75 * fshade, 1.0 - 0.5 * fshade)
        tree_mean = _mix(_rgb((0.025, 0.06, 0.025)), _rgb((0.085, 0.14, 0.035)), torch.full_like(x, 0.5))
        tree_lit = tree_mean * _lighting(climate, n_terrain, torch.full_like(x, 0.8), torch.full_like(x, 0.7))
        bould_lit = _rgb((0.20, 0.195, 0.185)) * _lighting(
            climate, n_terrain, torch.full_like(x, 0.85), torch.full_like(x, 0.8)
        )
        mean = ground_lit * (1.0 - cov_t - cov_b).unsqueeze(-1) + tree_lit * cov_t.unsqueeze(-1)
        mean = mean + bould_lit * cov_b.unsqueeze(-1)
        rgb = torch.where(is_water.unsqueeze(1), rgb, _mix(rgb, mean, far))

    labels = torch.full(x.shape, VEGETATION, dtype=torch.uint8)
    labels[is_ground & (dirt > 0.5)] = DIRT
    labels[is_ground & (rock > 0.5)] = ROCKY
    labels[is_road] = ROAD
    labels[is_tree] = TREES
    labels[is_boulder] = BOULDERS
    labels[is_water] = WATER
    return rgb, labels


#: Pixel footprints (metres) at which the shading normals use smoothing level 0, 1, 2, 3 of the terrain.
NORMAL_FOOTPRINT = (1.0, 2.0, 5.0, 12.0)


def _footprint_level(fp: torch.Tensor) -> torch.Tensor:
    """Fractional smoothing level in [0, 3] for pixel footprints ``fp``."""
    level = torch.zeros_like(fp)
    for k in range(3):
        lo, hi = NORMAL_FOOTPRINT[k], NORMAL_FOOTPRINT[k + 1]
        level = level + ((fp - lo) / (hi - lo)).clamp(0.0, 1.0)
    return level


def _blend_levels(grads: torch.Tensor, level: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Interpolate ``grads [4, 2, R]`` between levels at fractional ``level [R]``."""
    out = grads[0]
    for k in range(1, 4):
        wk = (level - (k - 1)).clamp(0.0, 1.0)
        out = out + (grads[k] - out) * wk
    return out[0], out[1]


def _ground_albedo(world, x, y, z, fp, tint, dirt, rock, road_d, fshade):
    """Grass, dirt and rocky ground (blended at the class borders), roads with their paint, darker under trees.
    Returns ``(albedo [R, 3], large-scale noise [R])``."""
    n_lo = fbm(x, y, fp, 48.0, 4, salt=1)
    n_mid = fbm(x, y, fp, 7.0, 3, salt=12)
    n_hi = fbm(x, y, fp, 2.0, 5, salt=2, gain=0.8)
    grass = _mix(
        _rgb((0.05, 0.10, 0.028)),
        _rgb((0.17, 0.19, 0.055)),
        (0.5 + 0.45 * tint + 0.5 * n_lo + 0.45 * n_mid).clamp(0, 1),
    )
    grass = grass * _mod(0.35 * n_mid + 0.55 * n_hi)
    dirt_c = _mix(_rgb((0.15, 0.11, 0.07)), _rgb((0.29, 0.22, 0.14)), (0.5 + 0.6 * n_lo + 0.45 * n_mid).clamp(0, 1))
    dirt_c = dirt_c * _mod(0.3 * n_mid + 0.5 * n_hi)
    ground = _mix(grass, dirt_c, ((dirt - 0.45) / 0.1).clamp(0, 1))
    rocky = (rock > 0.45).nonzero().squeeze(1)
    if rocky.numel():
        r = rocky
        rock_c = _mix(
            _rgb((0.10, 0.095, 0.09)), _rgb((0.21, 0.20, 0.185)), (0.5 + 0.7 * n_lo[r] + 0.3 * n_mid[r]).clamp(0, 1)
        )
        strata = fbm(x[r] * 0.15 + z[r] * 2.0, y[r] * 0.15 - z[r] * 2.0, fp[r] * 2.0, 2.0, 3, salt=3)
        rock_c = rock_c * _mod(0.45 * n_hi[r] + 0.25 * strata)
        ground[r] = _mix(ground[r], rock_c, ((rock[r] - 0.45) / 0.1).clamp(0, 1))
    # roads: asphalt, a dashed centre line and solid edge lines (box-filtered)
    near_road = (road_d < ROAD_HALF_WIDTH + fp).nonzero().squeeze(1)
    if near_road.numel():
        r = near_road
        asphalt = _rgb((0.085, 0.085, 0.09)) * _mod(0.25 * n_hi[r] + 0.15 * n_mid[r] + 0.1 * n_lo[r])
        road_cov = box_coverage(road_d[r], ROAD_HALF_WIDTH, fp[r])
        edge = box_coverage(road_d[r] - (ROAD_HALF_WIDTH - 0.35), 0.09, fp[r])
        along = _road_along(world, x[r], y[r])
        centre = box_coverage(road_d[r], 0.08, fp[r]) * periodic_coverage(along, 9.0, 1.5, fp[r])
        paint = (edge + centre).clamp(0, 1)
        road_c = _mix(asphalt, _rgb((0.65, 0.65, 0.6)), paint)
        ground[r] = _mix(ground[r], road_c, road_cov)
    return ground * (1.0 - 0.35 * fshade).unsqueeze(-1), n_lo


def _tree_albedo(x, y, z, fp, tree_id, normal, n_lo):
    """Per-tree hue (faded out where trees are small in the image) and leaf clumps (ground plane and a vertical
    plane, blended by the normal)."""
    id_fade = (1.5 - fp / 2.0).clamp(0.0, 1.0)
    tid = 0.5 + (tree_id - 0.5) * id_fade
    leaf_v = fbm(x + y, z, fp, 1.2, 3, salt=4)
    leaf_h = fbm(x, y, fp, 1.2, 3, salt=5)
    vert = normal[:, 2].abs()
    leaf = leaf_h * vert + leaf_v * (1 - vert)
    tree_c = _mix(_rgb((0.025, 0.06, 0.025)), _rgb((0.085, 0.14, 0.035)), tid)
    return tree_c * _mod(0.4 * leaf + 0.1 * n_lo)


def _boulder_albedo(x, y, z, fp, bould_id, normal):
    """Grey stone with per-boulder brightness, grain and lichen on the upper faces."""
    id_fade = (1.5 - fp / 2.0).clamp(0.0, 1.0)
    bid = 0.5 + (bould_id - 0.5) * id_fade
    boulder_c = _rgb((0.20, 0.195, 0.185)) * (0.7 + 0.6 * bid).unsqueeze(-1)
    stone = fbm(x + 0.7 * z, y - 0.7 * z, fp, 1.5, 4, salt=6)
    lichen = ((fbm(x, y + z, fp, 2.5, 2, salt=8) - 0.2) / 0.3).clamp(0, 1) * (0.5 + 0.5 * normal[:, 2])
    boulder_c = boulder_c * _mod(0.3 * stone)
    return _mix(boulder_c, _rgb((0.20, 0.22, 0.12)), lichen * 0.6)


def _water_albedo(climate, x, y, fp, water_depth):
    """Shallow water brownish, deep water dark, slow world-fixed waves (no reflections: view independent)."""
    depth_w = water_depth.clamp(min=0.0)
    water_c = _mix(_rgb((0.10, 0.12, 0.085)), _rgb((0.018, 0.05, 0.065)), (depth_w / 2.5).clamp(0, 1))
    waves = fbm(x, y, fp, 16.0, 6, salt=13)
    n_lo = fbm(x, y, fp, 48.0, 2, salt=1)
    return (water_c + _rgb(climate.zenith) * 0.1) * _mod(0.4 * waves + 0.15 * n_lo)


def _road_along(world: World, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Along-road coordinate of the nearest road (for the dashes), metres."""
    best = torch.full_like(x, float("inf"))
    along = torch.zeros_like(x)
    for k, axis in enumerate(world.road_axis):
        s, lat = (x, y) if axis == 0 else (y, x)
        g = s / CELL
        i0f = torch.floor(g)
        a = g - i0f
        i0 = i0f.long().remainder(GRID)
        i1 = torch.where(i0 == GRID - 1, 0, i0 + 1)
        c = world.road_lateral[k][i0] * (1 - a) + world.road_lateral[k][i1] * a
        dl = torch.remainder(lat - c + PERIOD / 2, PERIOD) - PERIOD / 2
        dist = dl.abs()
        closer = dist < best
        best = torch.where(closer, dist, best)
        along = torch.where(closer, s, along)
    return along


def shade_buildings(
    world: World,
    climate: Climate,
    p: torch.Tensor,
    d: torch.Tensor,
    dist: torch.Tensor,
    building: torch.Tensor,
    plane: torch.Tensor,
    pixel_angle: float,
):
    """Colour (linear, no fog) of building hits ``[R]``; walls have box-filtered windows."""
    b = world.buildings
    planes = torch.as_tensor(b.planes, dtype=torch.float32)
    normal = planes[building, plane, :3]
    roof = torch.as_tensor(b.roof)[building, plane]
    wall_c = torch.as_tensor(b.wall_colour, dtype=torch.float32)[building]
    roof_c = torch.as_tensor(b.roof_colour, dtype=torch.float32)[building]
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    fp = dist * pixel_angle / (-(d * normal).sum(1)).clamp(min=0.25)
    n_hi = fbm(x + z, y - z, fp, 2.0, 3, salt=11)
    # along-wall coordinate: horizontal tangent of the wall plane
    tang = torch.stack([-normal[:, 1], normal[:, 0]], 1)
    tang = tang / tang.norm(dim=1, keepdim=True).clamp(min=1e-6)
    along = x * tang[:, 0] + y * tang[:, 1]
    base = torch.as_tensor(b.corners[:, 0, 2], dtype=torch.float32)[building] + 1.0  # ground level (approx.)
    height = z - base
    win = periodic_coverage(along, 3.2, 0.6, fp) * periodic_coverage(height - 1.6, 3.0, 0.65, fp)
    win = win * ((height - 0.8) / 0.3).clamp(0, 1)
    wall = _mix(wall_c * _mod(0.1 * n_hi), _rgb((0.05, 0.06, 0.07)), win * 0.9)
    tiles = periodic_coverage(z * 3.0, 1.0, 0.08, fp * 3.0)
    roof_col = roof_c * _mod(0.12 * n_hi - 0.25 * tiles)
    albedo = torch.where(roof.unsqueeze(1), roof_col, wall)
    ones = torch.ones_like(x)
    return albedo * _lighting(climate, normal, ones, ones)
