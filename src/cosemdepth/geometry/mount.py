"""The camera mount: where the camera sits on the vehicle and which way it looks, and the camera's pose in the world
from the vehicle's (a flight log's) pose.

Frames (docs/own-flight.md draws them):

* **body FRD**: x forward, y right, z down (PX4, ArduPilot, MAVLink, DJI; REP 103's ``base_link`` is FLU: x forward,
  y left, z up);
* **world NED**: x north, y east, z down; a log's attitude is body FRD -> world NED;
* **camera FRD**: the camera's own forward-right-down frame (forward = the viewing direction, right = the image's
  right, down = the image's down);
* **optical** (OpenCV, REP 103 ``_optical``): x right, y down, z forward: ``x = r, y = d, z = f`` of camera FRD
  (:data:`OPTICAL_FROM_CAMERA_FRD`). The model's motions are in this frame.

A mount is ``R_body_optical`` (``[3, 3]``, optical -> body: its columns are the optical axes in body coordinates)
and a lever arm (``[3]``, the camera's origin in body FRD metres). ``--camera-mount SPEC[@X,Y,Z]``:

* ``forward``: camera FRD = body FRD (roll, pitch, yaw 0, 0, 0);
* ``down``: ``0,-90,0``, looking straight down with the image's top toward the vehicle's front;
* ``R,P,Y``: roll, pitch, yaw in degrees of camera FRD relative to body FRD, Z-Y-X intrinsic as for the vehicle's
  attitude, pitch positive up (``0,-30,0``: pitched down 30 degrees);
* a YAML file: a Kalibr camchain (``cam0: T_cam_imu``, the 4x4 imu -> camera-optical transform, its imu frame taken
  as the vehicle's body FRD), or a file with a top-level ``T_body_cam`` (4x4, camera-optical -> body) or
  ``T_cam_imu``; the lever arm is the transform's translation;
* ``@X,Y,Z``: the lever arm in metres, body FRD (not with a YAML file, which has its own).

A gimbal's angles (where a log records them) are the camera FRD's rotation relative to the body at each sample: they
replace the mount's rotation (:func:`camera_poses` ``gimbal_q``); the lever arm stays.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from .attitude import euler_to_matrix, matrix_to_quat, quat_to_matrix

#: ``M`` with ``X_optical = M X_camera_frd``: optical x = camera right, y = camera down, z = camera forward.
OPTICAL_FROM_CAMERA_FRD = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])

#: Named mounts: (roll, pitch, yaw) degrees of camera FRD relative to body FRD.
MOUNT_PRESETS: dict[str, tuple[float, float, float]] = {"forward": (0.0, 0.0, 0.0), "down": (0.0, -90.0, 0.0)}

#: Largest deviation from a rotation (``|R R^T - I|``) accepted in a transform read from a file.
ROTATION_TOLERANCE = 1e-3

_NUM = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?"
_TRIPLE = re.compile(rf"\s*({_NUM})\s*,\s*({_NUM})\s*,\s*({_NUM})\s*")


@dataclass(frozen=True)
class CameraMount:
    """A camera mount: ``R_body_optical [3, 3]`` (optical -> body FRD), ``lever_arm [3]`` (metres, body FRD) and
    ``spec``, the text it was made from."""

    R_body_optical: np.ndarray
    lever_arm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    spec: str = "forward"

    @property
    def R_body_camera_frd(self) -> np.ndarray:
        """``[3, 3]`` camera FRD -> body FRD."""
        return self.R_body_optical @ OPTICAL_FROM_CAMERA_FRD

    @property
    def is_identity(self) -> bool:
        """The camera is the body (``forward`` without a lever arm)."""
        return bool(np.array_equal(self.R_body_camera_frd, np.eye(3)) and not np.any(self.lever_arm))

    def metadata(self) -> dict:
        """A JSON-able description: the spec, ``R_body_optical`` (rows), the lever arm."""
        return {
            "spec": self.spec,
            "R_body_optical": [[float(v) for v in row] for row in self.R_body_optical],
            "lever_arm_m": [float(v) for v in self.lever_arm],
        }


def mount_from_euler(
    roll_deg: float, pitch_deg: float, yaw_deg: float, lever_arm=(0.0, 0.0, 0.0), spec: str | None = None
) -> CameraMount:
    """A mount from camera FRD's roll, pitch, yaw (degrees, Z-Y-X) relative to body FRD."""
    r = euler_to_matrix(math.radians(roll_deg), math.radians(pitch_deg), math.radians(yaw_deg))
    r = np.where(np.abs(r) < 1e-15, 0.0, r)  # cos(90 deg) is 6e-17: keep the presets exact
    text = spec if spec is not None else f"{roll_deg:g},{pitch_deg:g},{yaw_deg:g}"
    return CameraMount(r @ OPTICAL_FROM_CAMERA_FRD.T, _lever(lever_arm, text), text)


