"""A flight for the video + log tests: a ULog of a vehicle flying north while yawing, and a short video."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "data"))
from _videos import pattern, write_pyav  # noqa: E402

from cosemdepth.flightlogs.ulog_writer import PX4_FORMATS, Topic, write_ulog  # noqa: E402

RATE = 100.0  # log samples per second
LOG_START, LOG_END = 5.0, 20.0  # seconds since boot
SPEED = 2.0  # m/s north
YAW_RATE = 0.2  # rad/s, turning right (clockwise from above)


def body_pose(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vehicle flies north at SPEED while yawing right at YAW_RATE: body FRD -> NED quaternions, NED metres."""
    yaw = YAW_RATE * (t - LOG_START)
    q = np.stack([np.cos(yaw / 2), 0 * t, 0 * t, np.sin(yaw / 2)], -1)
    p = np.stack([SPEED * (t - LOG_START), 0 * t, -10.0 + 0 * t], -1)
    return q, p


def write_log(
    path: Path, q_fn=body_pose, positions: bool = True, start=LOG_START, end=LOG_END, utc_at_boot: float | None = None
) -> Path:
    """A ULog of ``q_fn``'s attitude (and positions) at RATE Hz from log time ``start``; with ``utc_at_boot``, a
    ``sensor_gps`` topic whose UTC clock says the boot was at that Unix time."""
    t = np.arange(start, end, 1 / RATE)
    q, p = q_fn(t)
    us = np.round(t * 1e6).astype(np.uint64)
    topics = [
        Topic("vehicle_attitude", PX4_FORMATS["vehicle_attitude"], {"timestamp": us, "timestamp_sample": us, "q": q})
    ]
    if positions:
        data = {"timestamp": us, "timestamp_sample": us, "x": p[:, 0], "y": p[:, 1], "z": p[:, 2]}
        data.update(xy_valid=np.ones(len(t)), z_valid=np.ones(len(t)))
        topics.append(Topic("vehicle_local_position", PX4_FORMATS["vehicle_local_position"], data))
    if utc_at_boot is not None:
        g = us[::20]
        utc = (g + np.uint64(round(utc_at_boot * 1e6))).astype(np.uint64)
        data = {"timestamp": g, "timestamp_sample": g, "time_utc_usec": utc, "fix_type": np.full(len(g), 3)}
        topics.append(Topic("sensor_gps", PX4_FORMATS["sensor_gps"], data))
    write_ulog(path, topics, start_us=int(start * 1e6) - 1000)
    return path


def write_video(path: Path, n: int = 20, fps: float = 25.0) -> Path:
    return write_pyav(path, [pattern(k) for k in range(n)], np.arange(n) / fps)
