"""Which flight log a file is, from its first bytes (never from its name)."""

from __future__ import annotations

import re
import struct
from pathlib import Path

from ..errors import DatasetError

#: The first bytes of a PX4 ULog file ("ULog" and the format's magic).
ULOG_MAGIC = b"ULog\x01\x12\x35"
#: An ArduPilot DataFlash message header (0xA3 0x95) followed by the id of the FMT message (128).
DATAFLASH_MAGIC = b"\xa3\x95\x80"
#: MAVLink 1 and 2 packet start bytes.
MAVLINK_MAGICS = (0xFE, 0xFD)
#: A tlog's 8-byte big-endian Unix time in microseconds must be a date in this range (2000-01-01 to 2100-01-01).
TLOG_TIME_RANGE_US = (946_684_800_000_000, 4_102_444_800_000_000)

_SRT_TIMING = re.compile(r"^\s*\d+\s*\r?\n\s*\d{1,2}:\d{2}:\d{2}[,.]\d{1,3}\s*-->\s*\d{1,2}:\d{2}:\d{2}[,.]\d{1,3}")


def detect_format(path: Path) -> str:
    """``"ulog"``, ``"dataflash"``, ``"tlog"`` or ``"srt"`` from the content of ``path``; a one-line DatasetError
    naming the file and what its first bytes look like otherwise."""
    try:
        with open(path, "rb") as f:
            head = f.read(512)
    except FileNotFoundError:
        raise DatasetError(f"{path}: flight log not found") from None
    except OSError as e:
        raise DatasetError(f"{path}: cannot read the flight log ({e.strerror or e})") from None
    if not head:
        raise DatasetError(f"{path}: the flight log is empty")
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if head.startswith(DATAFLASH_MAGIC):
        return "dataflash"
    if len(head) >= 9 and head[8] in MAVLINK_MAGICS:
        (stamp,) = struct.unpack(">Q", head[:8])
        if TLOG_TIME_RANGE_US[0] <= stamp < TLOG_TIME_RANGE_US[1]:
            return "tlog"
    text = head.decode("utf-8-sig", errors="replace")
    if _SRT_TIMING.match(text):
        return "srt"
    hint = ""
    if head.startswith(b"FMT,") or head.startswith(b"FMT, "):
        hint = " (an ArduPilot text log: convert it with mavlogdump or use the .bin)"
    elif head[:1] in (b"\xfe", b"\xfd"):
        hint = " (MAVLink packets without a tlog's timestamps)"
    raise DatasetError(
        f"{path}: not a flight log this reader knows (PX4 ULog, ArduPilot DataFlash .bin, MAVLink .tlog, DJI .SRT)"
        f"{hint}; it starts with {head[:8].hex(' ')}"
    )


__all__ = ["DATAFLASH_MAGIC", "MAVLINK_MAGICS", "TLOG_TIME_RANGE_US", "ULOG_MAGIC", "detect_format"]
