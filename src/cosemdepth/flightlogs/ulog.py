"""PX4 ULog (``.ulg``) through ``pyulog``.

Attitude and position come from ``vehicle_odometry`` (``q`` and ``position``, in the frame its ``pose_frame`` names:
1 NED, 2 FRD, a world frame with z down whose x is the vehicle's initial heading; older logs: ``local_frame`` 0 NED,
1 FRD, and ``x, y, z``) when it has both; else ``vehicle_attitude.q`` with ``vehicle_local_position`` (``x, y, z``
where ``xy_valid`` and ``z_valid``) or, without it, ``vehicle_global_position`` (latitude, longitude, altitude, to
metres from the first fix). Times are ``timestamp_sample`` (when the sample was measured) where the topic has it,
else ``timestamp``, both microseconds since boot. NaN and invalid samples are dropped. UTC from ``sensor_gps`` /
``vehicle_gps_position`` (``time_utc_usec`` against ``timestamp``).
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np

from ..errors import DatasetError
from ..optional import require
from .geodetic import geodetic_to_ned
from .log import FlightLog, describe, make_series, quaternion_series

#: The topics read (pyulog's message filter).
TOPICS = (
    "vehicle_odometry",
    "vehicle_attitude",
    "vehicle_local_position",
    "vehicle_global_position",
    "sensor_gps",
    "vehicle_gps_position",
)
#: vehicle_odometry frame numbers -> names: ``pose_frame`` (PX4 1.14+) and the older ``local_frame``.
POSE_FRAMES = {"pose_frame": {1: "NED", 2: "FRD"}, "local_frame": {0: "NED", 1: "FRD"}}


def read_ulog(path: Path) -> FlightLog:
    """Read a PX4 ULog file (see the module docstring)."""
    pyulog = require("pyulog", f"reading the PX4 log {path}")
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            ulog = pyulog.ULog(str(path), list(TOPICS), disable_str_exceptions=True)
    except Exception as e:  # pyulog raises whatever its parser meets on a damaged file
        raise DatasetError(f"{path}: not a readable PX4 ULog ({_first_line(e)})") from None
    topics = {d.name: d.data for d in ulog.data_list if d.multi_id == 0}
    used: dict = {"clock": "microseconds since boot"}
    if getattr(ulog, "file_corruption", False):
        used["damage"] = "pyulog found damaged data and skipped it"

    attitude = position = None
    odo_att = odo_pos = None
    note = ""
    if "vehicle_odometry" in topics:
        odo_att, odo_pos, note = _odometry(path, topics["vehicle_odometry"])
    if odo_att is not None and odo_pos is not None:
        attitude, position = odo_att, odo_pos
        used["attitude"] = describe("vehicle_odometry.q", attitude, note)
        used["position"] = describe("vehicle_odometry.position", position, note)
    elif "vehicle_attitude" in topics:
        d = topics["vehicle_attitude"]
        t, clock = _times(path, d, "vehicle_attitude")
        attitude = quaternion_series(path, "vehicle_attitude", t, _columns(path, d, "vehicle_attitude", "q", 4))
        used["attitude"] = describe("vehicle_attitude.q", attitude, clock)
    elif odo_att is not None and note.startswith("NED"):  # the same NED world as vehicle_local_position
        attitude = odo_att
        used["attitude"] = describe("vehicle_odometry.q", attitude, note)
    resolution = 0.0
    if position is None and "vehicle_local_position" in topics:
        d = topics["vehicle_local_position"]
        t, clock = _times(path, d, "vehicle_local_position")
        xyz = np.stack([_field(path, d, "vehicle_local_position", k) for k in "xyz"], 1)
        valid = np.ones(len(t), dtype=bool)
        for flag in ("xy_valid", "z_valid"):
            if flag in d:
                valid &= d[flag].astype(bool)
        position = make_series(path, "vehicle_local_position", t[valid], xyz[valid])
        used["position"] = describe("vehicle_local_position.x/y/z where xy_valid and z_valid", position, clock)
    if position is None and "vehicle_global_position" in topics:
        d = topics["vehicle_global_position"]
        t, clock = _times(path, d, "vehicle_global_position")
        lat, lon, alt = (_field(path, d, "vehicle_global_position", k) for k in ("lat", "lon", "alt"))
        ok = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(alt) & ~((lat == 0) & (lon == 0))
        if ok.any():
            position = make_series(path, "vehicle_global_position", t[ok], geodetic_to_ned(lat[ok], lon[ok], alt[ok]))
            used["position"] = describe(
                "vehicle_global_position.lat/lon/alt, metres from the first fix", position, clock
            )
    if attitude is None:
        found = ", ".join(sorted(topics)) or "none of them"
        raise DatasetError(
            f"{path}: the PX4 log has no attitude (vehicle_odometry or vehicle_attitude); topics read: {found}"
        )
    utc = _utc_offset(topics)
    if utc is not None:
        used["utc"] = f"{utc[1]}.time_utc_usec"
    return FlightLog(
        path=path,
        format="ulog",
        attitude=attitude,
        position=position,
        position_resolution_m=resolution,
        gimbal=None,
        utc_offset_s=None if utc is None else utc[0],
        used=used,
    )


def _odometry(path: Path, d: dict):
    """vehicle_odometry -> (attitude, position, "NED" / "FRD" note) in its most common valid frame."""
    t, clock = _times(path, d, "vehicle_odometry")
    key = next((k for k in POSE_FRAMES if k in d), None)
    if key is None:
        return None, None, ""
    frames = d[key].astype(int)
    names = POSE_FRAMES[key]
    valid = [f for f in names if np.any(frames == f)]
    if not valid:
        return None, None, ""
    frame = max(valid, key=lambda f: int(np.sum(frames == f)))
    rows = frames == frame
    q = _columns(path, d, "vehicle_odometry", "q", 4)[rows]
    if "position[0]" in d:
        p = _columns(path, d, "vehicle_odometry", "position", 3)[rows]
    else:
        p = np.stack([_field(path, d, "vehicle_odometry", k) for k in "xyz"], 1)[rows]
    note = f"{names[frame]} world, {key} {frame}, {clock}"
    if names[frame] == "FRD":
        note = f"FRD world: z down, x the initial heading, {key} {frame}, {clock}"
    attitude = quaternion_series(path, "vehicle_odometry", t[rows], q)
    position = make_series(path, "vehicle_odometry", t[rows], p)
    return attitude, position, note


def _times(path: Path, d: dict, topic: str) -> tuple[np.ndarray, str]:
    ts = d.get("timestamp_sample")
    if ts is not None and len(ts) and np.all(ts > 0):
        return ts.astype(np.float64) * 1e-6, "timestamp_sample"
    return _field(path, d, topic, "timestamp") * 1e-6, "timestamp"


def _field(path: Path, d: dict, topic: str, name: str) -> np.ndarray:
    if name not in d:
        raise DatasetError(f"{path}: PX4 topic {topic} has no field {name!r}")
    return d[name].astype(np.float64)


def _columns(path: Path, d: dict, topic: str, name: str, n: int) -> np.ndarray:
    return np.stack([_field(path, d, topic, f"{name}[{i}]") for i in range(n)], 1)


def _utc_offset(topics: dict) -> tuple[float, str] | None:
    for name in ("sensor_gps", "vehicle_gps_position"):
        d = topics.get(name)
        if d is None or "time_utc_usec" not in d or "timestamp" not in d:
            continue
        utc = d["time_utc_usec"].astype(np.float64)
        ok = utc > 0
        if ok.any():
            return float(np.median((utc[ok] - d["timestamp"][ok].astype(np.float64)) * 1e-6)), name
    return None


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0][:200] if text else type(e).__name__


__all__ = ["POSE_FRAMES", "TOPICS", "read_ulog"]
