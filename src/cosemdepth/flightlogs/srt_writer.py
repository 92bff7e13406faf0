"""DJI ``.SRT`` subtitles in the Mavic 3 layout (one subtitle per video frame), with the Mavic 3T's gimbal angles::

    1
    00:00:00,000 --> 00:00:00,040
    <font size="28">FrameCnt: 1, DiffTime: 40ms
    2026-12-07 10:00:02.000
    [iso: 100] [shutter: 1/1000.0] [fnum: 2.8] [ev: 0] [color_md: default] [focal_len: 24.00] [latitude: 46.518932]
    [longitude: 6.566751] [rel_alt: 12.300 abs_alt: 512.345] [gb_yaw: 105.2 gb_pitch: -30.0 gb_roll: 0.0] [ct: 5500] </font>

(the bracket groups on one line). Latitude and longitude with 6 decimals, altitudes with 3, angles with 1, times in
milliseconds, as DJI prints them.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np

from ..output_safety.atomic import atomic_write_text


def _clock(seconds: float) -> str:
    ms = int(round(seconds * 1000))
    h, rest = divmod(ms, 3_600_000)
    m, rest = divmod(rest, 60_000)
    s, ms = divmod(rest, 1000)
    return f"{h:02d}:{m:02d}:{s:02d},{ms:03d}"


def srt_text(
    times_s: np.ndarray,
    lat_deg: np.ndarray,
    lon_deg: np.ndarray,
    rel_alt_m: np.ndarray,
    abs_alt_m: np.ndarray,
    gimbal_ypr_deg: np.ndarray | None = None,
    start: dt.datetime | None = None,
) -> str:
    """The subtitles of frames at video times ``times_s [N]`` (seconds, increasing); each subtitle lasts until the
    next frame (the last one a median frame interval). ``gimbal_ypr_deg [N, 3]``: yaw, pitch, roll of the camera in
    the world (DJI's gimbal angles), or None for a model without them; ``start``: the wall clock of time 0."""
    t = np.asarray(times_s, dtype=np.float64)
    step = float(np.median(np.diff(t))) if len(t) > 1 else 1 / 30
    ends = np.append(t[1:], t[-1] + step)
    start = start or dt.datetime(2026, 12, 7, 10, 0, 0)
    out = []
    for k in range(len(t)):
        diff = int(round((t[k] - t[k - 1]) * 1000)) if k else int(round(step * 1000))
        wall = (start + dt.timedelta(seconds=float(t[k]))).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]
        gimbal = ""
        if gimbal_ypr_deg is not None:
            y, p, r = gimbal_ypr_deg[k]
            gimbal = f" [gb_yaw: {y:.1f} gb_pitch: {p:.1f} gb_roll: {r:.1f}]"
        out.append(
            f"{k + 1}\n{_clock(t[k])} --> {_clock(ends[k])}\n"
            f'<font size="28">FrameCnt: {k + 1}, DiffTime: {diff}ms\n{wall}\n'
            "[iso: 100] [shutter: 1/1000.0] [fnum: 2.8] [ev: 0] [color_md: default] [focal_len: 24.00] "
            f"[latitude: {lat_deg[k]:.6f}] [longitude: {lon_deg[k]:.6f}] "
            f"[rel_alt: {rel_alt_m[k]:.3f} abs_alt: {abs_alt_m[k]:.3f}]{gimbal} [ct: 5500] </font>\n"
        )
    return "\n".join(out)


def write_srt(path: str | Path, *args, **kwargs) -> None:
    """Write :func:`srt_text` to ``path`` atomically."""
    atomic_write_text(path, srt_text(*args, **kwargs))


__all__ = ["srt_text", "write_srt"]
