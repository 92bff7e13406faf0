"""Latitude, longitude and altitude to metres: a local NED frame at a log's first fix (``pymap3d``)."""

from __future__ import annotations

import math

import numpy as np

from ..optional import require

#: Metres per degree of latitude (WGS84 mean); a degree of longitude is this times cos(latitude).
METRES_PER_DEGREE = 111_320.0


def geodetic_to_ned(lat_deg, lon_deg, alt_m, origin: tuple[float, float, float] | None = None) -> np.ndarray:
    """``[N]`` latitudes, longitudes (degrees) and altitudes (metres; any datum, constant offsets cancel) ->
    ``[N, 3]`` NED metres in the local tangent frame at ``origin`` (lat, lon, alt; default: the first sample)."""
    pymap3d = require("pymap3d", "reading latitude/longitude positions")
    lat = np.asarray(lat_deg, dtype=np.float64)
    lon = np.asarray(lon_deg, dtype=np.float64)
    alt = np.asarray(alt_m, dtype=np.float64)
    if origin is None:
        origin = (float(lat[0]), float(lon[0]), float(alt[0]))
    n, e, d = pymap3d.geodetic2ned(lat, lon, alt, *origin)
    return np.stack([np.asarray(n), np.asarray(e), np.asarray(d)], axis=-1).reshape(-1, 3)


def ned_to_geodetic(ned: np.ndarray, origin: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``[N, 3]`` NED metres in the tangent frame at ``origin`` (lat, lon degrees, alt metres) -> ``(lat, lon, alt)``
    ``[N]`` each (WGS84)."""
    pymap3d = require("pymap3d", "writing latitude/longitude positions")
    ned = np.asarray(ned, dtype=np.float64).reshape(-1, 3)
    lat, lon, alt = pymap3d.ned2geodetic(ned[:, 0], ned[:, 1], ned[:, 2], *origin)
    return np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64), np.asarray(alt, dtype=np.float64)


def quantisation_m(lat_deg: float, step_deg: float, step_alt_m: float) -> float:
    """The position quantisation in metres of latitudes/longitudes written to ``step_deg`` degrees and altitudes to
    ``step_alt_m`` metres at latitude ``lat_deg``: the largest of the three axes' steps."""
    north = step_deg * METRES_PER_DEGREE
    east = north * math.cos(math.radians(lat_deg))
    return float(max(north, east, step_alt_m))


__all__ = ["METRES_PER_DEGREE", "geodetic_to_ned", "ned_to_geodetic", "quantisation_m"]