def mount_from_T_body_cam(t_body_cam, spec: str = "T_body_cam") -> CameraMount:
    """A mount from a 4x4 camera-optical -> body FRD transform (``X_body = R X_cam + t``)."""
    r, t = _rigid(t_body_cam, spec)
    return CameraMount(r, t, spec)


def mount_from_T_cam_imu(t_cam_imu, spec: str = "T_cam_imu") -> CameraMount:
    """A mount from Kalibr's 4x4 imu -> camera-optical transform (``X_cam = R X_imu + t``), the imu frame being the
    body FRD: ``R_body_optical = R^T``, lever arm ``-R^T t``."""
    r, t = _rigid(t_cam_imu, spec)
    return CameraMount(r.T, -r.T @ t, spec)


def parse_mount(spec: str) -> CameraMount:
    """``--camera-mount SPEC[@X,Y,Z]`` (see the module docstring) -> :class:`CameraMount`; a ConfigError naming the
    option otherwise."""
    if not isinstance(spec, str) or not spec.strip():
        raise ConfigError(f"--camera-mount: expected forward, down, R,P,Y (degrees) or a YAML file, got {spec!r}")
    text = spec.strip()
    head, sep, lever_text = text.rpartition("@") if "@" in text else (text, "", "")
    lever = (0.0, 0.0, 0.0)
    if sep:
        m = _TRIPLE.fullmatch(lever_text)
        if not m:
            raise ConfigError(f"--camera-mount {spec!r}: the lever arm after '@' must be X,Y,Z metres (body FRD)")
        lever = tuple(float(v) for v in m.groups())
    head = head.strip()
    if head.lower() in MOUNT_PRESETS:
        return mount_from_euler(*MOUNT_PRESETS[head.lower()], lever_arm=lever, spec=text)
    m = _TRIPLE.fullmatch(head)
    if m:
        angles = [float(v) for v in m.groups()]
        if not all(math.isfinite(a) and abs(a) <= 360 for a in angles):
            raise ConfigError(f"--camera-mount {spec!r}: roll, pitch, yaw must be degrees in [-360, 360]")
        return mount_from_euler(*angles, lever_arm=lever, spec=text)
    if Path(text).is_file():  # a file whose name holds an '@'
        return _mount_from_yaml(Path(text))
    path = Path(head)
    if sep:
        raise ConfigError(f"--camera-mount {spec!r}: a calibration file has its own lever arm; drop the '@X,Y,Z'")
    if not path.is_file():
        raise ConfigError(
            f"--camera-mount {spec!r}: not forward, down, R,P,Y (degrees, e.g. 0,-30,0) nor an existing YAML file"
        )
    return _mount_from_yaml(path)


def mount_rotation(spec: str) -> np.ndarray:
    """``R_body_optical [3, 3]`` of ``--camera-mount SPEC`` (:func:`parse_mount`)."""
    return parse_mount(spec).R_body_optical


