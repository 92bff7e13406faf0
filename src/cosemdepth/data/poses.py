"""Absolute pose files (TUM, CSV) and their conversion to the model's relative camera motion (design 2.2).

Pose files hold, per line, a timestamp and the pose of the camera (or body) in a fixed world frame: the position
``p`` of its origin in world coordinates and the unit quaternion ``q`` rotating its axes into the world's
(``X_world = R(q) X_local + p``, "camera-to-world" / "body-to-world"). Formats:

* **TUM** (``.txt``/``.tum``): ``timestamp tx ty tz qx qy qz qw`` separated by spaces, ``#`` comments;
  note the scalar-*last* quaternion;
* **CSV** (``.csv``): a header naming the columns, comma separated, ``#`` comments; columns ``timestamp``
  (alias ``time``; optional when poses are matched to images by order), ``tx ty tz`` and ``qw qx qy qz`` in any
  order, e.g. ``timestamp,tx,ty,tz,qw,qx,qy,qz``.

Axes of the local frame (``convention``), as 3x3 ``M`` with ``X_camera = M X_local``:

* ``"opencv"`` (default): the optical frame, x right, y down, z forward (TUM RGB-D ground truth, COLMAP and
  OpenCV camera-to-world poses); ``M = I``;
* ``"ned"``: a forward-looking camera on a body with x forward, y right, z down (Mid-Air, AirSim, PX4);
* ``"flu"``: a forward-looking camera on a body with x forward, y left, z up (ROS REP 103 ``base_link``);
* ``"opengl"``: camera x right, y up, z backward (OpenGL/Blender/NeRF camera-to-world); ``M = diag(1, -1, -1)``;
* or any 3x3 rotation matrix ``M``.

The relative motion of frame ``i`` w.r.t. the previous sampled frame ``j`` is, in local axes,
``R_l = R_j^T R_i`` and ``t_l = R_j^T (p_i - p_j)``, and in camera axes ``R = M R_l M^T``, ``t = M t_l``, so that
``X_prev = R X_curr + t`` (design 2.2).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import ConfigError, DatasetError
from .files import read_text
from .quaternion import qfrom_matrix, qmatrix

#: Accepted deviation of a pose quaternion's norm from 1 (poses are renormalized after the check).
QUATERNION_TOLERANCE = 1e-2

CONVENTIONS: dict[str, np.ndarray] = {
    "opencv": np.eye(3),
    "ned": np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),
    "flu": np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]),
    "opengl": np.diag([1.0, -1.0, -1.0]),
}

_CSV_ALIASES = {
    "timestamp": ("timestamp", "time"),
    "tx": ("tx",),
    "ty": ("ty",),
    "tz": ("tz",),
    "qw": ("qw",),
    "qx": ("qx",),
    "qy": ("qy",),
    "qz": ("qz",),
}


@dataclass
class PoseTrack:
    """Poses of one file: ``timestamps`` [N] (None if the file has none), ``positions`` [N, 3], ``quaternions``
    [N, 4] (w, x, y, z, unit), and the 1-based ``lines`` of the file they came from."""

    path: Path
    timestamps: np.ndarray | None
    positions: np.ndarray
    quaternions: np.ndarray
    lines: np.ndarray

    def __len__(self) -> int:
        return len(self.positions)


def _data_lines(path: Path) -> list[tuple[int, str]]:
    text = read_text(path, "pose file")
    return [
        (i, ln.strip())
        for i, ln in enumerate(text.splitlines(), start=1)
        if ln.strip() and not ln.lstrip().startswith("#")
    ]


def _float(path: Path, line: int, text: str, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise DatasetError(f"{path}:{line}: malformed number {text!r} for {what}") from None
    if not math.isfinite(v):
        raise DatasetError(f"{path}:{line}: {what} is {v} (NaN/inf)")
    return v


def read_tum(path: str | Path) -> PoseTrack:
    """Read a TUM trajectory file ``timestamp tx ty tz qx qy qz qw``."""
    path = Path(path)
    ts, pos, quat, lines = [], [], [], []
    for line_no, ln in _data_lines(path):
        fields = ln.replace(",", " ").split()
        if len(fields) != 8:
            raise DatasetError(
                f"{path}:{line_no}: expected 8 values 'timestamp tx ty tz qx qy qz qw', got {len(fields)}"
            )
        names = ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")
        v = [_float(path, line_no, f, n) for f, n in zip(fields, names)]
        ts.append(v[0])
        pos.append(v[1:4])
        quat.append([v[7], v[4], v[5], v[6]])
        lines.append(line_no)
    return _finish(path, np.array(ts), pos, quat, lines)


def read_pose_csv(path: str | Path) -> PoseTrack:
    """Read a pose CSV with a header (see the module docstring for the columns)."""
    path = Path(path)
    data = _data_lines(path)
    if not data:
        raise DatasetError(f"{path}: empty pose file")
    text = "\n".join(ln for _, ln in data)
    try:
        return _parse_pose_csv(path, data, csv.reader(io.StringIO(text)))
    except csv.Error as e:  # e.g. a field over the csv module's size limit, a NUL byte
        raise DatasetError(f"{path}: malformed pose CSV ({e})") from None


def _parse_pose_csv(path: Path, data: list[tuple[int, str]], reader) -> PoseTrack:
    header = [h.strip().lower() for h in next(reader)]
    cols: dict[str, int] = {}
    for key, aliases in _CSV_ALIASES.items():
        for a in aliases:
            if a in header:
                cols[key] = header.index(a)
                break
    missing = [k for k in ("tx", "ty", "tz", "qw", "qx", "qy", "qz") if k not in cols]
    if missing:
        raise DatasetError(f"{path}: pose CSV header lacks column(s) {missing}; found {header}")
    ts, pos, quat, lines = [], [], [], []
    for (line_no, _), row in zip(data[1:], reader):
        if len(row) != len(header):
            raise DatasetError(f"{path}:{line_no}: expected {len(header)} fields, got {len(row)} (truncated?)")
        get = {k: _float(path, line_no, row[i].strip(), k) for k, i in cols.items()}
        if "timestamp" in cols:
            ts.append(get["timestamp"])
        pos.append([get["tx"], get["ty"], get["tz"]])
        quat.append([get["qw"], get["qx"], get["qy"], get["qz"]])
        lines.append(line_no)
    return _finish(path, np.array(ts) if "timestamp" in cols else None, pos, quat, lines)


def _finish(path: Path, ts: np.ndarray | None, pos: list, quat: list, lines: list) -> PoseTrack:
    if not pos:
        raise DatasetError(f"{path}: pose file holds no poses")
    pos_a = np.asarray(pos, dtype=np.float64)
    quat_a = np.asarray(quat, dtype=np.float64)
    lines_a = np.asarray(lines)
    with np.errstate(over="ignore"):  # an overflowing norm is reported as not unit below
        norms = np.linalg.norm(quat_a, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1) > QUATERNION_TOLERANCE)
    if bad.size:
        raise DatasetError(f"{path}:{lines_a[bad[0]]}: quaternion is not unit (norm {norms[bad[0]]:.6f})")
    quat_a /= norms[:, None]
    if ts is not None:
        ts = np.asarray(ts, dtype=np.float64)
        back = np.flatnonzero(np.diff(ts) <= 0)
        if back.size:
            raise DatasetError(
                f"{path}:{lines_a[back[0] + 1]}: timestamps must increase strictly "
                f"({ts[back[0] + 1]} follows {ts[back[0]]})"
            )
    return PoseTrack(path, ts, pos_a, quat_a, lines_a)


def read_poses(path: str | Path, fmt: str = "auto") -> PoseTrack:
    """Read a pose file; ``fmt`` is ``"tum"``, ``"csv"`` or ``"auto"`` (``.csv`` -> CSV, else TUM)."""
    path = Path(path)
    if fmt == "auto":
        fmt = "csv" if path.suffix.lower() == ".csv" else "tum"
    if fmt == "tum":
        return read_tum(path)
    if fmt == "csv":
        return read_pose_csv(path)
    raise ConfigError(f"pose_format must be 'auto', 'tum' or 'csv', got {fmt!r}")


def slerp(q0: np.ndarray, q1: np.ndarray, a: float) -> np.ndarray:
    """Spherical linear interpolation between unit quaternions ``q0`` (a = 0) and ``q1`` (a = 1)."""
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    d = float(np.dot(q0, q1))
    if d < 0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + a * (q1 - q0)
    else:
        theta = math.acos(min(d, 1.0))
        q = (math.sin((1 - a) * theta) * q0 + math.sin(a * theta) * q1) / math.sin(theta)
    return q / np.linalg.norm(q)


def interpolate_pose(
    a: float, p0: np.ndarray, q0: np.ndarray, p1: np.ndarray, q1: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The pose a fraction ``a`` of the way from pose 0 (``a = 0``) to pose 1 (``a = 1``): linear position
    ``(1 - a) p0 + a p1`` and :func:`slerp` rotation (quaternions w, x, y, z)."""
    p = (1 - a) * np.asarray(p0, dtype=np.float64) + a * np.asarray(p1, dtype=np.float64)
    return p, slerp(q0, q1, a)


