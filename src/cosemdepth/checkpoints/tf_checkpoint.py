"""Read TensorFlow object-based checkpoints (``P.index`` + ``P.data-SSSSS-of-NNNNN``) without TensorFlow.

The format (design 13.2): ``P.index`` is a LevelDB-format sorted table whose empty key holds a
``BundleHeaderProto`` and whose other keys are variable paths with a ``BundleEntryProto`` each; a numeric tensor is
``size`` raw little-endian bytes at ``offset`` in data shard ``shard_id``. Every block of the table and every tensor
carries a masked CRC32C, and this reader checks all of them, so a corrupt or truncated file is reported, never
silently read.

Public API:

* :func:`resolve_checkpoint` turns a prefix, an ``.index`` file, a data shard or a folder holding a ``checkpoint``
  text file into the checkpoint prefix.
* :func:`list_entries` lists the entries (key, dtype, shape, ...), string tensors included.
* :func:`read_checkpoint` returns ``{key: np.ndarray}`` for the numeric tensors.
* :class:`CheckpointReader` does the same lazily, one tensor at a time.

Every problem is a :class:`~cosemdepth.errors.CheckpointError` naming the file and what is wrong.
"""

from __future__ import annotations

import math
import os
import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from ..errors import CheckpointError
from .crc32c import crc32c, mask_crc, masked_crc32c

TABLE_MAGIC = 0xDB4775248B80FB57
FOOTER_SIZE = 48
BLOCK_TRAILER_SIZE = 5
#: The bundle format version this reader understands (TensorFlow's ``kTensorBundleVersion``).
BUNDLE_VERSION = 1

#: TensorFlow ``DataType`` enum -> (name, numpy little-endian dtype or None for non-numeric types).
DTYPES: dict[int, tuple[str, str | None]] = {
    1: ("float32", "<f4"),
    2: ("float64", "<f8"),
    3: ("int32", "<i4"),
    4: ("uint8", "|u1"),
    5: ("int16", "<i2"),
    6: ("int8", "|i1"),
    7: ("string", None),
    8: ("complex64", "<c8"),
    9: ("int64", "<i8"),
    10: ("bool", "|b1"),
    14: ("bfloat16", "<u2"),  # read as its bit pattern, returned as float32
    17: ("uint16", "<u2"),
    18: ("complex128", "<c16"),
    19: ("float16", "<f2"),
    20: ("resource", None),
    21: ("variant", None),
    22: ("uint32", "<u4"),
    23: ("uint64", "<u8"),
}


@dataclass(frozen=True)
class TensorEntry:
    """One entry of a checkpoint index (a ``BundleEntryProto``)."""

    key: str
    dtype: str  #: TensorFlow dtype name, e.g. ``"float32"``, ``"string"``, or ``"dtype<N>"`` if unknown
    dtype_code: int
    shape: tuple[int, ...]
    shard_id: int
    offset: int
    size: int  #: bytes in the data shard
    crc32c: int | None  #: masked CRC32C of the bytes, as stored (None if absent)
    partitioned: bool = False  #: a partitioned variable (has ``slices``); not supported for reading

    @property
    def numeric(self) -> bool:
        """True for a tensor stored as raw fixed-size values (what :func:`read_checkpoint` returns)."""
        return DTYPES.get(self.dtype_code, ("", None))[1] is not None


# ----------------------------------------------------------------------------------------------------------------
# Locating a checkpoint


def shard_path(prefix: str | os.PathLike, shard: int, num_shards: int) -> Path:
    """File name of data shard ``shard`` (0-based) of ``num_shards``: ``P.data-00000-of-00001``."""
    return Path(f"{os.fspath(prefix)}.data-{shard:05d}-of-{num_shards:05d}")


_SHARD_SUFFIX = re.compile(r"\.data-\d{5}-of-\d{5}$")
_CKPT_LINE = re.compile(r'^\s*model_checkpoint_path\s*:\s*"((?:[^"\\]|\\.)*)"\s*$')


def resolve_checkpoint(path: str | os.PathLike) -> Path:
    """Return the checkpoint prefix ``P`` (``P.index`` exists) designated by ``path``.

    ``path`` may be the prefix itself (``.../cp-0059.ckpt``), its ``.index`` file or one of its data shards, or a
    folder holding a ``checkpoint`` text file, whose ``model_checkpoint_path: "..."`` line names the prefix
    (relative to that folder, or absolute).
    """
    try:
        return _resolve_checkpoint(Path(path))
    except OSError as e:  # a path the file system cannot even look up, e.g. a name too long
        raise CheckpointError(f"{e.filename or path}: cannot access ({e.strerror})") from None


