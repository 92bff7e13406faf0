"""Render one SynthAir frame: colour, exact z-depth and Mid-Air labels from a camera pose.

Camera model (design 2.1, 10.3): a pinhole with a 90 degree horizontal FOV, ``f_x = W / 2``, ``f_y = H / 2``,
``c = (W / 2, H / 2)``; pixel ``(i, j)`` looks along camera ray ``((j + 0.5 - c_x) / f_x, (i + 0.5 - c_y) / f_y, 1)``.
With a ``lens`` (a :class:`~cosemdepth.camera.Calibration` of these intrinsics and a distortion model), pixel
``(i, j)`` looks along the ray the lens maps to its centre: its distorted normalised coordinates undistorted
exactly (:func:`cosemdepth.camera.distortion.undistort_points`, float64), so colour, depth and labels are those of
the distorted image's own pixels, not a warped pinhole render. The level of detail and the texture footprint stay
those of the focal length (``1 / f_x`` per pixel), as for the pinhole.
The camera is fixed to the body: camera ``x`` = body ``y`` (right), camera ``y`` = body ``z`` (down), camera
``z`` = body ``x`` (forward). Poses are Mid-Air's: attitude quaternion ``(w, x, y, z)`` body -> world and position,
world NED.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import torch

from ..camera.calibration import Calibration
from ..camera.distortion import undistort_points
from ..data.quaternion import qmatrix
from .climate import Climate
from .raymarch import T_MAX, beam_start, intersect_buildings, march_heightfield
from .shading import CONSTRUCTION, SKY, apply_fog, shade_buildings, shade_heightfield, sky_colour, tone_map
from .terrain import PERIOD
from .world import World

#: z-depth written for the sky (and for rays that reach ``T_MAX`` without a hit): far, finite, so that the stored
#: disparity is tiny but never zero (as in Mid-Air).
SKY_DEPTH = 20000.0
#: Side weight of the 3-tap point spread of the camera (standard deviation about 0.63 pixel).
OPTICAL_BLUR = 0.2


@dataclass
class Frame:
    """One rendered frame: colour, z-depth and Mid-Air labels, all ``[H, W]`` maps of the same view."""

    rgb: np.ndarray  # [H, W, 3] uint8
    depth: np.ndarray  # [H, W] float32 z-depth, metres (SKY_DEPTH for the sky)
    labels: np.ndarray  # [H, W] uint8 Mid-Air label IDs


@lru_cache(maxsize=8)
def lens_grid(lens: Calibration, height: int, width: int, supersample: int = 1) -> torch.Tensor:
    """``[h, w, 2]`` float64 undistorted normalised coordinates ``(x, y)`` of every (sub)pixel centre of a
    ``lens`` (``h = height * supersample``), computed once per lens and size."""
    s = supersample
    u = (torch.arange(width * s, dtype=torch.float64) + 0.5) / s
    v = (torch.arange(height * s, dtype=torch.float64) + 0.5) / s
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), -1)
    xy = undistort_points(lens.model, lens.normalise(uv), lens.coefficients, lens.limit()[0])
    if not bool(torch.isfinite(xy).all()):
        raise ValueError("the lens has pixels without a ray in front of the camera")
    return xy


def camera_rays(rotation: np.ndarray, height: int, width: int, supersample: int = 1, lens: Calibration | None = None):
    """World ray directions of every (sub)pixel.

    Args:
        rotation: ``[3, 3]`` body -> world (NED) rotation matrix.
        lens: a distorting lens (see the module docstring); None: the 90-degree pinhole.
    Returns:
        ``(d [h, w, 3] float32 unit directions in (x north, y east, up), inv_norm [h, w] float32)`` where
        ``h = height * supersample`` and ``z-depth = distance * inv_norm``.
    """
    s = supersample
    if lens is not None:
        grid = lens_grid(lens, height, width, s)
        right, down = grid[..., 0], grid[..., 1]
    else:
        fx, fy = width / 2.0, height / 2.0
        cols = (torch.arange(width * s, dtype=torch.float64) + 0.5) / s - width / 2.0
        rows = (torch.arange(height * s, dtype=torch.float64) + 0.5) / s - height / 2.0
        right = (cols / fx).view(1, -1).expand(height * s, -1)
        down = (rows / fy).view(-1, 1).expand(-1, width * s)
    fwd = torch.ones_like(right)
    r = torch.as_tensor(rotation, dtype=torch.float64)
    # body (forward, right, down) -> NED, elementwise (no matmul: bitwise reproducible for any thread count)
    ned = [fwd * r[k, 0] + right * r[k, 1] + down * r[k, 2] for k in range(3)]
    d = torch.stack([ned[0], ned[1], -ned[2]], -1)
    norm = torch.sqrt(fwd * fwd + right * right + down * down)
    d = d / norm.unsqueeze(-1)
    return d.float(), (1.0 / norm).float()


def _building_rects(
    world: World, origin: np.ndarray, rotation: np.ndarray, height: int, width: int, grid: torch.Tensor | None = None
):
    """Buildings that may be visible, the periodic shift of their nearest copy and their pixel rectangle. ``grid``:
    the undistorted normalised coordinates ``[height, width, 2]`` of a lens's pixels (None: the pinhole); the
    rectangle is then the pixels whose rays fall in the building's box of normalised coordinates (a pinhole
    projection's box, exact for any lens)."""
    b = world.buildings
    if len(b) == 0:
        return []
    shift = np.zeros((len(b), 3))
    shift[:, :2] = np.round((b.center[:, :2] - origin[:2]) / PERIOD) * PERIOD
    centre = b.center - shift
    v = centre - origin
    dist = np.linalg.norm(v, axis=1)
    # world (x, y, up) -> body (forward, right, down)
    r_ned = rotation
    to_ned = np.array([1.0, 1.0, -1.0])
    cam = (v * to_ned) @ r_ned  # [B, 3] body coordinates
    fwd = cam[:, 0]
    ok = (dist - b.radius < T_MAX) & (fwd > -b.radius)
    ok &= np.abs(cam[:, 1]) <= fwd + b.radius * 1.5
    ok &= np.abs(cam[:, 2]) <= fwd + b.radius * 1.5
    out = []
    fx, fy = width / 2.0, height / 2.0
    for i in np.flatnonzero(ok):
        corners = ((b.corners[i] - shift[i] - origin) * to_ned) @ r_ned
        if (corners[:, 0] <= 0.05).any():
            rect = (0, height, 0, width)
        elif grid is not None:
            x, y = corners[:, 1] / corners[:, 0], corners[:, 2] / corners[:, 0]
            mx, my = 1.0 / fx, 1.0 / fy  # a pixel's margin, as the pinhole's
            inside = (grid[..., 0] >= x.min() - mx) & (grid[..., 0] <= x.max() + mx)
            inside &= (grid[..., 1] >= y.min() - my) & (grid[..., 1] <= y.max() + my)
            rows, cols = inside.any(1).nonzero(), inside.any(0).nonzero()
            if rows.numel() == 0:
                continue
            rect = (int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1)
        else:
            u = corners[:, 1] / corners[:, 0] * fx + fx
            w = corners[:, 2] / corners[:, 0] * fy + fy
            c0, c1 = int(np.floor(u.min())) - 1, int(np.ceil(u.max())) + 1
            r0, r1 = int(np.floor(w.min())) - 1, int(np.ceil(w.max())) + 1
            rect = (max(r0, 0), min(r1, height), max(c0, 0), min(c1, width))
        out.append((int(i), torch.tensor(shift[i], dtype=torch.float32), rect))
    return out


