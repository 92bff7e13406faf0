"""CRC32C (Castagnoli) in numpy, and the "masked" form used by LevelDB tables and TensorFlow bundles.

Why not a package: ``google-crc32c`` / ``crc32c`` would be faster, but the only user is the checkpoint reader,
which checks a few tens of MB once per conversion; a vectorised numpy version does 20 MB in about 0.1 s on
one core (see ``benchmarks/tf_checkpoint_speed.py``) and keeps the dependency list unchanged.

How it is fast without a compiled loop: the CRC register is linear over GF(2). The buffer is cut into ``M`` rows
of ``C`` bytes, and the table-driven byte step runs on all rows at once (``C`` numpy steps on ``M``-vectors, each
row starting from register 0). Each row's register is then "shifted" over the ``C`` bytes that follow it with a
precomputed linear operator (four 256-entry tables) and the rows are combined. Leading zero bytes do not change a
zero register, so the buffer is zero-padded at the front to a whole number of rows; the standard initial value
``0xFFFFFFFF`` (or a previous CRC being extended) is applied by XOR-ing it into the first four data bytes, which is
equivalent for a reflected CRC.
"""

from __future__ import annotations

import numpy as np

_POLY = 0x82F63B78  # reflected Castagnoli polynomial
_MASK_DELTA = 0xA282EAD8
_SMALL = 4096  # below this many bytes the plain byte loop is as fast


def _make_table() -> np.ndarray:
    table = np.zeros(256, dtype=np.uint32)
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ _POLY if c & 1 else c >> 1
        table[i] = c
    return table


_TABLE = _make_table()
_TABLE_LIST = [int(v) for v in _TABLE]
_SHIFT_CACHE: dict[int, np.ndarray] = {}


def _update_small(crc: int, data: bytes | memoryview) -> int:
    """Advance the raw register ``crc`` (no pre/post inversion) over ``data`` one byte at a time."""
    t = _TABLE_LIST
    for b in bytes(data):
        crc = t[(crc ^ b) & 0xFF] ^ (crc >> 8)
    return crc


def _shift_tables(nbytes: int) -> np.ndarray:
    """Tables ``T[4, 256]`` of the linear map "advance the register over ``nbytes`` zero bytes".

    ``shift(x) = T[0][x & 0xFF] ^ T[1][(x >> 8) & 0xFF] ^ T[2][(x >> 16) & 0xFF] ^ T[3][x >> 24]``.
    """
    cached = _SHIFT_CACHE.get(nbytes)
    if cached is not None:
        return cached
    # Images of the 32 basis bits under "advance over nbytes zero bytes", by binary powering of the 1-byte step.
    images = np.array([1 << i for i in range(32)], dtype=np.uint32)  # identity
    step = _zero_byte_images()  # operator for 1 zero byte
    n = nbytes
    while n:
        if n & 1:
            images = _apply_images(step, images)
        step = _apply_images(step, step)
        n >>= 1
    tables = np.zeros((4, 256), dtype=np.uint32)
    values = np.arange(256, dtype=np.uint32)
    for byte in range(4):
        acc = np.zeros(256, dtype=np.uint32)
        for bit in range(8):
            acc ^= np.where((values >> np.uint32(bit)) & np.uint32(1), images[8 * byte + bit], np.uint32(0))
        tables[byte] = acc
    _SHIFT_CACHE[nbytes] = tables
    return tables


def _zero_byte_images() -> np.ndarray:
    """Images of the 32 basis bits under one step over a zero byte."""
    return np.array([_update_small(1 << i, b"\x00") for i in range(32)], dtype=np.uint32)


def _apply_images(op: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Apply the linear operator given by its basis images ``op[32]`` to every value of ``x``."""
    out = np.zeros_like(x)
    for bit in range(32):
        out ^= np.where((x >> np.uint32(bit)) & np.uint32(1), op[bit], np.uint32(0))
    return out


def crc32c(data: bytes | bytearray | memoryview | np.ndarray, crc: int = 0) -> int:
    """Standard CRC32C of ``data`` (e.g. ``crc32c(b"123456789") == 0xE3069283``).

    ``crc`` continues a previous result: ``crc32c(b, crc32c(a)) == crc32c(a + b)``.
    """
    init = (crc & 0xFFFFFFFF) ^ 0xFFFFFFFF
    buf = np.frombuffer(memoryview(data).cast("B"), dtype=np.uint8) if not isinstance(data, np.ndarray) else (
        np.ascontiguousarray(data).reshape(-1).view(np.uint8)
    )
    n = buf.size
    if n < _SMALL:
        return _update_small(init, buf.tobytes()) ^ 0xFFFFFFFF
    # Cost ~ cols numpy steps + rows Python combine steps: balance them; a power of two keeps the cache small.
    cols = 1 << max(4, int(0.2 * n**0.5).bit_length())
    rows = -(-n // cols)
    padded = np.zeros(rows * cols, dtype=np.uint8)
    padded[rows * cols - n :] = buf
    start = rows * cols - n
    # The initial register, applied to the first 4 data bytes (equivalent for a reflected CRC).
    padded[start : start + 4] ^= np.frombuffer(init.to_bytes(4, "little"), dtype=np.uint8)
    columns = np.ascontiguousarray(padded.reshape(rows, cols).T)  # [cols, rows] uint8
    reg = np.zeros(rows, dtype=np.uint32)
    table = _TABLE
    mask = np.uint32(0xFF)
    eight = np.uint32(8)
    for c in range(cols):
        reg = table[(reg ^ columns[c]) & mask] ^ (reg >> eight)
    t = _shift_tables(cols)
    crc = 0
    t0, t1, t2, t3 = ([int(v) for v in t[i]] for i in range(4))
    for r in reg.tolist():
        crc = t0[crc & 0xFF] ^ t1[(crc >> 8) & 0xFF] ^ t2[(crc >> 16) & 0xFF] ^ t3[crc >> 24] ^ r
    return crc ^ 0xFFFFFFFF


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