def _resolve_checkpoint(p: Path) -> Path:
    if p.is_dir():
        state = p / "checkpoint"
        if not state.is_file():
            found = sorted(x.name for x in p.glob("*.index"))
            hint = f"; it holds {', '.join(found[:5])}: pass a prefix such as {p / found[0][:-6]}" if found else ""
            raise CheckpointError(f"{p}: folder holds no 'checkpoint' file naming a TensorFlow checkpoint{hint}")
        prefix = _read_checkpoint_state(state)
        if not prefix.is_absolute():
            prefix = p / prefix
        try:
            found = Path(f"{prefix}.index").is_file()
        except OSError as e:
            raise CheckpointError(
                f"{state}: names checkpoint {prefix}, which cannot be accessed ({e.strerror})"
            ) from None
        if not found:
            raise CheckpointError(f"{state}: names checkpoint {prefix}, but {prefix}.index does not exist")
        return prefix
    name = p.name
    if name.endswith(".index") and p.is_file():
        return p.with_name(name[: -len(".index")])
    if _SHARD_SUFFIX.search(name) and p.is_file():
        return p.with_name(_SHARD_SUFFIX.sub("", name))
    if Path(f"{p}.index").is_file():
        return p
    if not p.exists() and not p.parent.is_dir():
        raise CheckpointError(f"{p}: no such checkpoint (folder {p.parent} does not exist)")
    raise CheckpointError(f"{p}: not a TensorFlow checkpoint ({p}.index not found, and not a folder)")


def _read_checkpoint_state(state: Path) -> Path:
    try:
        text = state.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise CheckpointError(f"{state}: cannot read checkpoint state file: {e}") from e
    for line in text.splitlines():
        m = _CKPT_LINE.match(line)
        if m:
            value = _unescape_text_proto(m.group(1))
            if not value:
                raise CheckpointError(f"{state}: model_checkpoint_path is empty")
            return Path(value)
    raise CheckpointError(f"{state}: no 'model_checkpoint_path: \"...\"' line (not a TensorFlow checkpoint state file)")


_ESCAPE = re.compile(rb"\\([0-7]{1,3}|x[0-9a-fA-F]{1,2}|.)", re.DOTALL)
_SIMPLE_ESCAPES = {b"n": b"\n", b"r": b"\r", b"t": b"\t", b"a": b"\a", b"b": b"\b", b"f": b"\f", b"v": b"\v"}


def _unescape_text_proto(s: str) -> str:
    """Undo the C-style escapes of a text-format protobuf string (``\\"``, ``\\\\``, octal/hex bytes)."""

    def one(m: re.Match) -> bytes:
        e = m.group(1)
        if e[:1] == b"x":
            return bytes([int(e[1:], 16)])
        if e[:1].isdigit():
            return bytes([int(e, 8) & 0xFF])
        return _SIMPLE_ESCAPES.get(e, e)

    return _ESCAPE.sub(one, s.encode("utf-8")).decode("utf-8", errors="surrogateescape")


# ----------------------------------------------------------------------------------------------------------------
# Low-level decoding: varints, protobuf wire format


class _Truncated(Exception):
    pass


def _varint(buf: bytes | memoryview, pos: int, limit: int, max_bytes: int = 10) -> tuple[int, int]:
    """Decode a base-128 varint at ``pos``; return ``(value, new_pos)``."""
    result = 0
    shift = 0
    for i in range(max_bytes):
        if pos >= limit:
            raise _Truncated("varint runs past the end of its buffer")
        b = buf[pos]
        pos += 1
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            return result, pos
        shift += 7
    raise _Truncated(f"varint longer than {max_bytes} bytes")


