"""ArduPilot DataFlash (``.bin``) logs through ``pymavlink``'s ``DFReader``.

Attitude: ``ATT`` (Roll, Pitch, Yaw in degrees: Z-Y-X angles of the FRD body in NED), else the EKF's ``XKF1`` (EKF3)
or ``NKF1`` (EKF2) angles. Position: ``XKF1`` / ``NKF1`` ``PN, PE, PD`` (metres NED from the EKF origin), else
``POS`` (``Lat, Lng`` degrees, ``Alt`` metres) converted to metres from the first fix. For the EKF messages, core
(``C``) 0 only. Times: ``TimeUS`` (microseconds since boot; ``TimeMS`` in old logs). UTC from ``GPS`` (``GWk``,
``GMS``: GPS time, minus the leap seconds).
"""

from __future__ import annotations

import contextlib
import io
import math
from pathlib import Path

import numpy as np

from ..errors import DatasetError
from ..geometry.attitude import euler_to_quat
from ..optional import require
from .geodetic import geodetic_to_ned, quantisation_m
from .log import FlightLog, describe, make_series, quaternion_series

#: The message types read.
MESSAGES = ("ATT", "XKF1", "NKF1", "POS", "GPS")
#: GPS time (1980-01-06) in Unix seconds, and GPS - UTC in seconds (since 2017-01-01).
GPS_EPOCH_UNIX = 315_964_800
GPS_LEAP_SECONDS = 18
#: ``POS`` stores latitude/longitude as 1e-7 degree integers.
POS_STEP_DEG = 1e-7


def read_dataflash(path: Path) -> FlightLog:
    """Read an ArduPilot DataFlash binary log (see the module docstring)."""
    DFReader = require("pymavlink.DFReader", f"reading the ArduPilot log {path}")

    rows: dict[str, list] = {m: [] for m in MESSAGES}
    noise = io.StringIO()
    try:
        with contextlib.redirect_stdout(noise), contextlib.redirect_stderr(noise):
            log = DFReader.DFReader_binary(str(path), zero_time_base=False)
            while True:
                m = log.recv_match(type=list(MESSAGES))
                if m is None:
                    break
                rows[m.get_type()].append(m.to_dict())
    except Exception as e:  # DFReader raises whatever its parser meets on a damaged file
        raise DatasetError(f"{path}: not a readable ArduPilot DataFlash log ({_first_line(e)})") from None
    used: dict = {"clock": "microseconds since boot (TimeUS)"}
    damage = sum("bad header" in ln or "unknown msg type" in ln for ln in noise.getvalue().splitlines())
    if damage:
        used["damage"] = f"{damage} damaged spots skipped by the reader"

    attitude = None
    if rows["ATT"]:
        t, r, p, y = _columns(path, rows["ATT"], "ATT", ("Roll", "Pitch", "Yaw"))
        attitude = quaternion_series(path, "ATT", t, euler_to_quat(*np.radians([r, p, y])))
        used["attitude"] = describe("ATT.Roll/Pitch/Yaw", attitude)
    ekf_name = "XKF1" if rows["XKF1"] else "NKF1" if rows["NKF1"] else None
    ekf = _core0(rows[ekf_name]) if ekf_name else []
    if attitude is None and ekf:
        t, r, p, y = _columns(path, ekf, ekf_name, ("Roll", "Pitch", "Yaw"))
        attitude = quaternion_series(path, ekf_name, t, euler_to_quat(*np.radians([r, p, y])))
        used["attitude"] = describe(f"{ekf_name}.Roll/Pitch/Yaw", attitude, "core 0")
    if attitude is None:
        found = ", ".join(m for m in MESSAGES if rows[m]) or "none of them"
        raise DatasetError(f"{path}: the ArduPilot log has no attitude (ATT, XKF1 or NKF1); messages found: {found}")

    position, resolution = None, 0.0
    if ekf:
        t, n, e, d = _columns(path, ekf, ekf_name, ("PN", "PE", "PD"))
        position = make_series(path, ekf_name, t, np.stack([n, e, d], 1))
        used["position"] = describe(f"{ekf_name}.PN/PE/PD", position, "core 0, NED from the EKF origin")
    if position is None and rows["POS"]:
        t, lat, lon, alt = _columns(path, rows["POS"], "POS", ("Lat", "Lng", "Alt"))
        ok = ~((lat == 0) & (lon == 0))
        if ok.any():
            position = make_series(path, "POS", t[ok], geodetic_to_ned(lat[ok], lon[ok], alt[ok]))
            resolution = quantisation_m(float(lat[ok][0]), POS_STEP_DEG, 0.0)
            used["position"] = describe("POS.Lat/Lng/Alt", position, "metres from the first fix")
    utc = _utc_offset(rows["GPS"])
    if utc is not None:
        used["utc"] = "GPS.GWk/GMS"
    return FlightLog(path, "dataflash", attitude, position, resolution, None, utc, used)


def _time(path: Path, row: dict, name: str) -> float:
    if "TimeUS" in row:
        return _number(row["TimeUS"]) * 1e-6
    if "TimeMS" in row:
        return _number(row["TimeMS"]) * 1e-3
    raise DatasetError(f"{path}: ArduPilot message {name} has no TimeUS or TimeMS field")


def _columns(path: Path, rows: list[dict], name: str, fields: tuple[str, ...]) -> list[np.ndarray]:
    missing = [f for f in fields if f not in rows[0]]
    if missing:
        raise DatasetError(f"{path}: ArduPilot message {name} has no field(s) {missing}")
    t = np.array([_time(path, r, name) for r in rows])
    return [t] + [np.array([_number(r.get(f)) for r in rows]) for f in fields]


def _number(value) -> float:
    """A field's value as a float; NaN (the sample is then dropped) for a value of another type (a damaged FMT)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _core0(rows: list[dict]) -> list[dict]:
    return [r for r in rows if _number(r.get("C", 0)) == 0]


def _utc_offset(rows: list[dict]) -> float | None:
    offsets = []
    for r in rows:
        status, week, ms, us = (_number(r.get(k)) for k in ("Status", "GWk", "GMS", "TimeUS"))
        if status >= 3 and week > 0:
            utc = GPS_EPOCH_UNIX + week * 604800 + ms * 1e-3 - GPS_LEAP_SECONDS
            offsets.append(utc - us * 1e-6)
    offsets = [o for o in offsets if math.isfinite(o)]
    return float(np.median(offsets)) if offsets else None


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0][:200] if text else type(e).__name__


__all__ = ["GPS_EPOCH_UNIX", "GPS_LEAP_SECONDS", "MESSAGES", "POS_STEP_DEG", "read_dataflash"]
