"""A small PX4 ULog writer, following the "ULog File Format" specification of the PX4 documentation (``pyulog`` can
only re-write a log it has loaded).

File: a 16-byte header (``ULog`` magic, version 1, the logging start in microseconds), the definitions (a flag-bits
message ``B``, info ``I``, parameters ``P``, formats ``F``, subscriptions ``A``), then the data section: one ``D``
message per sample, all topics merged in time order, with a sync message ``S`` every :data:`SYNC_EVERY` messages.
Every message is ``uint16 size, uint8 type`` and a little-endian payload; a topic's samples are packed structs of its
format's fields in order (``uint64_t timestamp`` first); formats end with a padding field making them a multiple of
8 bytes, as PX4's do, and the data messages leave that trailing padding out, as the specification says.

:data:`PX4_FORMATS` holds the fields of the topics SynthAir writes (PX4 1.14 names and types, a subset of each).
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..output_safety.atomic import atomic_open
from .detect import ULOG_MAGIC

#: ULog scalar types -> numpy dtypes (little-endian).
ULOG_TYPES = {
    "int8_t": "i1",
    "uint8_t": "u1",
    "int16_t": "<i2",
    "uint16_t": "<u2",
    "int32_t": "<i4",
    "uint32_t": "<u4",
    "int64_t": "<i8",
    "uint64_t": "<u8",
    "float": "<f4",
    "double": "<f8",
    "bool": "u1",
    "char": "S1",
}
#: The sync message's payload (PX4 spec), written every SYNC_EVERY data messages so that a reader can resynchronise
#: after damage.
SYNC_MAGIC = bytes([0x2F, 0x73, 0x13, 0x20, 0x25, 0x0C, 0xBB, 0x12])
SYNC_EVERY = 500

#: Fields (type, name) of the PX4 topics SynthAir writes, in PX4's order (largest types first); padding is added.
PX4_FORMATS: dict[str, list[tuple[str, str]]] = {
    "vehicle_attitude": [
        ("uint64_t", "timestamp"),
        ("uint64_t", "timestamp_sample"),
        ("float[4]", "q"),
        ("float[4]", "delta_q_reset"),
        ("uint8_t", "quat_reset_counter"),
    ],
    "vehicle_local_position": [
        ("uint64_t", "timestamp"),
        ("uint64_t", "timestamp_sample"),
        ("uint64_t", "ref_timestamp"),
        ("double", "ref_lat"),
        ("double", "ref_lon"),
        ("float", "x"),
        ("float", "y"),
        ("float", "z"),
        ("float", "vx"),
        ("float", "vy"),
        ("float", "vz"),
        ("float", "heading"),
        ("float", "ref_alt"),
        ("float", "eph"),
        ("float", "epv"),
        ("bool", "xy_valid"),
        ("bool", "z_valid"),
        ("bool", "v_xy_valid"),
        ("bool", "v_z_valid"),
        ("bool", "xy_global"),
        ("bool", "z_global"),
    ],
    "vehicle_odometry": [
        ("uint64_t", "timestamp"),
        ("uint64_t", "timestamp_sample"),
        ("float[3]", "position"),
        ("float[4]", "q"),
        ("float[3]", "velocity"),
        ("float[3]", "angular_velocity"),
        ("float[3]", "position_variance"),
        ("float[3]", "orientation_variance"),
        ("float[3]", "velocity_variance"),
        ("uint8_t", "pose_frame"),
        ("uint8_t", "velocity_frame"),
        ("uint8_t", "reset_counter"),
        ("int8_t", "quality"),
    ],
    "sensor_gps": [
        ("uint64_t", "timestamp"),
        ("uint64_t", "timestamp_sample"),
        ("uint64_t", "time_utc_usec"),
        ("int32_t", "lat"),
        ("int32_t", "lon"),
        ("int32_t", "alt"),
        ("float", "eph"),
        ("float", "epv"),
        ("uint8_t", "fix_type"),
        ("uint8_t", "satellites_used"),
    ],
}

_ARRAY = re.compile(r"^(\w+)\[(\d+)\]$")


@dataclass
class Topic:
    """One topic to log: ``fields`` [(type, name)] (a type may be an array ``float[4]``; ``uint64_t timestamp``
    first), ``data`` {name: [N] or [N, k] values} (missing fields are zero), subscription ``multi_id``."""

    name: str
    fields: list[tuple[str, str]]
    data: dict[str, np.ndarray]
    multi_id: int = 0

    def padded_fields(self) -> list[tuple[str, str]]:
        """The fields with a trailing ``uint8_t[n] _padding0`` making the struct a multiple of 8 bytes."""
        size = self.dtype(self.fields).itemsize
        pad = (-size) % 8
        return self.fields + ([(f"uint8_t[{pad}]", "_padding0")] if pad else [])

    @staticmethod
    def dtype(fields: list[tuple[str, str]]) -> np.dtype:
        """The packed numpy dtype of ``fields``."""
        parts = []
        for ctype, name in fields:
            m = _ARRAY.match(ctype)
            base, count = (m.group(1), int(m.group(2))) if m else (ctype, 1)
            if base not in ULOG_TYPES:
                raise ValueError(f"ULog type {base!r} of field {name!r} is not one of {sorted(ULOG_TYPES)}")
            parts.append((name, ULOG_TYPES[base], (count,)) if m else (name, ULOG_TYPES[base]))
        return np.dtype(parts)

    def rows(self) -> np.ndarray:
        """The samples as a packed structured array (sorted by timestamp), without the trailing padding, which the
        format declares but a log does not hold (the specification's rule for padding at the end)."""
        fields = self.fields
        n = len(self.data["timestamp"])
        out = np.zeros(n, dtype=self.dtype(fields))
        for _, name in fields:
            if name in self.data:
                out[name] = np.asarray(self.data[name]).reshape(out[name].shape)
        return out[np.argsort(out["timestamp"], kind="stable")]


def _message(kind: str, payload: bytes) -> bytes:
    if len(payload) > 0xFFFF:
        raise ValueError(f"ULog message {kind!r} of {len(payload)} bytes is too long")
    return struct.pack("<HB", len(payload), ord(kind)) + payload


def _key_value(ctype: str, key: str, value: bytes) -> bytes:
    k = f"{ctype} {key}".encode()
    return bytes([len(k)]) + k + value


def ulog_bytes(
    topics: list[Topic],
    start_us: int,
    info: dict[str, str] | None = None,
    parameters: dict[str, float | int] | None = None,
) -> bytes:
    """The bytes of a ULog file holding ``topics`` (see the module docstring); ``info``: string info messages
    (``sys_name``, ``ver_hw``...); ``parameters``: floats or 32-bit ints."""
    out = bytearray(ULOG_MAGIC + bytes([1]) + struct.pack("<Q", int(start_us)))
    out += _message("B", bytes(40))  # no compat/incompat flags, no appended data
    for key, value in (info or {}).items():
        v = value.encode()
        out += _message("I", _key_value(f"char[{len(v)}]", key, v))
    for key, value in (parameters or {}).items():
        packed = struct.pack("<i", value) if isinstance(value, int) else struct.pack("<f", value)
        out += _message("P", _key_value("int32_t" if isinstance(value, int) else "float", key, packed))
    for topic in topics:
        fmt = f"{topic.name}:" + "".join(f"{ctype} {name};" for ctype, name in topic.padded_fields())
        out += _message("F", fmt.encode())
    rows = [t.rows() for t in topics]
    for msg_id, topic in enumerate(topics):
        out += _message("A", struct.pack("<BH", topic.multi_id, msg_id) + topic.name.encode())
    out += _message("S", SYNC_MAGIC)
    keys = [(int(ts), i, j) for i, rs in enumerate(rows) for j, ts in enumerate(rs["timestamp"])]
    for count, (_, i, j) in enumerate(sorted(keys)):
        out += _message("D", struct.pack("<H", i) + rows[i][j].tobytes())
        if (count + 1) % SYNC_EVERY == 0:
            out += _message("S", SYNC_MAGIC)
    return bytes(out)


def write_ulog(path: str | Path, topics: list[Topic], start_us: int, info=None, parameters=None) -> None:
    """Write :func:`ulog_bytes` to ``path`` atomically."""
    with atomic_open(path, "wb") as f:
        f.write(ulog_bytes(topics, start_us, info, parameters))


__all__ = ["PX4_FORMATS", "SYNC_EVERY", "SYNC_MAGIC", "Topic", "ULOG_TYPES", "ulog_bytes", "write_ulog"]