def _proto_fields(data: bytes) -> dict[int, list]:
    """Decode a protobuf message into ``{field_number: [values]}``.

    Varints (wire type 0) are ints, fixed64/fixed32 (1, 5) are unsigned ints, length-delimited (2) are bytes.
    """
    fields: dict[int, list] = {}
    pos, end = 0, len(data)
    while pos < end:
        tag, pos = _varint(data, pos, end)
        number, wire = tag >> 3, tag & 7
        if number == 0:
            raise _Truncated("field number 0")
        if wire == 0:
            value, pos = _varint(data, pos, end)
        elif wire == 1:
            if pos + 8 > end:
                raise _Truncated("fixed64 field runs past the end")
            value = struct.unpack_from("<Q", data, pos)[0]
            pos += 8
        elif wire == 2:
            n, pos = _varint(data, pos, end)
            if pos + n > end:
                raise _Truncated("length-delimited field runs past the end")
            value = bytes(data[pos : pos + n])
            pos += n
        elif wire == 5:
            if pos + 4 > end:
                raise _Truncated("fixed32 field runs past the end")
            value = struct.unpack_from("<I", data, pos)[0]
            pos += 4
        else:
            raise _Truncated(f"unsupported protobuf wire type {wire}")
        fields.setdefault(number, []).append(value)
    return fields


def _int64(v: int) -> int:
    return v - (1 << 64) if v >= 1 << 63 else v


def _all(fields: dict[int, list], number: int, kind: type) -> list:
    """Every value of field ``number``, checked to be of ``kind`` (``int`` for varint/fixed fields, ``bytes`` for
    length-delimited ones): a field of the wrong wire type is a malformed message."""
    values = fields.get(number, [])
    for v in values:
        if not isinstance(v, kind):
            expected = "a number" if kind is int else "bytes"
            raise _Truncated(f"field {number} has the wrong wire type (expected {expected})")
    return values


def _last(fields: dict[int, list], number: int, default=0):
    """The last value of field ``number`` (protobuf's rule for repeated scalars), of the type of ``default``."""
    values = _all(fields, number, type(default))
    return values[-1] if values else default


def _decode_shape(data: bytes) -> tuple[int, ...]:
    f = _proto_fields(data)
    if _last(f, 3, 0):
        raise _Truncated("tensor shape has unknown rank")
    dims = []
    for dim in _all(f, 2, bytes):
        size = _int64(_last(_proto_fields(dim), 1, 0))
        if size < 0:
            raise _Truncated(f"tensor shape has an unknown dimension ({size})")
        dims.append(size)
    return tuple(dims)


def _decode_entry(key: str, value: bytes) -> TensorEntry:
    f = _proto_fields(value)
    code = _last(f, 1, 0)
    name = DTYPES.get(code, (f"dtype<{code}>", None))[0]
    shape_bytes = _last(f, 2, b"")
    shape = _decode_shape(shape_bytes) if shape_bytes else ()
    crc = _all(f, 6, int)
    return TensorEntry(
        key=key,
        dtype=name,
        dtype_code=code,
        shape=shape,
        shard_id=_last(f, 3, 0),
        offset=_int64(_last(f, 4, 0)),
        size=_int64(_last(f, 5, 0)),
        crc32c=crc[-1] if crc else None,
        partitioned=bool(f.get(7)),
    )


# ----------------------------------------------------------------------------------------------------------------
# The LevelDB-format table of the .index file


def _read_block(index: Path, data: bytes, offset: int, size: int, what: str) -> bytes:
    """Return the contents of the block at ``(offset, size)``, after checking its trailer."""
    end = offset + size + BLOCK_TRAILER_SIZE
    if offset < 0 or size < 0 or end > len(data) - FOOTER_SIZE:
        raise CheckpointError(
            f"{index}: {what} block (offset {offset}, size {size}) runs past the end of the table "
            f"({len(data)} bytes): truncated or corrupt index"
        )
    block = data[offset : offset + size]
    ctype = data[offset + size]
    (stored,) = struct.unpack_from("<I", data, offset + size + 1)
    if masked_crc32c(data[offset : offset + size + 1]) != stored:
        raise CheckpointError(f"{index}: CRC32C mismatch in {what} block at offset {offset}: corrupt index")
    if ctype != 0:
        raise CheckpointError(
            f"{index}: {what} block at offset {offset} is compressed (type {ctype}); only uncompressed "
            "tables are supported (TensorFlow writes the index uncompressed)"
        )
    return block