def camera_poses(
    q_body_ned: np.ndarray,
    p_body_ned: np.ndarray,
    R_body_optical: np.ndarray,
    lever_arm: np.ndarray = (0.0, 0.0, 0.0),
    gimbal_q: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The optical frame's pose in the world from the body's.

    Args:
        q_body_ned: ``[N, 4]`` body FRD -> world NED (w, x, y, z).
        p_body_ned: ``[N, 3]`` body origin, world NED metres.
        R_body_optical: ``[3, 3]`` optical -> body FRD (the mount).
        lever_arm: ``[3]`` camera origin in body FRD metres.
        gimbal_q: ``[N, 4]`` camera FRD -> body FRD at each sample (a gimbal's angles); replaces the mount's rotation.
    Returns:
        ``(q_optical_ned [N, 4] with w >= 0, p_optical_ned [N, 3])``: optical -> world NED and the camera's origin,
        ready for ``relative_camera_motions(q, p, "opencv")``.
    """
    r_body = quat_to_matrix(np.asarray(q_body_ned, dtype=np.float64))
    if gimbal_q is None:
        r_body_opt = np.asarray(R_body_optical, dtype=np.float64)
    else:
        r_body_opt = quat_to_matrix(np.asarray(gimbal_q, dtype=np.float64)) @ OPTICAL_FROM_CAMERA_FRD.T
    r = r_body @ r_body_opt
    p = np.asarray(p_body_ned, dtype=np.float64) + r_body @ np.asarray(lever_arm, dtype=np.float64)
    return matrix_to_quat(r), p


def optical_to_camera_frd(q_optical_ned: np.ndarray) -> np.ndarray:
    """``[N, 4]`` optical -> NED quaternions -> camera FRD -> NED (the attitude a Mid-Air-style camera pose uses,
    e.g. SynthAir's renderer), ``w >= 0``."""
    return matrix_to_quat(quat_to_matrix(q_optical_ned) @ OPTICAL_FROM_CAMERA_FRD)


def _lever(values, spec: str) -> np.ndarray:
    lever = np.asarray(values, dtype=np.float64).reshape(-1)
    if lever.shape != (3,) or not np.all(np.isfinite(lever)) or np.any(np.abs(lever) > 1000):
        raise ConfigError(
            f"--camera-mount {spec!r}: the lever arm must be 3 finite metres (at most 1000), got {values}"
        )
    return lever


def _rigid(t, spec: str) -> tuple[np.ndarray, np.ndarray]:
    try:
        m = np.asarray(t, dtype=np.float64)
    except (TypeError, ValueError):
        m = np.zeros(0)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise ConfigError(f"--camera-mount {spec}: a transform must be a 4x4 matrix of finite numbers")
    if not np.allclose(m[3], [0, 0, 0, 1]):
        raise ConfigError(f"--camera-mount {spec}: the last row of a 4x4 transform must be 0 0 0 1, got {m[3]}")
    r = m[:3, :3]
    err = float(np.abs(r @ r.T - np.eye(3)).max())
    if err > ROTATION_TOLERANCE or np.linalg.det(r) < 0:
        raise ConfigError(
            f"--camera-mount {spec}: the transform's 3x3 part is not a rotation (|R R^T - I| = {err:.2g}, "
            f"det {np.linalg.det(r):.3f})"
        )
    u, _, vt = np.linalg.svd(r)  # the nearest rotation: drop the file's rounding
    return u @ vt, _lever(m[:3, 3], spec)


def _mount_from_yaml(path: Path) -> CameraMount:
    import yaml

    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ConfigError(f"--camera-mount {path}: cannot read the YAML file ({first})") from None
    if isinstance(data, dict) and "T_body_cam" in data:
        return mount_from_T_body_cam(data["T_body_cam"], f"{path} (T_body_cam)")
    if isinstance(data, dict) and "T_cam_imu" in data:
        return mount_from_T_cam_imu(data["T_cam_imu"], f"{path} (T_cam_imu)")
    if isinstance(data, dict) and isinstance(data.get("cam0"), dict) and "T_cam_imu" in data["cam0"]:
        return mount_from_T_cam_imu(data["cam0"]["T_cam_imu"], f"{path} (Kalibr cam0.T_cam_imu)")
    raise ConfigError(
        f"--camera-mount {path}: the YAML file has no cam0.T_cam_imu (Kalibr camchain), T_cam_imu or T_body_cam"
    )


__all__ = [
    "MOUNT_PRESETS",
    "OPTICAL_FROM_CAMERA_FRD",
    "ROTATION_TOLERANCE",
    "CameraMount",
    "camera_poses",
    "mount_from_T_body_cam",
    "mount_from_T_cam_imu",
    "mount_from_euler",
    "mount_rotation",
    "optical_to_camera_frd",
    "parse_mount",
]