def optical_blur(rgb: torch.Tensor, side: float = OPTICAL_BLUR) -> torch.Tensor:
    """The camera's point spread: a separable ``[side, 1 - 2 side, side]`` filter (edges replicated) over
    ``rgb [B, H, W, 3]`` in linear light. Real cameras are never pixel-sharp, and a soft point spread keeps the
    silhouettes that a single ray per pixel leaves jagged from flickering between frames."""
    if side <= 0:
        return rgb
    x = torch.nn.functional.pad(rgb.permute(0, 3, 1, 2), (1, 1, 1, 1), mode="replicate")
    x = side * x[..., :-2] + (1 - 2 * side) * x[..., 1:-1] + side * x[..., 2:]
    x = side * x[..., :-2, :] + (1 - 2 * side) * x[..., 1:-1, :] + side * x[..., 2:, :]
    return x.permute(0, 2, 3, 1)


def render_frame(
    world: World,
    climate: Climate,
    attitude: np.ndarray,
    position: np.ndarray,
    height: int,
    width: int,
    supersample: int = 1,
    lens: Calibration | None = None,
) -> Frame:
    """Render the view of a camera with Mid-Air pose ``attitude`` (w, x, y, z; body -> NED) and ``position`` (NED).

    With ``supersample = s`` (odd), colour is the mean of ``s x s`` sub-pixel rays, while depth and labels come from
    the pixel-centre ray. ``lens``: a distorting lens of size ``(height, width)`` (module docstring).
    """
    return render_frames(
        world, climate, np.asarray(attitude)[None], np.asarray(position)[None], height, width, supersample, lens
    )[0]