def _block_entries(index: Path, block: bytes, what: str) -> Iterator[tuple[bytes, bytes]]:
    """Yield the ``(key, value)`` entries of a table block (prefix-compressed keys, restart array at the end)."""
    if len(block) < 4:
        raise CheckpointError(f"{index}: {what} block is too short ({len(block)} bytes): corrupt index")
    (num_restarts,) = struct.unpack_from("<I", block, len(block) - 4)
    limit = len(block) - 4 - 4 * num_restarts
    if limit < 0:
        raise CheckpointError(f"{index}: {what} block has a bad restart count ({num_restarts}): corrupt index")
    pos = 0
    key = b""
    try:
        while pos < limit:
            shared, pos = _varint(block, pos, limit, 5)
            unshared, pos = _varint(block, pos, limit, 5)
            vlen, pos = _varint(block, pos, limit, 5)
            if shared > len(key) or pos + unshared + vlen > limit:
                raise _Truncated("entry runs past the end of its block")
            key = key[:shared] + block[pos : pos + unshared]
            pos += unshared
            yield key, block[pos : pos + vlen]
            pos += vlen
    except _Truncated as e:
        raise CheckpointError(f"{index}: malformed {what} block ({e}): corrupt index") from None


def _block_handle(index: Path, value: bytes, what: str) -> tuple[int, int]:
    try:
        offset, pos = _varint(value, 0, len(value))
        size, _ = _varint(value, pos, len(value))
    except _Truncated as e:
        raise CheckpointError(f"{index}: malformed block handle in {what} ({e}): corrupt index") from None
    return offset, size


def _read_table(index: Path) -> list[tuple[bytes, bytes]]:
    """All ``(key, value)`` pairs of the table in ``index``, in file order (checked to be strictly sorted)."""
    try:
        data = index.read_bytes()
    except FileNotFoundError:
        raise CheckpointError(f"{index}: checkpoint index file not found") from None
    except OSError as e:
        raise CheckpointError(f"{index}: cannot read checkpoint index: {e}") from e
    if len(data) < FOOTER_SIZE:
        raise CheckpointError(
            f"{index}: {len(data)} bytes, too short for a TensorFlow checkpoint index (truncated or not an index)"
        )
    (magic,) = struct.unpack_from("<Q", data, len(data) - 8)
    if magic != TABLE_MAGIC:
        raise CheckpointError(
            f"{index}: bad magic number 0x{magic:016x} (expected 0x{TABLE_MAGIC:016x}): not a TensorFlow checkpoint "
            "index, or truncated"
        )
    footer = data[len(data) - FOOTER_SIZE : len(data) - 8]
    try:
        _meta_off, pos = _varint(footer, 0, len(footer))
        _meta_size, pos = _varint(footer, pos, len(footer))
        idx_off, pos = _varint(footer, pos, len(footer))
        idx_size, pos = _varint(footer, pos, len(footer))
    except _Truncated as e:
        raise CheckpointError(f"{index}: malformed table footer ({e}): corrupt index") from None
    index_block = _read_block(index, data, idx_off, idx_size, "index")
    pairs: list[tuple[bytes, bytes]] = []
    for _, handle in _block_entries(index, index_block, "index"):
        off, size = _block_handle(index, handle, "index block")
        block = _read_block(index, data, off, size, "data")
        pairs.extend(_block_entries(index, block, "data"))
    for (a, _), (b, _) in zip(pairs, pairs[1:]):
        if not a < b:
            raise CheckpointError(f"{index}: keys out of order or duplicated ({a!r} then {b!r}): corrupt index")
    return pairs


# ----------------------------------------------------------------------------------------------------------------
# The bundle


