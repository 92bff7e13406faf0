"""What a flight log gives: time series of the vehicle's attitude and position (and a gimbal's), and their
interpolation at any time.

Frames: attitude is body FRD -> world NED (``v_ned = R(q) v_body``, quaternion w, x, y, z); positions are metres in a
local NED frame from the log's origin (the estimator's origin, or the first fix of a latitude/longitude source); a
gimbal's rotation is camera FRD -> body FRD (:mod:`cosemdepth.geometry.mount`). Times are seconds on the log's own
clock (time since boot for PX4 and ArduPilot, the video's clock for DJI subtitles).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DatasetError
from ..geometry.attitude import slerp

#: The formats :func:`cosemdepth.flightlogs.read_log` reads.
LOG_FORMATS = ("ulog", "dataflash", "tlog", "srt")
#: Default largest gap (seconds) interpolated across: this many times the series' median sample interval...
GAP_FACTOR = 5.0
#: ... and at least this many seconds.
MIN_GAP_S = 0.1
#: A quaternion whose norm differs from 1 by more than this is dropped as invalid (a log's "no estimate" value).
QUATERNION_TOLERANCE = 0.01
#: A clock stepping back by more than this (seconds) is a restart inside the log, refused; smaller steps back
#: (reordered samples) are dropped.
MAX_BACKSTEP_S = 1.0


@dataclass(frozen=True)
class Series:
    """One signal of a log: ``t [N]`` float64 seconds on the log's clock, strictly increasing; ``v [N, K]``
    float64 values (quaternions w, x, y, z or NED metres)."""

    t: np.ndarray
    v: np.ndarray

    def __len__(self) -> int:
        return len(self.t)

    @property
    def span(self) -> tuple[float, float]:
        """``(first, last)`` sample time."""
        return float(self.t[0]), float(self.t[-1])

    @property
    def median_interval(self) -> float:
        """Median time between samples (0.0 for a single sample)."""
        return float(np.median(np.diff(self.t))) if len(self.t) > 1 else 0.0

    def default_max_gap(self) -> float:
        """The largest gap interpolated across by default: ``max(MIN_GAP_S, GAP_FACTOR * median interval)``."""
        return max(MIN_GAP_S, GAP_FACTOR * self.median_interval)

    def interpolate(self, t: np.ndarray, max_gap: float | None = None, rotation: bool = False):
        """Values at times ``t [M]``: linear (``rotation``: slerp of quaternions) between the two samples around
        each time. Returns ``(v [M, K], ok [M] bool)``; ``ok`` is False (and the row NaN) outside ``span`` or where
        the two samples are more than ``max_gap`` seconds apart (default :meth:`default_max_gap`)."""
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        gap = self.default_max_gap() if max_gap is None else float(max_gap)
        n = len(self.t)
        out = np.full((len(t), self.v.shape[1]), np.nan)
        if n == 1:
            ok = t == self.t[0]
            out[ok] = self.v[0]
            return out, ok
        i0 = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, n - 2)
        t0, t1 = self.t[i0], self.t[i0 + 1]
        ok = np.isfinite(t) & (t >= self.t[0]) & (t <= self.t[-1]) & (t1 - t0 <= gap + 1e-9)
        a = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)[ok]
        v0, v1 = self.v[i0[ok]], self.v[i0[ok] + 1]
        out[ok] = slerp(v0, v1, a) if rotation else v0 + a[:, None] * (v1 - v0)
        return out, ok


@dataclass(frozen=True)
class FlightLog:
    """A flight log read by :func:`cosemdepth.flightlogs.read_log`.

    ``attitude`` ([N, 4] body FRD -> NED), ``position`` ([M, 3] local NED metres), ``gimbal`` ([G, 4] camera FRD ->
    body FRD) may each be None when the log has none; ``position_resolution_m`` is the positions' quantisation (0.0
    for an estimator's local positions, e.g. 0.011 m for 1e-7 degree integers, ~0.1-11 m for DJI's printed
    degrees); ``utc_offset_s``: UTC seconds = log time + this, where the log has an absolute clock (else None);
    ``used``: which messages and fields gave each series and how many samples, and any damage skipped.
    """

    path: Path
    format: str
    attitude: Series | None
    position: Series | None
    position_resolution_m: float
    gimbal: Series | None = None
    utc_offset_s: float | None = None
    used: dict = field(default_factory=dict)

    def covered(self) -> tuple[float, float] | None:
        """The time span covered by both attitude and position, or None if they do not overlap (or one is missing)."""
        if self.attitude is None or self.position is None:
            return None
        start = max(self.attitude.t[0], self.position.t[0])
        end = min(self.attitude.t[-1], self.position.t[-1])
        return (float(start), float(end)) if start <= end else None

    def pose_at(self, t: np.ndarray, max_gap: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The body's pose at log times ``t [N]`` (seconds): ``(q [N, 4] body FRD -> NED, slerped; p [N, 3] NED,
        linear; ok [N] bool)``. ``ok`` is True where ``t`` lies inside both series' spans and neither pair of
        samples around it is more than ``max_gap`` seconds apart (default: per series, ``GAP_FACTOR`` times its
        median interval, at least ``MIN_GAP_S``); rows that are not ok are NaN."""
        if self.attitude is None:
            raise DatasetError(f"{self.path}: the log has no attitude, so it gives no poses")
        if self.position is None:
            raise DatasetError(f"{self.path}: the log has no positions, so it gives no poses")
        q, ok_q = self.attitude.interpolate(t, max_gap, rotation=True)
        p, ok_p = self.position.interpolate(t, max_gap)
        ok = ok_q & ok_p
        q[~ok] = np.nan
        p[~ok] = np.nan
        return q, p, ok

    def gimbal_at(self, t: np.ndarray, max_gap: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The gimbal's rotation (camera FRD -> body FRD) at log times ``t [N]``: ``(q [N, 4], ok [N])``, as
        :meth:`pose_at`; a DatasetError when the log records no gimbal."""
        if self.gimbal is None:
            raise DatasetError(f"{self.path}: the log records no gimbal angles")
        return self.gimbal.interpolate(t, max_gap, rotation=True)


def make_series(path: Path, what: str, t, v) -> Series | None:
    """A :class:`Series` from raw samples: rows with a non-finite time or value dropped, then samples that do not
    come after every earlier one dropped (duplicates, reordering); None if nothing is left. A step back of the
    clock by more than ``MAX_BACKSTEP_S`` is a DatasetError naming ``what`` (a restart inside the log)."""
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    v = np.asarray(v, dtype=np.float64)
    v = v.reshape(len(t), -1) if v.size else v.reshape(len(t), v.shape[-1] if v.ndim > 1 else 1)
    keep = np.isfinite(t) & np.all(np.isfinite(v), axis=1)
    t, v = t[keep], v[keep]
    if len(t) == 0:
        return None
    before = np.maximum.accumulate(t)
    back = np.flatnonzero(t[1:] < before[:-1] - MAX_BACKSTEP_S)
    if back.size:
        i = back[0] + 1
        raise DatasetError(
            f"{path}: the clock of {what} goes back by {before[i - 1] - t[i]:.3f} s at {t[i]:.3f} s (the vehicle "
            "restarted inside the log?); cut the log there"
        )
    later = np.concatenate([[True], t[1:] > before[:-1]])
    return Series(t[later], v[later])


def quaternion_series(path: Path, what: str, t, q) -> Series | None:
    """:func:`make_series` for quaternions ``[N, 4]`` (w, x, y, z): rows whose norm is not 1 within
    ``QUATERNION_TOLERANCE`` are dropped (a log's "no estimate": zeros, NaN), the rest renormalised."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    with np.errstate(invalid="ignore", over="ignore"):
        norm = np.linalg.norm(q, axis=1)
        good = np.abs(norm - 1) <= QUATERNION_TOLERANCE
        q = np.where(good[:, None], q / np.where(good, norm, 1.0)[:, None], np.nan)
    return make_series(path, what, t, q)


def describe(source: str, series: Series | None, detail: str = "") -> str:
    """``"ATT.Roll/Pitch/Yaw (1234 samples, 50 Hz; detail)"``, for ``FlightLog.used``."""
    if series is None:
        return f"{source} (no valid samples{'; ' + detail if detail else ''})"
    dt = series.median_interval
    rate = f", {1 / dt:.4g} Hz" if dt > 0 else ""
    return f"{source} ({len(series)} samples{rate}{'; ' + detail if detail else ''})"


__all__ = [
    "FlightLog",
    "GAP_FACTOR",
    "LOG_FORMATS",
    "MAX_BACKSTEP_S",
    "MIN_GAP_S",
    "QUATERNION_TOLERANCE",
    "Series",
    "describe",
    "make_series",
    "quaternion_series",
]
