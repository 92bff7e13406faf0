"""DJI ``.SRT`` subtitle files (written beside the video; the layout differs between models).

Each subtitle is ``index``, ``start --> end`` and a few lines of text. Its start time, in seconds from the video's
start, is the sample's time: the SRT's clock is the video's (a time offset of 0 by construction). Layouts read:

* Mavic 3 / Mini / Air 3 (``FrameCnt``): ``[latitude: 46.518932] [longitude: 6.566751] [rel_alt: 12.300
  abs_alt: 512.345]``, one subtitle per frame; Mavic 3T adds ``[gb_yaw: 105.2 gb_pitch: -90.0 gb_roll: 0.0]``;
* Mavic 2 (``[longtitude : ...]``), Air 2S (``SrtCnt``, ``[altitude: ...]``);
* Mavic Pro / Phantom 4 (once per second): ``GPS(longitude,latitude,satellites) BAROMETER:height``;
* Matrice 300: ``GPS(latitude,longitude,altitude M) BAROMETER:height M``;
* Phantom 4 RTK, Mini: ``GPS (longitude, latitude, n)`` or ``RTK (...)``, ``H 76.19m``, ``F.PRY (pitch, roll,
  yaw)`` the aircraft's and ``G.PRY (pitch, roll, yaw)`` the gimbal's attitude (degrees).

Positions: latitude/longitude and the altitude (``abs_alt``, else ``rel_alt``, ``altitude``, ``H``, an ``M``
altitude in ``GPS(...)``, ``BAROMETER``) to metres from the first fix; ``position_resolution_m`` from the digits
printed (6 decimals of a degree: 0.11 m; 4: 11 m). A position of 0, 0 (no fix) is dropped. Attitude: the aircraft's
``F.PRY``. DJI's gimbal angles (``G.PRY``, ``gb_*``) are the camera's own attitude in the world (yaw from north,
pitch negative below the horizon, Z-Y-X): with ``F.PRY`` they become the gimbal's rotation relative to the body;
without it, the camera's attitude is taken as the "body" and the gimbal is the identity (either way the camera
pose is exact, whatever ``--camera-mount`` says). Without any angles the file has no attitude.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import numpy as np

from ..errors import DatasetError
from ..geometry.attitude import euler_to_quat, quat_conjugate, quat_multiply
from .geodetic import geodetic_to_ned, quantisation_m
from .log import FlightLog, describe, make_series, quaternion_series

_NUM = r"[+-]?\d+(?:\.\d*)?"
_TIMING = re.compile(r"(\d{1,2}):(\d{2}):(\d{2})[,.](\d{1,3})\s*-->\s*(\d{1,2}):(\d{2}):(\d{2})[,.](\d{1,3})")
_TAG = re.compile(r"<[^<>]*>")
_FIELDS = {
    "lat": re.compile(rf"\[\s*latitude\s*:\s*({_NUM})\s*\]", re.I),
    "lon": re.compile(rf"\[\s*longt?itude\s*:\s*({_NUM})\s*\]", re.I),
    "abs_alt": re.compile(rf"abs_alt\s*:\s*({_NUM})\s*\]", re.I),
    "rel_alt": re.compile(rf"rel_alt\s*:\s*({_NUM})\s+abs_alt", re.I),
    "altitude": re.compile(rf"\[\s*altitude\s*:\s*({_NUM})\s*\]", re.I),
    "H": re.compile(rf"(?:^|[\s,])H\s+({_NUM})\s*m\b"),
    "BAROMETER": re.compile(rf"BAROMETER\s*:?\s*\(?\s*({_NUM})\s*M?\s*\)?(?=\s|$)", re.I),
}
_GPS = re.compile(rf"\b(?:GPS|RTK)\s*\(\s*({_NUM})\s*,\s*({_NUM})\s*,\s*({_NUM})\s*(M?)\s*\)", re.I)
_PRY = {k: re.compile(rf"\b{k}\.PRY\s*\(\s*({_NUM})°?\s*,\s*({_NUM})°?\s*,\s*({_NUM})°?\s*\)") for k in "FG"}
_GB = re.compile(rf"gb_yaw\s*:\s*({_NUM})\s+gb_pitch\s*:\s*({_NUM})\s+gb_roll\s*:\s*({_NUM})", re.I)
_DATE = re.compile(r"\d{4}[-.]\d{2}[-.]\d{2}\s+\d{2}:\d{2}:\d{2}(?:[.,]\d{1,6}(?:,\d{1,3})?)?")
#: Altitude sources, most trusted first.
ALTITUDES = ("abs_alt", "rel_alt", "altitude", "H", "gps_M", "BAROMETER")


def _decimals(text: str) -> int:
    return len(text.split(".")[1]) if "." in text else 0


def _subtitles(path: Path, text: str) -> list[tuple[float, str]]:
    """``(start seconds, text without tags)`` of every subtitle, in file order."""
    lines = text.splitlines()
    heads = [i for i, ln in enumerate(lines) if _TIMING.search(ln)]
    out = []
    for k, i in enumerate(heads):
        m = _TIMING.search(lines[i])
        h, mi, s = (int(g) for g in m.groups()[:3])
        ms = m.group(4)
        end = heads[k + 1] - 1 if k + 1 < len(heads) else len(lines)  # the next subtitle's index line excluded
        body = " ".join(_TAG.sub(" ", ln) for ln in lines[i + 1 : end])
        out.append((h * 3600 + mi * 60 + s + int(ms.ljust(3, "0")) / 1000, body))
    return out


def read_srt(path: Path, require_attitude: bool = True) -> FlightLog:
    """Read a DJI subtitle file (see the module docstring)."""
    try:
        text = path.read_bytes().decode("utf-8-sig", errors="replace")
    except OSError as e:
        raise DatasetError(f"{path}: cannot read the subtitle file ({e.strerror or e})") from None
    subs = _subtitles(path, text)
    if not subs:
        raise DatasetError(f"{path}: no subtitle with a 'HH:MM:SS,mmm --> HH:MM:SS,mmm' line")
    times = np.array([t for t, _ in subs])
    samples = []
    for _, body in subs:
        f = {k: rx.search(body) for k, rx in _FIELDS.items()}
        row = {k: m.group(1) for k, m in f.items() if m}
        gps = _GPS.search(body)
        if gps:
            row["gps"] = gps.groups()
        for k, rx in _PRY.items():
            m = rx.search(body)
            if m:
                row[f"{k}.PRY"] = tuple(float(v) for v in m.groups())
        m = _GB.search(body)
        if m:
            row["gb"] = tuple(float(v) for v in m.groups())
        m = _DATE.search(body)
        if m:
            row["date"] = m.group(0)
        samples.append(row)
    used: dict = {"clock": "the video's clock (subtitle start times)", "subtitles": len(subs)}
    dates = [s["date"] for s in samples if "date" in s]
    if dates:
        used["clock"] += f"; wall clock of the first subtitle {dates[0]} (the drone's local time)"

    position, resolution = _positions(path, times, samples, used)
    attitude, gimbal = _attitudes(path, times, samples, used)
    if attitude is None and require_attitude:
        raise DatasetError(
            f"{path}: this DJI subtitle file has no attitude (no F.PRY, G.PRY or gb_yaw/gb_pitch/gb_roll angles; "
            "this model writes positions only), so it gives no camera poses"
        )
    return FlightLog(path, "srt", attitude, position, resolution, gimbal, None, used)


def _positions(path: Path, times: np.ndarray, samples: list[dict], used: dict):
    lat_s, lon_s, alt_s, keep = [], [], [], []
    keyed = sum("lat" in s and "lon" in s for s in samples)
    tupled = sum("gps" in s for s in samples)
    if not keyed and not tupled:
        return None, 0.0
    present = Counter(k for s in samples for k in ALTITUDES if _alt(s, k) is not None)
    best_alt = next((k for k in ALTITUDES if present[k]), None)
    if keyed >= tupled:
        source = "[latitude] [longitude]"
        for i, s in enumerate(samples):
            if "lat" in s and "lon" in s:
                lat_s.append(s["lat"])
                lon_s.append(s["lon"])
                alt_s.append(_alt(s, best_alt))
                keep.append(i)
    else:
        rows = [(i, s["gps"]) for i, s in enumerate(samples) if "gps" in s]
        lat_first = any(g[3] for _, g in rows)  # Matrice 300: GPS(lat, lon, alt M); others GPS(lon, lat, n)
        a = np.array([float(g[0]) for _, g in rows])
        b = np.array([float(g[1]) for _, g in rows])
        if lat_first and np.any(np.abs(a) > 90):
            lat_first = False
        elif not lat_first and np.any(np.abs(b) > 90):
            lat_first = True
        source = "GPS(latitude, longitude, ...)" if lat_first else "GPS(longitude, latitude, ...)"
        for i, g in rows:
            lat_s.append(g[0] if lat_first else g[1])
            lon_s.append(g[1] if lat_first else g[0])
            alt_s.append(_alt(samples[i], best_alt))
            keep.append(i)
    lat = np.array([float(v) for v in lat_s])
    lon = np.array([float(v) for v in lon_s])
    alt = np.array([np.nan if v is None else float(v) for v in alt_s])
    if np.any(np.abs(lat) > 90) or np.any(np.abs(lon) > 180):
        raise DatasetError(f"{path}: latitude/longitude out of range in the subtitles ({source})")
    ok = ~((lat == 0) & (lon == 0))
    if best_alt is None:
        alt = np.zeros_like(lat)
        used["altitude"] = "none in the file: positions are horizontal only (down = 0)"
    ok &= np.isfinite(alt)
    if not ok.any():
        used["position"] = f"{source}: no fix in any subtitle"
        return None, 0.0
    keep = np.array(keep)[ok]
    ned = geodetic_to_ned(lat[ok], lon[ok], alt[ok])
    position = make_series(path, "subtitle positions", times[keep], ned)
    deg_step = 10.0 ** -max(_decimals(v) for v, o in zip(lat_s + lon_s, np.concatenate([ok, ok])) if o)
    alt_texts = [v for v, o in zip(alt_s, ok) if o and v is not None]
    alt_step = 10.0 ** -max(_decimals(v) for v in alt_texts) if alt_texts else 0.0
    resolution = quantisation_m(float(lat[ok][0]), deg_step, alt_step)
    alt_note = f", altitude from {best_alt}" if best_alt else ""
    used["position"] = describe(
        source, position, f"metres from the first fix{alt_note}; printed to {deg_step:g} degrees = {resolution:.3g} m"
    )
    return position, resolution


def _alt(sample: dict, key: str | None) -> str | None:
    if key is None:
        return None
    if key == "gps_M":
        return sample["gps"][2] if "gps" in sample and sample["gps"][3] else None
    return sample.get(key)


def _attitudes(path: Path, times: np.ndarray, samples: list[dict], used: dict):
    def series(key: str, order: tuple[int, int, int], what: str):
        rows = [(t, s[key]) for t, s in zip(times, samples) if key in s]
        if not rows:
            return None
        t = np.array([r[0] for r in rows])
        ang = np.radians(np.array([[r[1][i] for i in order] for r in rows]))  # roll, pitch, yaw
        return quaternion_series(path, what, t, euler_to_quat(ang[:, 0], ang[:, 1], ang[:, 2]))

    aircraft = series("F.PRY", (1, 0, 2), "F.PRY")  # (pitch, roll, yaw)
    camera = series("G.PRY", (1, 0, 2), "G.PRY")
    camera_src = "G.PRY"
    if camera is None:
        camera = series("gb", (2, 1, 0), "gb_yaw/gb_pitch/gb_roll")  # (yaw, pitch, roll)
        camera_src = "gb_yaw/gb_pitch/gb_roll"
    if aircraft is not None:
        used["attitude"] = describe("F.PRY", aircraft, "the aircraft's pitch, roll, yaw")
        gimbal = None
        if camera is not None:
            q_air, ok = aircraft.interpolate(camera.t, rotation=True)
            rel = quat_multiply(quat_conjugate(q_air[ok]), camera.v[ok])
            gimbal = quaternion_series(path, camera_src, camera.t[ok], rel)
            used["gimbal"] = describe(camera_src, gimbal, "the camera's attitude relative to the aircraft's")
        return aircraft, gimbal
    if camera is not None:
        used["attitude"] = describe(
            camera_src, camera, "the camera's own attitude (no aircraft attitude in this file): the body is the camera"
        )
        gimbal = make_series(path, camera_src, camera.t, np.tile([1.0, 0.0, 0.0, 0.0], (len(camera.t), 1)))
        used["gimbal"] = "identity: the attitude is the camera's (replaces --camera-mount's rotation)"
        return camera, gimbal
    return None, None


__all__ = ["ALTITUDES", "read_srt"]