class CheckpointReader:
    """A TensorFlow checkpoint opened for reading.

    ``CheckpointReader(path)`` reads and checks the index (header, every block CRC, every entry). Tensors are read
    on demand with :meth:`read`, which checks each tensor's CRC32C.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.prefix: Path = resolve_checkpoint(path)
        self.index_path = Path(f"{self.prefix}.index")
        pairs = _read_table(self.index_path)
        if not pairs or pairs[0][0] != b"":
            raise CheckpointError(f"{self.index_path}: no bundle header (empty key): not a TensorFlow checkpoint index")
        try:
            header = _proto_fields(pairs[0][1])
            version = _proto_fields(_last(header, 3, b""))
            self.num_shards = _last(header, 1, 0)
            endianness = _last(header, 2, 0)
            min_consumer = _int64(_last(version, 2, 0))
        except _Truncated as e:
            raise CheckpointError(f"{self.index_path}: malformed bundle header ({e})") from None
        if endianness == 1:
            raise CheckpointError(
                f"{self.index_path}: big-endian checkpoint; only little-endian checkpoints are supported"
            )
        if endianness != 0:
            raise CheckpointError(f"{self.index_path}: unknown endianness {endianness} in bundle header")
        if min_consumer > BUNDLE_VERSION:
            raise CheckpointError(
                f"{self.index_path}: bundle format version {min_consumer} or newer is required to read it; "
                f"this reader supports version {BUNDLE_VERSION}"
            )
        if self.num_shards < 1:
            raise CheckpointError(f"{self.index_path}: bundle header says {self.num_shards} data shards")
        self.entries: dict[str, TensorEntry] = {}
        for raw_key, value in pairs[1:]:
            key = raw_key.decode("utf-8", errors="backslashreplace")
            try:
                entry = _decode_entry(key, value)
            except _Truncated as e:
                raise CheckpointError(f"{self.index_path}: malformed entry for {key!r} ({e})") from None
            if not entry.partitioned and not 0 <= entry.shard_id < self.num_shards:
                raise CheckpointError(
                    f"{self.index_path}: entry {key!r} is in shard {entry.shard_id}, but the bundle has "
                    f"{self.num_shards} shard(s)"
                )
            self.entries[key] = entry

    # -- listing ----------------------------------------------------------------------------------------------

    def __contains__(self, key: object) -> bool:
        return key in self.entries

    def __len__(self) -> int:
        return len(self.entries)

    def keys(self) -> list[str]:
        return list(self.entries)

    def shard_file(self, shard: int) -> Path:
        return shard_path(self.prefix, shard, self.num_shards)

    # -- reading ----------------------------------------------------------------------------------------------

    def read(self, key: str) -> np.ndarray:
        """The numeric tensor ``key`` as a native-endian numpy array of its shape (bfloat16 comes back as float32)."""
        entry = self.entries.get(key)
        if entry is None:
            raise CheckpointError(f"{self.index_path}: no entry {key!r}")
        return self._read_entries([entry])[key]

    def read_all(self, keys: Iterable[str] | None = None) -> dict[str, np.ndarray]:
        """``{key: array}`` for ``keys`` (default: every numeric tensor; string/resource entries are skipped)."""
        if keys is None:
            entries = [e for e in self.entries.values() if e.numeric]
        else:
            entries = []
            for k in keys:
                if k not in self.entries:
                    raise CheckpointError(f"{self.index_path}: no entry {k!r}")
                entries.append(self.entries[k])
        return self._read_entries(entries)

    def read_strings(self, key: str) -> list[bytes]:
        """The elements of string tensor ``key`` (row-major), after checking the tensor's CRC32C.

        Layout: one varint64 length per element, a 4-byte masked CRC32C of the lengths, then the bytes. The CRCs
        cover each length as a 4-byte little-endian integer (checked against a checkpoint written by TensorFlow).
        """
        entry = self.entries.get(key)
        if entry is None:
            raise CheckpointError(f"{self.index_path}: no entry {key!r}")
        if entry.dtype != "string" or entry.partitioned:
            raise CheckpointError(f"{self.index_path}: {key!r} is not a (non-partitioned) string tensor")
        shard = self.shard_file(entry.shard_id)
        with _open_shard(shard) as f:
            data = self._read_bytes(f, shard, _file_size(f), entry, check_crc=False)
        count = math.prod(entry.shape)  # exact: a huge declared shape must not wrap around
        bad = CheckpointError(f"{shard}: malformed string tensor {key!r}: corrupt data shard")
        pos, lengths, crc = 0, [], 0
        try:
            for _ in range(count):
                n, pos = _varint(data, pos, len(data))
                lengths.append(n)
                crc = crc32c((n & 0xFFFFFFFF).to_bytes(4, "little"), crc)
        except _Truncated:
            raise bad from None
        if pos + 4 > len(data):
            raise bad
        stored = data[pos : pos + 4]
        if int.from_bytes(stored, "little") != mask_crc(crc):
            raise CheckpointError(
                f"{shard}: CRC32C mismatch in the lengths of string tensor {key!r}: corrupt data shard"
            )
        crc = crc32c(stored, crc)
        pos += 4
        if pos + sum(lengths) != len(data):
            raise bad
        crc = crc32c(data[pos:], crc)
        if entry.crc32c is not None and mask_crc(crc) != entry.crc32c:
            raise CheckpointError(f"{shard}: CRC32C mismatch for tensor {key!r}: corrupt data shard")
        out = []
        for n in lengths:
            out.append(data[pos : pos + n])
            pos += n
        return out

    def verify(self) -> None:
        """Read every entry and check every CRC (numeric and string tensors); raise on the first problem."""
        self.read_all()
        for e in self.entries.values():
            if e.dtype == "string" and not e.partitioned:
                self.read_strings(e.key)

    def _read_entries(self, entries: list[TensorEntry]) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        by_shard: dict[int, list[TensorEntry]] = {}
        for e in entries:
            if e.partitioned:
                raise CheckpointError(f"{self.index_path}: {e.key!r} is a partitioned variable, which is not supported")
            if not e.numeric:
                raise CheckpointError(f"{self.index_path}: {e.key!r} is a {e.dtype} tensor, not a numeric one")
            by_shard.setdefault(e.shard_id, []).append(e)
        for shard_id in sorted(by_shard):
            shard = self.shard_file(shard_id)
            with _open_shard(shard) as f:
                file_size = _file_size(f)
                for e in sorted(by_shard[shard_id], key=lambda e: e.offset):
                    out[e.key] = self._decode(shard, e, self._read_bytes(f, shard, file_size, e))
        return {e.key: out[e.key] for e in entries}

    def _read_bytes(self, f, shard: Path, file_size: int, e: TensorEntry, check_crc: bool = True) -> bytes:
        if e.offset < 0 or e.size < 0 or e.offset + e.size > file_size:
            raise CheckpointError(
                f"{shard}: tensor {e.key!r} needs bytes {e.offset}..{e.offset + e.size}, but the file has "
                f"{file_size} bytes: truncated data shard"
            )
        f.seek(e.offset)
        data = f.read(e.size)
        if len(data) != e.size:
            raise CheckpointError(f"{shard}: short read for tensor {e.key!r}: truncated data shard")
        if check_crc and e.crc32c is not None and masked_crc32c(data) != e.crc32c:
            raise CheckpointError(f"{shard}: CRC32C mismatch for tensor {e.key!r}: corrupt data shard")
        return data

    def _decode(self, shard: Path, e: TensorEntry, data: bytes) -> np.ndarray:
        np_dtype = np.dtype(DTYPES[e.dtype_code][1])
        count = math.prod(e.shape)  # exact: a huge declared shape must not wrap around
        if count * np_dtype.itemsize != len(data):
            raise CheckpointError(
                f"{shard}: tensor {e.key!r} of dtype {e.dtype} and shape {list(e.shape)} should take "
                f"{count * np_dtype.itemsize} bytes, the index says {len(data)}: corrupt index"
            )
        arr = np.frombuffer(data, dtype=np_dtype).reshape(e.shape)
        if e.dtype == "bfloat16":
            return (arr.astype(np.uint32) << np.uint32(16)).view(np.float32)
        return arr.astype(np_dtype.newbyteorder("="), copy=True)


def _open_shard(shard: Path):
    try:
        return open(shard, "rb")
    except FileNotFoundError:
        raise CheckpointError(f"{shard}: data shard of the checkpoint not found") from None
    except OSError as e:
        raise CheckpointError(f"{shard}: cannot read data shard: {e}") from e


def _file_size(f) -> int:
    return os.fstat(f.fileno()).st_size


def list_entries(path: str | os.PathLike) -> list[TensorEntry]:
    """Every entry of the checkpoint at ``path`` (see :func:`resolve_checkpoint`), in key order."""
    return list(CheckpointReader(path).entries.values())


def read_checkpoint(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every numeric tensor of the checkpoint at ``path`` as ``{key: np.ndarray}`` (string tensors are skipped)."""
    return CheckpointReader(path).read_all()


def is_tf_checkpoint(path: str | os.PathLike) -> bool:
    """True if ``path`` designates a TensorFlow checkpoint that :func:`resolve_checkpoint` would accept."""
    p = Path(path)
    if p.is_dir():
        return (p / "checkpoint").is_file()
    if Path(f"{p}.index").is_file():
        return True
    return p.is_file() and (p.name.endswith(".index") or bool(_SHARD_SUFFIX.search(p.name)))


__all__ = [
    "CheckpointReader",
    "TensorEntry",
    "DTYPES",
    "is_tf_checkpoint",
    "list_entries",
    "read_checkpoint",
    "resolve_checkpoint",
    "shard_path",
]
