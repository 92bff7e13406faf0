"""Independent helpers of the flight-log tests: an analytic flight (Euler angles and a helix, written out by hand),
rotation matrices and quaternions by the textbook formulas, and the rotation angle between two attitudes."""

from __future__ import annotations

import numpy as np

#: Flight time (seconds) of the analytic flights; log clock = flight time + BOOT.
DURATION = 4.0
BOOT = 12.5


def angles(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Roll, pitch, yaw (radians) of the analytic flight at flight times ``t``: a slow yaw sweep across north
    (-1.0 to 1.4 rad), pitch and roll oscillating by up to 0.25 and 0.2 rad."""
    t = np.asarray(t, dtype=np.float64)
    return 0.2 * np.sin(0.9 * t + 0.5), 0.25 * np.sin(1.3 * t), -1.0 + 0.6 * t


def position(t: np.ndarray) -> np.ndarray:
    """``[N, 3]`` NED metres: a climbing helix around (100, -50)."""
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    return np.stack([100 + 20 * np.cos(0.3 * t), -50 + 20 * np.sin(0.3 * t), -30.0 - 2.0 * t], 1)


def euler_matrix(roll, pitch, yaw) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` ([N, 3, 3]), the three elementary rotations multiplied out."""
    roll, pitch, yaw = np.broadcast_arrays(np.asarray(roll, float), np.asarray(pitch, float), np.asarray(yaw, float))
    out = []
    for r, p, y in zip(roll.ravel(), pitch.ravel(), yaw.ravel()):
        rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
        ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
        rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
        out.append(rz @ ry @ rx)
    return np.array(out)


def quaternion_matrix(q) -> np.ndarray:
    """``[N, 4]`` (w, x, y, z) -> ``[N, 3, 3]``, the textbook formula."""
    q = np.atleast_2d(np.asarray(q, dtype=np.float64))
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], 1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], 1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1),
        ],
        1,
    )


def matrix_quaternion(m) -> np.ndarray:
    """``[N, 3, 3]`` -> ``[N, 4]`` for rotations by less than about 160 degrees (trace > -0.9)."""
    out = []
    for r in np.asarray(m, dtype=np.float64).reshape(-1, 3, 3):
        w = np.sqrt(1.0 + np.trace(r)) / 2
        out.append([w, (r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w), (r[1, 0] - r[0, 1]) / (4 * w)])
    return np.array(out)


def truth_quaternions(t) -> np.ndarray:
    """The analytic flight's attitude (body FRD -> NED) at ``t`` as quaternions."""
    return matrix_quaternion(euler_matrix(*angles(t)))


def angle_between(r1: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """Rotation angle (degrees) between ``[N, 3, 3]`` rotations."""
    rel = np.transpose(r1, (0, 2, 1)) @ r2
    return np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)))


def sample_times(rate: float, phase: float, tick: float) -> np.ndarray:
    """Log-clock ticks (integers of ``tick`` seconds) of a stream at ``rate`` Hz over the flight."""
    t = np.arange(phase, DURATION, 1.0 / rate)
    return np.unique(np.round((t + BOOT) / tick).astype(np.int64))
