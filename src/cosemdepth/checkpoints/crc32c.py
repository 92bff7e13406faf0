"""CRC32C (Castagnoli) through ``google-crc32c``, and the "masked" form LevelDB tables and TensorFlow bundles store."""

from __future__ import annotations

import google_crc32c
import numpy as np

_MASK_DELTA = 0xA282EAD8


def crc32c(data: bytes | bytearray | memoryview | np.ndarray, crc: int = 0) -> int:
    """Standard CRC32C of ``data`` (``crc32c(b"123456789") == 0xE3069283``); a previous ``crc`` is extended."""
    if isinstance(data, memoryview):  # the C extension takes bytes and buffers, not memoryviews
        data = np.frombuffer(data, np.uint8)
    return google_crc32c.extend(crc, data)


def mask_crc(crc: int) -> int:
    """LevelDB/TensorFlow masking: rotate right by 15 bits and add a constant (32-bit arithmetic)."""
    crc &= 0xFFFFFFFF
    return ((((crc >> 15) | (crc << 17)) & 0xFFFFFFFF) + _MASK_DELTA) & 0xFFFFFFFF


def unmask_crc(masked: int) -> int:
    """Inverse of :func:`mask_crc`."""
    rot = (masked - _MASK_DELTA) & 0xFFFFFFFF
    return ((rot >> 17) | (rot << 15)) & 0xFFFFFFFF


def masked_crc32c(data: bytes | bytearray | memoryview | np.ndarray) -> int:
    """``mask_crc(crc32c(data))``: the value stored in block trailers and ``BundleEntryProto.crc32c``."""
    return mask_crc(crc32c(data))


__all__ = ["crc32c", "mask_crc", "unmask_crc", "masked_crc32c"]
