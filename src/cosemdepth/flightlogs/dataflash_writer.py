"""ArduPilot DataFlash (``.bin``) logs packed with ``pymavlink``'s own DataFlash structures (``DFFormat``,
``DFMessage.get_msgbuf``): pymavlink has no log writer, but it packs a message of a known format, applying the
format's multipliers (``c`` centidegrees, ``L`` 1e-7 degrees...).

A log is the FMT message of FMT itself, one FMT per message type, then the records in time order. :data:`FORMATS`
holds ArduPilot 4.x's layouts of the messages SynthAir writes.
"""

from __future__ import annotations

import struct
from pathlib import Path

from ..optional import require
from ..output_safety.atomic import atomic_open

#: Message name -> (type id, format characters, column names): ArduPilot 4.x's ATT, POS, XKF1 and GPS.
FORMATS: dict[str, tuple[int, str, str]] = {
    "ATT": (35, "QccccCCCCB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw,AEKF"),
    "POS": (36, "QLLfff", "TimeUS,Lat,Lng,Alt,RelHomeAlt,RelOriginAlt"),
    "XKF1": (37, "QBccCfffffffccce", "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH"),
    "GPS": (38, "QBBIHBcLLeffffB", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U"),
}
#: The FMT message's own format (type 128).
FMT_FORMAT = (0x80, "BBnNZ", "Type,Length,Name,Format,Columns")


class DataflashWriter:
    """Collects records and packs them: ``add(name, time_us, **fields)`` (physical units: degrees, metres; missing
    fields are 0), then :meth:`to_bytes` or :meth:`write`."""

    def __init__(self, formats: dict[str, tuple[int, str, str]] | None = None) -> None:
        dfreader = require("pymavlink.DFReader", "writing an ArduPilot DataFlash log")
        self._df = dfreader
        self.formats = dict(FORMATS if formats is None else formats)
        fmt_type, fmt_chars, fmt_cols = FMT_FORMAT
        self._fmt_fmt = dfreader.DFFormat(fmt_type, "FMT", 3 + struct.calcsize("<" + "BB4s16s64s"), fmt_chars, fmt_cols)
        self._df_formats = {}
        for name, (type_id, chars, cols) in self.formats.items():
            probe = dfreader.DFFormat(type_id, name, 0, chars, cols)
            self._df_formats[name] = dfreader.DFFormat(
                type_id, name, 3 + struct.calcsize(probe.msg_struct), chars, cols
            )
        self._records: list[tuple[int, int, bytes]] = []

    def _pack(self, fmt, values: dict) -> bytes:
        msg = self._df.DFMessage(fmt, [0] * len(fmt.columns), True, None)
        for col in fmt.columns:
            if col in values:
                setattr(msg, col, values[col])
        buf = msg.get_msgbuf()
        if buf is None:
            raise ValueError(f"DataFlash {fmt.name}: a value does not fit its field: {values}")
        return buf

    def add(self, name: str, time_us: int, **fields) -> None:
        """Queue a ``name`` record at ``time_us`` (``TimeUS``) with ``fields`` in physical units."""
        fields["TimeUS"] = int(time_us)
        self._records.append((int(time_us), len(self._records), self._pack(self._df_formats[name], fields)))

    def to_bytes(self) -> bytes:
        """The log: FMT records, then every record in time order (ties in the order added)."""
        out = bytearray()
        fmt_fmt = self._fmt_fmt
        for fmt in [fmt_fmt, *self._df_formats.values()]:
            out += self._pack(
                fmt_fmt,
                {
                    "Type": fmt.type,
                    "Length": fmt.len,
                    "Name": fmt.name,
                    "Format": fmt.format,
                    "Columns": ",".join(fmt.columns),
                },
            )
        for _, _, buf in sorted(self._records, key=lambda r: (r[0], r[1])):
            out += buf
        return bytes(out)

    def write(self, path: str | Path) -> None:
        """Write :meth:`to_bytes` to ``path`` atomically."""
        with atomic_open(path, "wb") as f:
            f.write(self.to_bytes())


__all__ = ["DataflashWriter", "FMT_FORMAT", "FORMATS"]
