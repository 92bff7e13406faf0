"""A small writer of TensorFlow-format checkpoints (``P.index`` + ``P.data-*``), for tests only.

It writes the format of design 13.2 from the description, independently of the reader: a LevelDB-format
table (prefix-compressed keys, restart points, several data blocks, an index block, an empty meta-index block,
the 48-byte footer) whose empty key holds the ``BundleHeaderProto``, and raw little-endian tensors in one or
more data shards, every block and tensor with its masked CRC32C. Options produce the odd cases the reader must
reject (big-endian header, compressed block type, ...). It also builds the key/shape sets of Co-SemDepth,
M4Depth and M4Semantic checkpoints as design section 13.1 names them.

CRC32C comes from ``cosemdepth.checkpoints.crc32c``, whose values are checked separately against published test vectors,
a bit-by-bit reference and a checkpoint written by TensorFlow itself.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from cosemdepth.checkpoints.crc32c import crc32c, mask_crc

MAGIC = 0xDB4775248B80FB57
SUFFIX = "/.ATTRIBUTES/VARIABLE_VALUE"

_DTYPE_CODES = {
    np.dtype(np.float32): 1,
    np.dtype(np.float64): 2,
    np.dtype(np.int32): 3,
    np.dtype(np.uint8): 4,
    np.dtype(np.int16): 5,
    np.dtype(np.int8): 6,
    np.dtype(np.int64): 9,
    np.dtype(np.bool_): 10,
    np.dtype(np.uint16): 17,
    np.dtype(np.float16): 19,
}


class BFloat16:
    """Marks a float32 array to be stored as bfloat16 (its top 16 bits)."""

    def __init__(self, values: np.ndarray) -> None:
        self.values = np.asarray(values, dtype=np.float32)


# --------------------------------------------------------------------------------------------------------------
# protobuf / varint encoding


def varint(n: int) -> bytes:
    if n < 0:
        n += 1 << 64
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def pb_varint(field: int, value: int) -> bytes:
    return varint(field << 3) + varint(value)


def pb_bytes(field: int, value: bytes) -> bytes:
    return varint((field << 3) | 2) + varint(len(value)) + value


def pb_fixed32(field: int, value: int) -> bytes:
    return varint((field << 3) | 5) + struct.pack("<I", value)


def shape_proto(shape: Sequence[int]) -> bytes:
    return b"".join(pb_bytes(2, pb_varint(1, d) if d else b"") for d in shape)


def entry_proto(dtype: int, shape: Sequence[int], shard: int, offset: int, size: int, crc: int) -> bytes:
    out = pb_varint(1, dtype) + pb_bytes(2, shape_proto(shape))
    if shard:
        out += pb_varint(3, shard)
    if offset:
        out += pb_varint(4, offset)
    if size:
        out += pb_varint(5, size)
    return out + pb_fixed32(6, crc)


def header_proto(num_shards: int, endianness: int = 0, min_consumer: int = 0) -> bytes:
    version = pb_varint(1, 1) + (pb_varint(2, min_consumer) if min_consumer else b"")
    out = pb_varint(1, num_shards)
    if endianness:
        out += pb_varint(2, endianness)
    return out + pb_bytes(3, version)


# --------------------------------------------------------------------------------------------------------------
# LevelDB table


def _block(entries: Sequence[tuple[bytes, bytes]], restart_interval: int) -> bytes:
    out = bytearray()
    restarts = []
    prev = b""
    for i, (key, value) in enumerate(entries):
        if i % restart_interval == 0:
            restarts.append(len(out))
            shared = 0
        else:
            shared = 0
            while shared < min(len(prev), len(key)) and prev[shared] == key[shared]:
                shared += 1
        out += varint(shared) + varint(len(key) - shared) + varint(len(value)) + key[shared:] + value
        prev = key
    if not restarts:
        restarts = [0]
    for r in restarts:
        out += struct.pack("<I", r)
    out += struct.pack("<I", len(restarts))
    return bytes(out)


def table_bytes(
    entries: Sequence[tuple[bytes, bytes]],
    block_size: int = 4096,
    restart_interval: int = 16,
    compression: int = 0,
) -> bytes:
    """A LevelDB-format table holding the sorted ``entries``."""
    out = bytearray()

    def put(block: bytes, ctype: int = 0) -> bytes:
        handle = varint(len(out)) + varint(len(block))
        trailer = bytes([ctype])
        out.extend(block + trailer + struct.pack("<I", mask_crc(crc32c(block + trailer))))
        return handle

    index_entries = []
    pending: list[tuple[bytes, bytes]] = []
    size = 0
    for key, value in entries:
        pending.append((key, value))
        size += len(key) + len(value) + 8
        if size >= block_size:
            index_entries.append((pending[-1][0], put(_block(pending, restart_interval), compression)))
            pending, size = [], 0
    if pending:
        index_entries.append((pending[-1][0], put(_block(pending, restart_interval), compression)))
    meta_handle = put(_block([], 1))
    index_handle = put(_block(index_entries, 1))
    footer = (meta_handle + index_handle).ljust(40, b"\x00") + struct.pack("<Q", MAGIC)
    out.extend(footer)
    return bytes(out)


# --------------------------------------------------------------------------------------------------------------
# Bundle


def _tensor_bytes(value) -> tuple[int, tuple[int, ...], bytes, int]:
    """``(dtype code, shape, bytes, masked crc)`` of a tensor (a numpy array, BFloat16, or a list of bytes)."""
    if isinstance(value, list):  # a 1-D string tensor
        lengths = b"".join(varint(len(s)) for s in value)
        crc = 0
        for s in value:
            crc = crc32c(struct.pack("<I", len(s)), crc)
        length_crc = struct.pack("<I", mask_crc(crc))
        crc = crc32c(length_crc, crc)
        data = b"".join(value)
        crc = crc32c(data, crc)
        return 7, (len(value),), lengths + length_crc + data, mask_crc(crc)
    if isinstance(value, bytes):  # a scalar string tensor
        dtype, _, data, crc = _tensor_bytes([value])
        return dtype, (), data, crc
    if isinstance(value, BFloat16):
        data = (value.values.view(np.uint32) >> np.uint32(16)).astype("<u2").tobytes()
        return 14, value.values.shape, data, mask_crc(crc32c(data))
    arr = np.asarray(value)
    code = _DTYPE_CODES[arr.dtype]
    data = np.ascontiguousarray(arr, dtype=arr.dtype.newbyteorder("<")).tobytes()
    return code, arr.shape, data, mask_crc(crc32c(data))


def write_bundle(
    prefix: str | os.PathLike,
    tensors: Mapping[str, object],
    *,
    num_shards: int = 1,
    endianness: int = 0,
    min_consumer: int = 0,
    block_size: int = 4096,
    restart_interval: int = 16,
    compression: int = 0,
    checkpoint_file: bool = True,
) -> Path:
    """Write ``prefix.index`` and ``prefix.data-0000i-of-0000n`` (tensor i goes to shard i mod n) and, if asked, a
    ``checkpoint`` state file beside them naming the prefix (relative). Returns the prefix."""
    prefix = Path(prefix)
    prefix.parent.mkdir(parents=True, exist_ok=True)
    shards = [bytearray() for _ in range(num_shards)]
    entries = [(b"", header_proto(num_shards, endianness, min_consumer))]
    for i, key in enumerate(sorted(tensors, key=lambda k: k.encode())):
        dtype, shape, data, crc = _tensor_bytes(tensors[key])
        shard = i % num_shards
        offset = len(shards[shard])
        shards[shard] += data
        entries.append((key.encode(), entry_proto(dtype, shape, shard, offset, len(data), crc)))
    Path(f"{prefix}.index").write_bytes(table_bytes(entries, block_size, restart_interval, compression))
    for s, data in enumerate(shards):
        Path(f"{prefix}.data-{s:05d}-of-{num_shards:05d}").write_bytes(bytes(data))
    if checkpoint_file:
        (prefix.parent / "checkpoint").write_text(
            f'model_checkpoint_path: "{prefix.name}"\nall_model_checkpoint_paths: "{prefix.name}"\n'
        )
    return prefix


# --------------------------------------------------------------------------------------------------------------
# Model checkpoints (design 13.1 names, design 4.1 / 5.1 / 6 shapes)

ENCODER_CHANNELS = (16, 32, 64, 96, 128, 192)
REFINER = (128, 128, 96, 64, 32, 16)


def depth_refiner_inputs(level: int, sncv=True, time_recurrence=True, level_memory=True, subdivision=True) -> int:
    k = 2 ** (level // 2) if subdivision else 1
    return 9 * k + 1 + (4 if level_memory else 0) + (49 * k if sncv else 0) + (1 if time_recurrence else 0)


def model_tensors(
    levels: int = 5,
    depth: bool = True,
    semantic: bool = True,
    classes: int = 7,
    dinl: bool = True,
    sncv: bool = True,
    time_recurrence: bool = True,
    level_memory: bool = True,
    subdivision: bool = True,
    roots: tuple[str, str, str] = ("encoder", "d_estimator", "s_estimator"),
    extras: bool = True,
    seed: int = 0,
    zeros: bool = False,
    semantic_extra: int = 0,
) -> dict[str, object]:
    """TF checkpoint tensors of a model, keyed as the authors' code writes them, with random (or zero) values.

    ``semantic_extra`` input channels are added to every semantic refiner (layouts the released code does not have).

    ``extras`` adds what a real training checkpoint also holds: Adam slots for two variables, optimizer scalars,
    metric variables, the step counter, inference state variables and the object graph.
    """
    rng = np.random.default_rng(seed)

    def arr(*shape):
        if zeros:
            return np.zeros(shape, np.float32)
        return rng.standard_normal(shape, dtype=np.float32)

    enc, dec_d, dec_s = roots
    t: dict[str, object] = {}

    def conv(path, c_in, c_out):
        t[f"{path}/kernel{SUFFIX}"] = arr(3, 3, c_in, c_out)
        t[f"{path}/bias{SUFFIX}"] = arr(c_out)

    c_prev = 3
    for k in range(levels):
        c = ENCODER_CHANNELS[k]
        conv(f"{enc}/conv_layers_s1/{k}", c_prev, c)
        conv(f"{enc}/conv_layers_s2/{k}", c, c)
        c_prev = c
    if dinl:
        t[f"{enc}/dn_layers/0/scale{SUFFIX}"] = arr(1, 1, 1, 16)
        t[f"{enc}/dn_layers/0/bias{SUFFIX}"] = arr(1, 1, 1, 16)

    def refiner(path, name, est, c_in, c_out):
        chans = (c_in, *REFINER, c_out)
        for k in range(3):
            conv(f"{path}/{name}/prep_conv_layers/{k}", chans[k], chans[k + 1])
        for k in range(4):
            conv(f"{path}/{name}/{est}/{k}", chans[3 + k], chans[4 + k])

    for j in range(levels):
        if depth:
            c_in = depth_refiner_inputs(j + 1, sncv, time_recurrence, level_memory, subdivision)
            refiner(f"{dec_d}/levels/{j}", "disp_refiner", "est_d_conv_layers", c_in, 5)
        if semantic:
            refiner(
                f"{dec_s}/levels/{j}",
                "semantic_refiner",
                "est_s_conv_layers",
                classes + 4 + ENCODER_CHANNELS[j] + semantic_extra,
                classes + 4,
            )
    if extras:
        for key in list(t)[:2]:
            var = key[: -len(SUFFIX)]
            for slot in ("m", "v"):
                t[f"{var}/.OPTIMIZER_SLOT/optimizer/{slot}{SUFFIX}"] = np.zeros_like(t[key])
        t[f"optimizer/iter{SUFFIX}"] = np.array(7, np.int64)
        t[f"optimizer/learning_rate{SUFFIX}"] = np.array(1e-4, np.float32)
        t[f"step_counter{SUFFIX}"] = np.array(7, np.int64)
        t[f"save_counter{SUFFIX}"] = np.array(1, np.int64)
        t[f"depth_metrics/0/total{SUFFIX}"] = np.array(0.0, np.float32)
        t[f"semantic_metrics/0/total_confusion_matrix{SUFFIX}"] = np.zeros((classes, classes), np.float32)
        if depth:
            t[f"{dec_d}/levels/0/depth_prev_f_maps{SUFFIX}"] = np.zeros((1, 4, 4, 16), np.float32)
            t[f"{dec_d}/levels/0/prev_f_maps{SUFFIX}"] = np.zeros((1, 4, 4, 16), np.float32)
            t[f"{dec_d}/levels/0/depth_prev_t{SUFFIX}"] = np.zeros((1, 4, 4, 1), np.float32)
        if semantic:
            t[f"{dec_s}/levels/0/semantic_prev_t{SUFFIX}"] = np.zeros((1, 4, 4, classes), np.float32)
        t["_CHECKPOINTABLE_OBJECT_GRAPH"] = b"\x0a\x00not a real object graph"
    return t


def refiner_params(c_in: int, c_out: int) -> int:
    """Design 5.5.6: ``P(C_in, C_out) = 1152·C_in + 336,848 + 145·C_out``."""
    return 1152 * c_in + 336_848 + 145 * c_out
