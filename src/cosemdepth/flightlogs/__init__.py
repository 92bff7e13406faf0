"""Flight logs as pose sources: PX4 ULog, ArduPilot DataFlash, MAVLink telemetry logs and DJI subtitles.

``read_log(path)`` recognises the format from the file's content and returns a :class:`FlightLog`: the vehicle's
attitude (body FRD -> world NED) and position (local NED metres) as time series on the log's clock, a gimbal's
rotation where recorded, which messages were used (``FlightLog.used``), and ``pose_at(t)`` to interpolate them.
Conventions and the camera mount: :mod:`cosemdepth.geometry.mount`, docs/own-flight.md.

The readers need the ``flight`` extra (``pip install 'cosemdepth[flight]'``: pyulog, pymavlink, pymap3d); a
missing package is a one-line error naming it. The writers (:mod:`.ulog_writer`, :mod:`.dataflash_writer`,
:mod:`.tlog_writer`, :mod:`.srt_writer`) make logs of known trajectories (SynthAir's ``--export``, the tests).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import ConfigError, DatasetError
from .detect import detect_format
from .log import LOG_FORMATS, FlightLog, Series


def read_log(path: str | Path, format: str | None = None, *, require_attitude: bool = True) -> FlightLog:
    """Read a flight log. ``format``: one of :data:`LOG_FORMATS`, or None to recognise it from the content (never
    from the file name); a given format must match the content. A missing, empty, truncated-before-its-data,
    corrupt or unknown file, or a log without attitude, is a one-line DatasetError naming the file and what is
    wrong (a log cut in its data section reads up to the cut, noted in ``used["damage"]`` where the library says so).
    ``require_attitude=False`` accepts a DJI subtitle file with positions only (``attitude`` None)."""
    path = Path(path)
    if format is not None and format not in LOG_FORMATS:
        raise ConfigError(f"--log-format must be one of {', '.join(LOG_FORMATS)}, got {format!r}")
    found = detect_format(path)
    if format is not None and found != format:
        raise DatasetError(f"{path}: not a {format} log (its content is that of a {found} log)")
    if found == "ulog":
        from .ulog import read_ulog

        return read_ulog(path)
    if found == "dataflash":
        from .dataflash import read_dataflash

        return read_dataflash(path)
    if found == "tlog":
        from .tlog import read_tlog

        return read_tlog(path)
    from .srt import read_srt

    return read_srt(path, require_attitude=require_attitude)


__all__ = ["LOG_FORMATS", "FlightLog", "Series", "detect_format", "read_log"]
