"""Synthetic camera attitudes and the rotation a video of them shows (for the clock-offset tests)."""

from __future__ import annotations

import numpy as np

from cosemdepth.data.quaternion import qmul, qrotate
from cosemdepth.flightlogs.timesync import Attitude, VideoRotations, pair_rotations


def euler_quaternions(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """Z-Y-X angles (radians) -> ``[N, 4]`` quaternions (w, x, y, z)."""
    z = np.zeros_like(yaw)
    qz = np.stack([np.cos(yaw / 2), z, z, np.sin(yaw / 2)], -1)
    qy = np.stack([np.cos(pitch / 2), z, np.sin(pitch / 2), z], -1)
    qx = np.stack([np.cos(roll / 2), np.sin(roll / 2), z, z], -1)
    return qmul(qmul(qz, qy), qx)


def smooth(n: int, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """``[n]`` Gaussian-filtered white noise of unit standard deviation (``sigma`` in samples)."""
    r = int(3 * sigma)
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    x = np.convolve(rng.normal(size=n + 2 * r), k, mode="valid")
    return x / x.std()


def random_attitude(
    seconds: float, rng: np.random.Generator, hz: float = 200.0, t0: float = 1000.0, amp_deg: float = 15.0
) -> Attitude:
    """A camera that wanders in yaw, pitch and roll (angles of ``amp_deg`` standard deviation, changing over
    about a second), sampled at ``hz`` from log time ``t0``."""
    n = int(seconds * hz)
    t = t0 + np.arange(n) / hz
    yaw, pitch, roll = (np.deg2rad(amp_deg) * smooth(n, 0.3 * hz, rng) for _ in range(3))
    return Attitude(t, euler_quaternions(yaw + 0.01 * np.arange(n) / hz, pitch, roll))


def video_of(
    att: Attitude, offset: float, pts: np.ndarray, rng: np.random.Generator, noise: float = 0.0
) -> VideoRotations:
    """The rotations a video with frame times ``pts`` shows when its first frame is at log time ``offset``
    (plus white noise of ``noise`` radians per axis)."""
    a, b = pts[:-1] - pts[0], pts[1:] - pts[0]
    rv = pair_rotations(att, offset + a, offset + b) + rng.normal(size=(len(a), 3)) * noise
    return VideoRotations(pts[:-1], pts[1:], rv, np.ones(len(a), bool), float(pts[0]))


def render_sphere(q_cam_world: np.ndarray, size: tuple[int, int], focal: float, seed: int = 3) -> np.ndarray:
    """What a centred pinhole camera with attitude ``q`` (optical frame -> world) sees of a textured sphere at
    infinity: ``[H, W]`` float (each ray's brightness is a sum of sinusoids of its world direction)."""
    rng = np.random.default_rng(seed)
    freq = rng.normal(size=(40, 3)) * rng.uniform(4, 20, size=(40, 1))
    phase = rng.uniform(0, 2 * np.pi, 40)
    h, w = size
    j, i = np.meshgrid(np.arange(w) + 0.5 - w / 2, np.arange(h) + 0.5 - h / 2)
    rays = np.stack([j / focal, i / focal, np.ones_like(j)], -1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    world = qrotate(np.broadcast_to(q_cam_world, rays.shape[:-1] + (4,)), rays)
    return np.sin(world @ freq.T + phase).sum(-1)