def render_frames(
    world: World,
    climate: Climate,
    attitudes: np.ndarray,
    positions: np.ndarray,
    height: int,
    width: int,
    supersample: int = 1,
    lens: Calibration | None = None,
) -> list[Frame]:
    """Render several views at once (``attitudes [B, 4]``, ``positions [B, 3]``); the same result as rendering
    them one by one with :func:`render_frame`, with less overhead for small images."""
    if supersample < 1 or supersample % 2 == 0:
        raise ValueError(f"supersample must be an odd positive integer, got {supersample}")
    if lens is not None and tuple(lens.size) != (height, width):
        raise ValueError(f"the lens is for {lens.size} images, not {(height, width)}")
    attitudes = np.asarray(attitudes, dtype=np.float64).reshape(-1, 4)
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    nb = len(attitudes)
    s = supersample
    hs, ws = height * s, width * s
    pixel_angle = 1.0 / (width / 2.0 * s)  # texture footprint of one (sub)sample
    lod_angle = 1.0 / (width / 2.0)  # level of detail of the geometry: by output pixel, whatever the supersampling

    dirs, inv_norms, origins, t_bs, b_idxs, b_planes = [], [], [], [], [], []
    for att, pos in zip(attitudes, positions):
        rotation = qmatrix(att)
        origin = np.array([pos[0] % PERIOD, pos[1] % PERIOD, -pos[2]])
        d, inv_norm = camera_rays(rotation, height, width, s, lens)
        o32 = torch.tensor(origin, dtype=torch.float32)
        grid = None if lens is None else lens_grid(lens, height, width, s)
        rects = _building_rects(world, origin, rotation, hs, ws, grid)
        t_b, b_idx, b_plane = intersect_buildings(world, o32, d, rects)
        dirs.append(d)
        inv_norms.append(inv_norm)
        origins.append(o32)
        t_bs.append(t_b)
        b_idxs.append(b_idx)
        b_planes.append(b_plane)
    d = torch.stack(dirs)  # [B, hs, ws, 3]
    org = torch.stack(origins)  # [B, 3]
    t_b = torch.stack(t_bs).reshape(-1)
    b_idx = torch.stack(b_idxs).reshape(-1)
    b_plane = torch.stack(b_planes).reshape(-1)
    inv_norm = torch.stack(inv_norms).reshape(-1)

    flat_d = d.reshape(-1, 3)
    ray_org = org.repeat_interleave(hs * ws, dim=0)  # [R, 3]
    t_lim = torch.clamp(t_b, max=T_MAX)
    t0, l0 = beam_start(world, org, d, exact_cone=lens is not None)
    t_h = march_heightfield(world, ray_org, flat_d, t_lim, t0.reshape(-1), l0.reshape(-1), lod_angle)
    hit_h = torch.isfinite(t_h)
    hit_b = (~hit_h) & torch.isfinite(t_b)
    dist = torch.where(hit_h, t_h, torch.where(hit_b, t_b, torch.full_like(t_h, float("inf"))))

    n = flat_d.shape[0]
    rgb = torch.zeros((n, 3))
    labels = torch.full((n,), SKY, dtype=torch.uint8)
    hi = hit_h.nonzero().squeeze(1)
    if hi.numel():
        p = ray_org[hi] + flat_d[hi] * t_h[hi].unsqueeze(1)
        c, lab = shade_heightfield(world, climate, p, flat_d[hi], t_h[hi], pixel_angle, ray_org[hi, :2].T, lod_angle)
        rgb[hi] = c
        labels[hi] = lab
    bi = hit_b.nonzero().squeeze(1)
    if bi.numel():
        tb = t_b[bi]
        p = ray_org[bi] + flat_d[bi] * tb.unsqueeze(1)
        rgb[bi] = shade_buildings(world, climate, p, flat_d[bi], tb, b_idx[bi], b_plane[bi], pixel_angle)
        labels[bi] = CONSTRUCTION
    hit = hit_h | hit_b
    hit_idx = hit.nonzero().squeeze(1)
    if hit_idx.numel():
        rgb[hit_idx] = apply_fog(climate, rgb[hit_idx], flat_d[hit_idx], dist[hit_idx])
    sky_idx = (~hit).nonzero().squeeze(1)
    if sky_idx.numel():
        rgb[sky_idx] = sky_colour(climate, flat_d[sky_idx], pixel_angle)

    depth = torch.where(hit, dist * inv_norm, torch.full_like(dist, SKY_DEPTH))
    rgb = rgb.view(nb, hs, ws, 3)
    depth = depth.view(nb, hs, ws)
    labels = labels.view(nb, hs, ws)
    if s > 1:
        rgb = rgb.view(nb, height, s, width, s, 3).mean(dim=(2, 4))
        depth = depth[:, s // 2 :: s, s // 2 :: s]
        labels = labels[:, s // 2 :: s, s // 2 :: s]
    rgb8 = tone_map(optical_blur(rgb), climate.exposure)
    depth_np = depth.numpy().astype(np.float32)
    labels_np = labels.numpy()
    return [Frame(rgb=rgb8[i].copy(), depth=depth_np[i].copy(), labels=labels_np[i].copy()) for i in range(nb)]
