"""Attitude maths on numpy arrays for flight logs and camera mounts: quaternions (w, x, y, z; Hamilton product),
rotation matrices and aerospace Euler angles.

Conventions (those of PX4, ArduPilot, MAVLink and DJI):

* a quaternion ``q`` or matrix ``R`` of "frame A -> frame B" rotates A's axes into B's: ``v_B = R v_A``; the columns
  of ``R`` are A's axes in B's coordinates;
* Euler angles are Z-Y-X intrinsic (yaw about z, then pitch about the new y, then roll about the newest x):
  ``R = Rz(yaw) Ry(pitch) Rx(roll)``; on an FRD body in an NED world, yaw is the heading clockwise from north seen
  from above, pitch is positive nose up, roll positive right wing down. Radians everywhere here.

All functions broadcast over leading axes: ``q [..., 4]``, ``R [..., 3, 3]``, angles ``[...]``.
"""

from __future__ import annotations

import numpy as np


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a b`` of ``[..., 4]`` quaternions (the rotation ``b`` then ``a``, as matrices ``R_a R_b``)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """``[..., 4]`` -> the inverse rotation of unit quaternions."""
    return np.asarray(q, dtype=np.float64) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """``[..., 4]`` unit quaternions -> ``[..., 3, 3]`` rotation matrices."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """``[..., 3, 3]`` rotation matrices -> ``[..., 4]`` unit quaternions with ``w >= 0`` (the largest of the four
    candidate components is computed first, so every rotation is well conditioned)."""
    m = np.asarray(m, dtype=np.float64)
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    cand = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    k = np.argmax(cand, axis=-1)
    s = np.sqrt(np.maximum(np.take_along_axis(cand, k[..., None], -1)[..., 0], 1e-300)) * 2  # 4 |largest component|
    d21, d02, d10 = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]
    s01, s02, s12 = m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1]
    options = np.stack(
        [
            np.stack([s / 4, d21 / s, d02 / s, d10 / s], -1),
            np.stack([d21 / s, s / 4, s01 / s, s02 / s], -1),
            np.stack([d02 / s, s01 / s, s / 4, s12 / s], -1),
            np.stack([d10 / s, s02 / s, s12 / s, s / 4], -1),
        ],
        -2,
    )
    q = np.take_along_axis(options, k[..., None, None], -2)[..., 0, :]
    q = np.where(q[..., :1] < 0, -q, q)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def euler_to_matrix(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Z-Y-X Euler angles (radians) -> ``[..., 3, 3]`` ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    roll, pitch, yaw = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (roll, pitch, yaw)))
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1),
        ],
        -2,
    )


def euler_to_quat(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Z-Y-X Euler angles (radians) -> ``[..., 4]`` unit quaternions (not sign-normalised: ``w`` may be negative
    for yaws beyond +-180 degrees; both signs are the same rotation)."""
    roll, pitch, yaw = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) / 2 for a in (roll, pitch, yaw)))
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.stack(
        [
            cy * cp * cr + sy * sp * sr,
            cy * cp * sr - sy * sp * cr,
            cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr,
        ],
        -1,
    )


def quat_to_euler(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``[..., 4]`` unit quaternions -> Z-Y-X ``(roll, pitch, yaw)`` in radians: roll and yaw in ``(-pi, pi]``,
    pitch in ``[-pi/2, pi/2]`` (at +-90 degrees of pitch only ``yaw - roll`` or ``yaw + roll`` is defined; the
    angles returned still give the same rotation)."""
    r = quat_to_matrix(q)
    cos_pitch = np.hypot(r[..., 2, 1], r[..., 2, 2])
    pitch = np.arctan2(-r[..., 2, 0], cos_pitch)  # well conditioned near +-90 degrees, unlike arcsin
    roll = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    yaw = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    lock = cos_pitch < 1e-9  # gimbal lock: put the whole turn into yaw
    if np.any(lock):
        roll = np.where(lock, 0.0, roll)
        yaw = np.where(lock, np.arctan2(-r[..., 0, 1], r[..., 1, 1]), yaw)
    return roll, pitch, yaw


def slerp(q0: np.ndarray, q1: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions ``[..., 4]`` at fractions ``a [...]`` (0: ``q0``, 1: ``q1``),
    along the shorter arc; normalised linear interpolation where the two are within about 0.005 degrees."""
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    a = np.asarray(a, dtype=np.float64)[..., None]
    d = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(d < 0, -q1, q1)
    d = np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    near = d > 1 - 1e-9
    sin_t = np.where(near, 1.0, np.sin(theta))
    w0 = np.where(near, 1 - a, np.sin((1 - a) * theta) / sin_t)
    w1 = np.where(near, a, np.sin(a * theta) / sin_t)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


__all__ = [
    "euler_to_matrix",
    "euler_to_quat",
    "matrix_to_quat",
    "quat_conjugate",
    "quat_multiply",
    "quat_to_euler",
    "quat_to_matrix",
    "slerp",
]
