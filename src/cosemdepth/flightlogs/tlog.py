"""MAVLink telemetry logs (``.tlog``, written by ground stations: each packet preceded by its 8-byte big-endian
Unix time of reception in microseconds) through ``pymavlink``'s ``mavlogfile``.

Only the vehicle's own messages are used: those of the system id that sends the most attitude messages (a ground
station's or a companion computer's packets are left out). Attitude: ``ATTITUDE_QUATERNION`` (w, x, y, z), else
``ATTITUDE`` (roll, pitch, yaw in radians, Z-Y-X of the FRD body in NED). Position: ``LOCAL_POSITION_NED`` (metres
from the estimator's origin), else ``GLOBAL_POSITION_INT`` (1e-7 degree integers, altitude in millimetres, to metres
from the first fix). Times: the vehicle's ``time_boot_ms`` (the sample's own time, not the reception time, which
carries the telemetry link's delay). UTC: ``SYSTEM_TIME`` (``time_unix_usec`` against ``time_boot_ms``), else the
reception times (then including the link's delay).
"""

from __future__ import annotations

import contextlib
import io
from collections import Counter
from pathlib import Path

import numpy as np

from ..errors import DatasetError
from ..geometry.attitude import euler_to_quat
from ..optional import require
from .geodetic import geodetic_to_ned, quantisation_m
from .log import FlightLog, describe, make_series, quaternion_series

#: The message types read.
MESSAGES = ("ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "SYSTEM_TIME")
#: GLOBAL_POSITION_INT's steps: 1e-7 degrees, 1 mm.
GLOBAL_STEP_DEG = 1e-7
GLOBAL_STEP_ALT_M = 1e-3


def read_tlog(path: Path) -> FlightLog:
    """Read a MAVLink telemetry log (see the module docstring)."""
    mavutil = require("pymavlink.mavutil", f"reading the MAVLink log {path}")
    msgs: dict[int, dict[str, list]] = {}
    bad = total = 0
    noise = io.StringIO()
    try:
        with contextlib.redirect_stdout(noise), contextlib.redirect_stderr(noise):
            log = mavutil.mavlogfile(str(path), robust_parsing=True)
            try:
                while True:
                    m = log.recv_msg()
                    if m is None:
                        break
                    total += 1
                    kind = m.get_type()
                    if kind == "BAD_DATA":
                        bad += 1
                    elif kind in MESSAGES:
                        msgs.setdefault(m.get_srcSystem(), {}).setdefault(kind, []).append((m._timestamp, m))
            finally:
                log.close()
    except Exception as e:  # mavlogfile raises whatever its parser meets on a damaged file
        raise DatasetError(f"{path}: not a readable MAVLink telemetry log ({_first_line(e)})") from None
    if total == bad:
        raise DatasetError(f"{path}: no MAVLink packet could be read from the telemetry log")
    counts = Counter(
        {sysid: len(k.get("ATTITUDE", [])) + len(k.get("ATTITUDE_QUATERNION", [])) for sysid, k in msgs.items()}
    )
    if not counts or counts.most_common(1)[0][1] == 0:
        found = sorted({kind for k in msgs.values() for kind in k})
        raise DatasetError(
            f"{path}: the telemetry log has no attitude (ATTITUDE or ATTITUDE_QUATERNION); messages read: "
            f"{', '.join(found) or 'none of these: ' + ', '.join(MESSAGES)}"
        )
    sysid = counts.most_common(1)[0][0]
    rows = msgs[sysid]
    used: dict = {"clock": "time_boot_ms (milliseconds since the vehicle's boot)", "system": f"system id {sysid}"}
    if len(counts) > 1:
        used["system"] += f" (of {len(counts)} systems in the log)"
    if bad:
        used["damage"] = f"{bad} unreadable stretches of bytes skipped by the reader"

    if rows.get("ATTITUDE_QUATERNION"):
        t, q = _arrays(rows["ATTITUDE_QUATERNION"], ("q1", "q2", "q3", "q4"))
        attitude = quaternion_series(path, "ATTITUDE_QUATERNION", t, q)
        used["attitude"] = describe("ATTITUDE_QUATERNION.q1..q4", attitude)
    else:
        t, rpy = _arrays(rows["ATTITUDE"], ("roll", "pitch", "yaw"))
        attitude = quaternion_series(path, "ATTITUDE", t, euler_to_quat(rpy[:, 0], rpy[:, 1], rpy[:, 2]))
        used["attitude"] = describe("ATTITUDE.roll/pitch/yaw", attitude)

    position, resolution = None, 0.0
    if rows.get("LOCAL_POSITION_NED"):
        t, xyz = _arrays(rows["LOCAL_POSITION_NED"], ("x", "y", "z"))
        position = make_series(path, "LOCAL_POSITION_NED", t, xyz)
        used["position"] = describe("LOCAL_POSITION_NED.x/y/z", position, "NED from the estimator's origin")
    if position is None and rows.get("GLOBAL_POSITION_INT"):
        t, g = _arrays(rows["GLOBAL_POSITION_INT"], ("lat", "lon", "alt"))
        ok = ~((g[:, 0] == 0) & (g[:, 1] == 0))
        if ok.any():
            lat, lon, alt = g[ok, 0] * GLOBAL_STEP_DEG, g[ok, 1] * GLOBAL_STEP_DEG, g[ok, 2] * GLOBAL_STEP_ALT_M
            position = make_series(path, "GLOBAL_POSITION_INT", t[ok], geodetic_to_ned(lat, lon, alt))
            resolution = quantisation_m(float(lat[0]), GLOBAL_STEP_DEG, GLOBAL_STEP_ALT_M)
            used["position"] = describe("GLOBAL_POSITION_INT.lat/lon/alt", position, "metres from the first fix")

    utc = None
    if rows.get("SYSTEM_TIME"):
        st = [(m.time_unix_usec, m.time_boot_ms) for _, m in rows["SYSTEM_TIME"] if m.time_unix_usec > 0]
        if st:
            utc = float(np.median([u * 1e-6 - b * 1e-3 for u, b in st]))
            used["utc"] = "SYSTEM_TIME.time_unix_usec"
    if utc is None:
        received = rows.get("ATTITUDE_QUATERNION") or rows["ATTITUDE"]
        utc = float(np.median([stamp - m.time_boot_ms * 1e-3 for stamp, m in received]))
        used["utc"] = "the tlog's reception times (they include the telemetry link's delay)"
    return FlightLog(path, "tlog", attitude, position, resolution, None, utc, used)


def _arrays(rows: list, fields: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    t = np.array([m.time_boot_ms * 1e-3 for _, m in rows], dtype=np.float64)
    v = np.array([[float(getattr(m, f)) for f in fields] for _, m in rows], dtype=np.float64)
    return t, v


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0][:200] if text else type(e).__name__


__all__ = ["GLOBAL_STEP_ALT_M", "GLOBAL_STEP_DEG", "MESSAGES", "read_tlog"]
