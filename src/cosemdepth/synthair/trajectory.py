"""Camera flights: smooth 6-DoF low-altitude trajectories sampled as Mid-Air ground truth (100 Hz, NED).

Body axes are x forward, y right, z down; the attitude is the unit quaternion ``(w, x, y, z)`` of the body -> world
(NED) rotation; positions are metres in NED (``x`` north, ``y`` east, ``z`` down). Camera frame ``n`` (25 Hz) is
ground-truth sample ``4 n``.

A flight is built from uniform cubic B-splines of random control values (speed, turn rate, height above the ground
or the tree tops, camera pitch, roll and yaw offsets). The altitude is smoothed, then lifted (smoothly) wherever it
would come closer than ``CLEARANCE`` to the surface under the camera (and within 1 m of it) or to a roof. A motion
profile (:mod:`.motion`: hover, yaw in place, slow and fast segments) reads such a flight along a warped timeline.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from ..data.quaternion import qconj, qmul
from .raymarch import surface_height
from .terrain import CELL, GRID, PERIOD
from .world import World

GT_RATE = 100.0
MODES = ("road", "village", "lake", "free")
#: Minimum height (metres) of the camera above the surface under it and within 1 m of it (trees, boulders, roofs).
CLEARANCE = 0.5
#: Fraction of the flights that dip down to the ground or the tree tops once.
DIP_PROBABILITY = 0.5
#: Height (metres) above the ground or the tree tops at the bottom of a dip.
DIP_HEIGHT = 0.6


@dataclass
class Flight:
    mode: str
    attitude: np.ndarray  # [N, 4] (w, x, y, z) body -> world (NED)
    position: np.ndarray  # [N, 3] NED metres
    velocity: np.ndarray  # [N, 3] NED m/s
    acceleration: np.ndarray  # [N, 3] NED m/s^2
    angular_velocity: np.ndarray  # [N, 3] body rad/s
    altitude: np.ndarray  # [N] metres above the terrain/water surface

    def __len__(self) -> int:
        return len(self.position)


def bspline(control: np.ndarray, knot_spacing: float, times: np.ndarray, t0: float) -> np.ndarray:
    """Uniform cubic B-spline with control values ``control [M, ...]`` (knot ``k`` at ``t0 + k * spacing``)."""
    u = (times - t0) / knot_spacing
    k = np.clip(np.floor(u).astype(np.int64), 1, len(control) - 3)
    f = (u - k)[(...,) + (None,) * (control.ndim - 1)]
    b0 = (1 - f) ** 3 / 6
    b1 = (3 * f**3 - 6 * f**2 + 4) / 6
    b2 = (-3 * f**3 + 3 * f**2 + 3 * f + 1) / 6
    b3 = f**3 / 6
    return b0 * control[k - 1] + b1 * control[k] + b2 * control[k + 1] + b3 * control[k + 2]


def euler_to_quaternion(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """ZYX (yaw, pitch, roll) angles in radians -> quaternions ``[N, 4]`` body -> NED (aerospace convention)."""
    z = np.zeros_like(yaw)
    qz = np.stack([np.cos(yaw / 2), z, z, np.sin(yaw / 2)], -1)
    qy = np.stack([np.cos(pitch / 2), z, np.sin(pitch / 2), z], -1)
    qx = np.stack([np.cos(roll / 2), np.sin(roll / 2), z, z], -1)
    return qmul(qmul(qz, qy), qx)


def _smooth(signal: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian smoothing (truncated at 3 sigma, edges replicated); ``sigma`` in samples."""
    r = int(np.ceil(3 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    padded = np.concatenate([np.full(r, signal[0]), signal, np.full(r, signal[-1])])
    return np.convolve(padded, k, mode="valid")


def _max_filter(signal: np.ndarray, radius: int) -> np.ndarray:
    padded = np.concatenate([np.full(radius, signal[0]), signal, np.full(radius, signal[-1])])
    win = np.lib.stride_tricks.sliding_window_view(padded, 2 * radius + 1)
    return win.max(axis=1)


def surface_max_near(world: World, xy: np.ndarray, radius: float) -> np.ndarray:
    """Highest point of the height field (terrain, water, trees, boulders; full detail) at ``xy [N, 2]`` and on
    two rings around it (radius/2 and radius, 8 points each)."""
    ang = np.arange(8) * (np.pi / 4)
    ring = np.concatenate([[[0.0, 0.0]], *[r * np.stack([np.cos(ang), np.sin(ang)], 1) for r in (radius / 2, radius)]])
    pts = xy[:, None, :] + ring[None]  # [N, 17, 2]
    flat = torch.tensor(pts.reshape(-1, 2).T, dtype=torch.float32)
    return surface_height(world, flat).double().numpy().reshape(len(xy), -1).max(axis=1)


def buildings_near(world: World, x: np.ndarray, y: np.ndarray, margin: float = 6.0) -> np.ndarray:
    """Highest building roof within ``margin`` metres of the footprint around points ``(x, y)`` (-inf if none)."""
    b = world.buildings
    out = np.full(np.shape(x), -np.inf)
    for i in range(len(b)):
        dx = (np.asarray(x) - b.center[i, 0] + PERIOD / 2) % PERIOD - PERIOD / 2
        dy = (np.asarray(y) - b.center[i, 1] + PERIOD / 2) % PERIOD - PERIOD / 2
        r = np.linalg.norm(b.corners[i, 0, :2] - b.center[i, :2]) + margin
        out = np.where(dx * dx + dy * dy < r * r, np.maximum(out, b.top[i]), out)
    return out


def _spline_times(duration: float, spacing: float):
    n = int(np.ceil((duration + 6.0) / spacing)) + 4
    return n, -3.0 - spacing


def _choose_start(world: World, rng: np.random.Generator, mode: str):
    """Start point and initial heading for a flight mode."""
    t = world.terrain
    if mode == "road":
        k = int(rng.integers(len(t.roads.axis)))
        s = rng.uniform(0, PERIOD)
        if len(world.buildings) and rng.uniform() < 0.75:
            # start on the road nearest to a building, level with it
            c = world.buildings.center[rng.integers(len(world.buildings))]
            dist, which = t.roads.distance(np.array([c[0]]), np.array([c[1]]))
            if dist[0] < 150.0:
                k = int(which[0])
                s = c[0] if t.roads.axis[k] == 0 else c[1]
                s -= rng.uniform(20.0, 80.0)
        return {"road": k, "s": s, "direction": 1.0}
    if mode == "village" and len(world.buildings):
        c = world.buildings.center[rng.integers(len(world.buildings))]
        ang = rng.uniform(0, 2 * np.pi)
        dist = rng.uniform(25, 80)
        x0, y0 = c[0] - dist * np.cos(ang), c[1] - dist * np.sin(ang)
        return {"xy": (x0, y0), "heading": ang + rng.normal(0, 0.15)}
    if mode == "lake":
        wet = np.flatnonzero(t.height.ravel() < t.water_level - 1.0)
        if wet.size:
            cell = wet[rng.integers(wet.size)]
            cx, cy = (cell // GRID) * CELL, (cell % GRID) * CELL
            ang = rng.uniform(0, 2 * np.pi)
            dist = rng.uniform(80, 200)
            return {"xy": (cx - dist * np.cos(ang), cy - dist * np.sin(ang)), "heading": ang + rng.normal(0, 0.2)}
    return {"xy": tuple(rng.uniform(0, PERIOD, 2)), "heading": rng.uniform(0, 2 * np.pi)}


def flight_from_poses(mode: str, attitude: np.ndarray, position: np.ndarray, altitude: np.ndarray) -> Flight:
    """A :class:`Flight` from 100 Hz poses: velocity, acceleration and body angular velocity are their finite
    differences (``np.gradient``: central inside, one-sided at the ends).

    Args:
        attitude: ``[N, 4]`` unit quaternions (w, x, y, z), body -> world (NED).
        position: ``[N, 3]`` NED metres.
        altitude: ``[N]`` metres above the terrain/water surface.
    """
    dt = 1.0 / GT_RATE
    velocity = np.gradient(position, dt, axis=0)
    acceleration = np.gradient(velocity, dt, axis=0)
    dq = np.gradient(attitude, dt, axis=0)
    angular_velocity = 2.0 * qmul(qconj(attitude), dq)[:, 1:]
    return Flight(mode, attitude, position, velocity, acceleration, angular_velocity, altitude)


def make_flight(
    world: World,
    rng: np.random.Generator,
    n_frames: int,
    mode: str,
    ground_track: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Flight:
    """A flight of ``n_frames`` camera frames (25 Hz), i.e. ``4 n_frames`` ground-truth samples (100 Hz).

    ``ground_track`` maps the horizontal path ``[4 n_frames, 2]`` to the points the drone will actually fly over
    (a motion profile turns the rest of the path where the drone yaws in place, :mod:`.motion`): the height above
    the surface and the clearance are then computed over those points, while the returned positions and attitudes
    stay those of the unturned path (the caller applies the same map). The random draws do not depend on it.
    """
    n = 4 * n_frames
    dt = 1.0 / GT_RATE
    times = np.arange(n) * dt
    duration = n * dt
    ks = 1.5
    m, t0 = _spline_times(duration, ks)

    speed = bspline(rng.uniform(4.0, 13.0, m), ks, times, t0)
    start = _choose_start(world, rng, mode)
    if "road" in start:
        roads = world.terrain.roads
        k, direction = start["road"], start["direction"]
        s = start["s"] + direction * np.concatenate([[0.0], np.cumsum(speed[:-1] * dt)])
        lateral_off = bspline(rng.uniform(-14.0, 14.0, m), 3.0, times, t0 * 2)
        pts = np.array([roads.point(k, si) for si in s])
        tang = np.array([roads.tangent(k, si) for si in s]) * direction
        normal = np.stack([-tang[:, 1], tang[:, 0]], 1)
        xy = pts + normal * lateral_off[:, None]
    else:
        turn_max = np.radians(18.0 if mode == "free" else 8.0)
        turn = bspline(rng.uniform(-turn_max, turn_max, m), ks, times, t0)
        heading = start["heading"] + np.concatenate([[0.0], np.cumsum(turn[:-1] * dt)])
        step = np.stack([np.cos(heading), np.sin(heading)], 1) * (speed * dt)[:, None]
        xy = np.array(start["xy"]) + np.concatenate([np.zeros((1, 2)), np.cumsum(step[:-1], axis=0)])

    # heading of the path (central differences of the smooth horizontal path)
    vel_xy = np.gradient(xy, dt, axis=0)
    path_heading = np.unwrap(np.arctan2(vel_xy[:, 1], vel_xy[:, 0]))

    # the points the drone flies over (the path itself unless a motion profile turns it)
    track = xy if ground_track is None else np.asarray(ground_track(xy), dtype=np.float64)
    ground = world.terrain.surface_at(track[:, 0], track[:, 1])
    # Height above the ground or the tree tops (the smoothed surface envelope): a per-flight base (log-uniform),
    # slow variations, and in half of the flights a dip down to the ground or the tree tops.
    # (a running max first, so that the flight does not sink into the gaps between tree tops)
    canopy = _smooth(_max_filter(surface_max_near(world, track, 3.0), int(0.75 * GT_RATE)), 0.25 * GT_RATE)
    hi_alt = 25.0 if mode == "village" else 45.0
    base = np.exp(rng.uniform(np.log(6.0), np.log(hi_alt)))
    alt = bspline(base * np.exp(rng.uniform(-0.5, 0.5, m)), 2.0, times, -5.0)
    dip = np.zeros(n)
    if rng.uniform() < DIP_PROBABILITY:
        # over the most open stretch of the middle of the flight (no diving between trees)
        jitter = rng.uniform(0.0, 1.0, n)
        middle = (times >= 0.15 * duration) & (times <= 0.85 * duration)
        clutter = np.where(middle, canopy - ground + jitter, np.inf)
        ci = int(np.argmin(clutter))
        centre = times[ci]
        # slow enough to descend and climb back at about 2.5 m/s at most (Gaussian: max slope ~ drop / (1.65 w))
        width = max(rng.uniform(1.0, 2.5), (alt[ci] - DIP_HEIGHT) / 4.0)
        dip = np.exp(-0.5 * ((times - centre) / width) ** 2)
        alt = alt + (DIP_HEIGHT - alt) * dip
    # a dip comes down to the ground itself (the clearance below keeps it off trees and boulders)
    reference = np.maximum(ground, canopy) * (1.0 - dip) + ground * dip
    target = reference + np.clip(alt, DIP_HEIGHT, 80.0)
    # never inside or right on top of anything: the exact surface under the camera and around it (1 m), roofs
    obstacle = np.maximum(surface_max_near(world, track, 1.0), buildings_near(world, track[:, 0], track[:, 1]))
    required = np.maximum(target, obstacle + CLEARANCE)
    # smooth the altitude, then lift it where it comes too close to an obstacle: the lift is a max filter of the
    # deficit (half-width w) followed by a Gaussian truncated at 3 sigma <= w, which never falls below the deficit
    sigma = 0.7 * GT_RATE
    smooth_target = _smooth(target, sigma)
    deficit = np.maximum(required - smooth_target, 0.0)
    lift_sigma = 0.9 * GT_RATE
    lift = _smooth(_max_filter(deficit, int(np.ceil(3 * lift_sigma))), lift_sigma)
    altitude_up = np.maximum(smooth_target + lift, required)  # equal to the sum up to rounding

    # attitude: yaw follows the path with a small offset, the camera looks down, rolls into turns
    yaw = path_heading + np.radians(bspline(rng.uniform(-8.0, 8.0, m), ks, times, t0))
    turn_rate = np.gradient(path_heading, dt)
    # the camera looks down more during a dip (the view then reaches the ground right under the drone)
    pitch_down = bspline(rng.uniform(10.0, 30.0, m), 2.0, times, -5.0) + 20.0 * dip
    pitch = -np.radians(pitch_down)
    hspeed = np.linalg.norm(vel_xy, axis=1)
    bank = np.arctan(hspeed * _smooth(turn_rate, 0.2 * GT_RATE) / 9.81)
    roll = np.clip(0.8 * bank + np.radians(bspline(rng.uniform(-6.0, 6.0, m), ks, times, t0)), -0.5, 0.5)
    attitude = euler_to_quaternion(yaw, pitch, roll)
    attitude /= np.linalg.norm(attitude, axis=1, keepdims=True)

    position = np.stack([xy[:, 0], xy[:, 1], -altitude_up], 1)
    return flight_from_poses(mode, attitude, position, altitude_up - ground)