def poses_at(
    track: PoseTrack,
    times: np.ndarray,
    names: list[str],
    max_gap: float,
    exact_tolerance: float = 1e-6,
    *,
    pose_times: np.ndarray | None = None,
    skip_unposed: bool = False,
    hint: Callable[[float], str] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses at ``times`` (seconds): the pose with the same timestamp (within ``exact_tolerance`` s), else the
    interpolation (linear position, slerp rotation) of the two poses around it when they are at most ``max_gap`` s
    apart. ``pose_times``: the track's timestamps in seconds (default: ``track.timestamps`` as written).

    Returns ``(positions [N, 3], quaternions [N, 4], posed [N] bool)``. A time without a pose is a DatasetError
    naming ``names[i]`` (the image) and the pose file, ending with ``hint(distance to the nearest pose)`` when that
    is not empty; with ``skip_unposed`` its ``posed`` entry is False instead (and its pose rows are NaN).
    """
    if track.timestamps is None:
        raise DatasetError(f"{track.path}: pose file has no timestamp column; match images by order instead")
    ts = track.timestamps if pose_times is None else np.asarray(pose_times, dtype=np.float64)
    pos = np.full((len(times), 3), np.nan)
    quat = np.full((len(times), 4), np.nan)
    posed = np.zeros(len(times), dtype=bool)
    for i, t in enumerate(times):
        k = int(np.searchsorted(ts, t))
        near = [j for j in (k - 1, k) if 0 <= j < len(ts)]
        j_best = min(near, key=lambda j: abs(ts[j] - t))
        if abs(ts[j_best] - t) <= exact_tolerance:
            pos[i], quat[i] = track.positions[j_best], track.quaternions[j_best]
            posed[i] = True
            continue
        if 0 < k < len(ts) and ts[k] - ts[k - 1] <= max_gap + 1e-9:
            a = (t - ts[k - 1]) / (ts[k] - ts[k - 1])
            pos[i], quat[i] = interpolate_pose(
                a, track.positions[k - 1], track.quaternions[k - 1], track.positions[k], track.quaternions[k]
            )
            posed[i] = True
            continue
        if skip_unposed:
            continue
        around = (
            f"poses {t - ts[k - 1]:.6f} s before and {ts[k] - t:.6f} s after, {ts[k] - ts[k - 1]:.6f} s apart"
            if 0 < k < len(ts)
            else f"nearest pose {ts[j_best] - t:+.6f} s away"
        )
        extra = hint(abs(ts[j_best] - t)) if hint is not None else ""
        raise DatasetError(
            f"{names[i]}: no pose for timestamp {t:.6f} in {track.path} ({around}; poses cover {ts[0]:.6f}.."
            f"{ts[-1]:.6f} s; interpolation only across gaps <= {max_gap:g} s: --max-pose-gap, or --skip-unposed)"
            + (f"; {extra}" if extra else "")
        )
    return pos, quat, posed


def convention_matrix(convention: str | np.ndarray) -> np.ndarray:
    """``M`` with ``X_camera = M X_local`` for a convention name or a 3x3 rotation matrix."""
    if isinstance(convention, str):
        if convention not in CONVENTIONS:
            raise ConfigError(
                f"pose convention must be one of {sorted(CONVENTIONS)} or a 3x3 matrix, got {convention!r}"
            )
        return CONVENTIONS[convention]
    m = np.asarray(convention, dtype=np.float64)
    if m.shape != (3, 3) or not np.allclose(m @ m.T, np.eye(3), atol=1e-6) or np.linalg.det(m) < 0:
        raise ConfigError("a pose convention matrix must be a 3x3 rotation matrix")
    return m


def relative_camera_motions(
    quaternions: np.ndarray, positions: np.ndarray, convention: str | np.ndarray = "opencv"
) -> tuple[np.ndarray, np.ndarray]:
    """Absolute poses ``[N, 4]`` (w, x, y, z) / ``[N, 3]`` -> per-frame relative motion in camera axes.

    Returns ``(q [N, 4], t [N, 3])`` with row ``i > 0`` the motion from frame ``i - 1`` to frame ``i``
    (``X_{i-1} = R(q_i) X_i + t_i``, w >= 0) and row 0 the identity (frame 0 is a reset).
    """
    m = convention_matrix(convention)
    r = qmatrix(np.asarray(quaternions, dtype=np.float64))  # [N, 3, 3] local -> world
    p = np.asarray(positions, dtype=np.float64)
    n = len(p)
    rot = np.tile(np.eye(3), (n, 1, 1))
    trans = np.zeros((n, 3))
    if n > 1:
        r_prev_t = np.transpose(r[:-1], (0, 2, 1))
        r_loc = r_prev_t @ r[1:]
        t_loc = np.einsum("nij,nj->ni", r_prev_t, p[1:] - p[:-1])
        rot[1:] = m @ r_loc @ m.T
        trans[1:] = t_loc @ m.T
    return qfrom_matrix(rot), trans
