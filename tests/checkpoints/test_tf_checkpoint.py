"""TensorFlow checkpoint reader: CRC32C, the real TF fixture, round trips through the test writer, corrupt files."""

from __future__ import annotations

import json
import zlib
from pathlib import Path

import numpy as np
import pytest
from tf_bundle_writer import BFloat16, table_bytes, write_bundle

from cosemdepth.checkpoints.crc32c import crc32c, mask_crc, masked_crc32c, unmask_crc
from cosemdepth.checkpoints.tf_checkpoint import (
    CheckpointReader,
    is_tf_checkpoint,
    list_entries,
    read_checkpoint,
    resolve_checkpoint,
)
from cosemdepth.errors import CheckpointError

# ------------------------------------------------------------------------------------------------------------------
# CRC32C


def _crc32c_bitwise(data: bytes) -> int:
    """Textbook bit-at-a-time CRC32C (reflected polynomial 0x82F63B78)."""
    crc = 0xFFFFFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ (0x82F63B78 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


@pytest.mark.parametrize(
    "data, expected",
    [
        (b"", 0x00000000),
        (b"123456789", 0xE3069283),  # the CRC catalogue's check value
        (bytes(32), 0x8A9136AA),  # RFC 3720 B.4 test vectors
        (b"\xff" * 32, 0x62A8AB43),
        (bytes(range(32)), 0x46DD794E),
        (bytes(range(31, -1, -1)), 0x113FDB5C),
    ],
)
def test_crc32c_known_vectors(data, expected):
    assert crc32c(data) == expected


@pytest.mark.parametrize("n", [1, 3, 4, 5, 4095, 4096, 4097, 5000, 12_345, 40_000])
def test_crc32c_matches_bitwise_reference(n):
    data = np.random.default_rng(n).integers(0, 256, n, dtype=np.uint8).tobytes()
    assert crc32c(data) == _crc32c_bitwise(data)
    assert crc32c(np.frombuffer(data, np.uint8)) == _crc32c_bitwise(data)


def test_crc32c_large_buffer_and_extend():
    """A few MB at once agree with chaining small pieces, and memoryview slices are accepted."""
    data = np.random.default_rng(1).integers(0, 256, 3_000_017, dtype=np.uint8).tobytes()
    chained = 0
    for i in range(0, len(data), 4000):  # pieces under the vectorised threshold
        chained = crc32c(data[i : i + 4000], chained)
    assert crc32c(data) == chained
    cut = 1_234_567
    assert crc32c(data[cut:], crc32c(data[:cut])) == chained
    view = memoryview(data)
    assert crc32c(view[cut:], crc32c(view[:cut])) == chained


def test_crc_mask_round_trip_and_formula():
    for c in (0, 1, 0xE3069283, 0xFFFFFFFF, 0x80000000):
        m = mask_crc(c)
        assert m == ((((c >> 15) | (c << 17)) & 0xFFFFFFFF) + 0xA282EAD8) & 0xFFFFFFFF
        assert unmask_crc(m) == c
    assert masked_crc32c(b"123456789") == mask_crc(0xE3069283)


# ------------------------------------------------------------------------------------------------------------------
# The checkpoint written by the authors' TensorFlow code

ENC_KERNEL = "encoder/conv_layers_s1/0/kernel/.ATTRIBUTES/VARIABLE_VALUE"


@pytest.fixture(scope="module")
def tf_fixture(tfref_dir):
    weights = json.loads((tfref_dir / "weights.json").read_text())
    reader = CheckpointReader(tfref_dir / "ckpt")
    return reader, reader.read_all(), weights


def test_fixture_index(tf_fixture, tfref_dir):
    reader, _, weights = tf_fixture
    assert reader.prefix == tfref_dir / "ckpt" / "cp-0000.ckpt"
    assert reader.num_shards == 1
    assert len(reader) == 181
    e = reader.entries[ENC_KERNEL]
    assert (e.dtype, e.shape, e.shard_id) == ("float32", (3, 3, 3, 16), 0)
    listed = {x["key"]: (tuple(x["shape"]), x["dtype"]) for x in weights["checkpoint_file_keys"]}
    assert {k: (e.shape, e.dtype) for k, e in reader.entries.items()} == listed
    assert [e.key for e in list_entries(tfref_dir / "ckpt")] == sorted(listed)


def test_fixture_every_variable_has_listed_shape_and_dtype(tf_fixture):
    _, tensors, weights = tf_fixture
    assert len(weights["variables"]) == 178
    for v in weights["variables"]:
        a = tensors[v["checkpoint_key"]]
        assert a.shape == tuple(v["shape"]), v["checkpoint_key"]
        assert a.dtype == np.dtype(v["dtype"]), v["checkpoint_key"]
    assert "_CHECKPOINTABLE_OBJECT_GRAPH" not in tensors  # string tensors are skipped
    assert len(tensors) == 180


def test_fixture_values_are_the_documented_random_draws(tf_fixture, tfref_dir):
    """weights.json documents the generator: numpy default_rng([seed, crc32(key)]), biases N(0, bias_std), DINL
    scale 1 + N(0, 0.1), DINL bias N(0, 0.1), kernels He truncated normal with out-of-range draws redrawn (seed and
    bias_std from meta.json). Regenerating them independently checks that the reader returns the bytes TensorFlow
    wrote, in the right order."""
    _, tensors, weights = tf_fixture
    config = json.loads((tfref_dir / "meta.json").read_text())["config"]
    seed, bias_std = config["seed"], config["bias_std"]
    for v in weights["variables"]:
        if not v["trainable"]:
            continue
        key, shape = v["checkpoint_key"], tuple(v["shape"])
        rng = np.random.default_rng([seed, zlib.crc32(key.encode())])
        got = tensors[key]
        if "/dn_layers/0/scale/" in key:
            np.testing.assert_array_equal(got, (1 + rng.normal(0, 0.1, shape)).astype(np.float32))
        elif "/dn_layers/0/bias/" in key:
            np.testing.assert_array_equal(got, rng.normal(0, 0.1, shape).astype(np.float32))
        elif key.endswith("/bias/.ATTRIBUTES/VARIABLE_VALUE"):
            np.testing.assert_array_equal(got, rng.normal(0, bias_std, shape).astype(np.float32))
        else:
            std = np.sqrt(2.0 / (9 * shape[2])) / 0.87962566103423978
            z = rng.standard_normal(shape)
            keep = np.abs(z) <= 2  # the first draws that were in range are kept as drawn
            np.testing.assert_array_equal(got[keep], (z * std).astype(np.float32)[keep])
            assert np.all(np.abs(got) <= 2 * std * (1 + 1e-6))


def test_fixture_all_crcs_including_string_tensor(tf_fixture):
    reader, _, _ = tf_fixture
    reader.verify()
    (graph,) = reader.read_strings("_CHECKPOINTABLE_OBJECT_GRAPH")
    assert len(graph) == reader.entries["_CHECKPOINTABLE_OBJECT_GRAPH"].size - 3 - 4  # 3-byte varint + length CRC


def test_fixture_non_weight_entries(tf_fixture):
    _, tensors, _ = tf_fixture
    assert tensors["step_counter/.ATTRIBUTES/VARIABLE_VALUE"].dtype == np.int64
    assert tensors["semantic_metrics/0/total_confusion_matrix/.ATTRIBUTES/VARIABLE_VALUE"].shape == (7, 7)


def test_resolve_checkpoint_forms(tfref_dir):
    prefix = tfref_dir / "ckpt" / "cp-0000.ckpt"
    assert resolve_checkpoint(tfref_dir / "ckpt") == prefix
    assert resolve_checkpoint(prefix) == prefix
    assert resolve_checkpoint(f"{prefix}.index") == prefix
    assert resolve_checkpoint(f"{prefix}.data-00000-of-00001") == prefix
    assert is_tf_checkpoint(tfref_dir / "ckpt") and is_tf_checkpoint(prefix)
    assert not is_tf_checkpoint(tfref_dir)


# ------------------------------------------------------------------------------------------------------------------
# Round trips through the test writer


def _sample_tensors() -> dict[str, object]:
    rng = np.random.default_rng(0)
    return {
        "a/kernel": rng.standard_normal((3, 3, 5, 7)).astype(np.float32),
        "a/bias": rng.standard_normal(7).astype(np.float32),
        "b/f64": rng.standard_normal((2, 3)),
        "b/f16": rng.standard_normal(9).astype(np.float16),
        "b/i32": rng.integers(-1000, 1000, (4, 4)).astype(np.int32),
        "b/i64": np.array(-(2**40), np.int64),
        "b/u8": np.arange(10, dtype=np.uint8),
        "b/bool": np.array([True, False, True]),
        "b/empty": np.zeros((0, 3), np.float32),
        "c/bf16": BFloat16(np.array([1.0, -2.5, 3.140625, 0.0], np.float32)),
        "d/strings": [b"alpha", b"", b"gamma\x00delta"],
        "d/scalar_string": b"object graph bytes",
    }


def test_round_trip_dtypes_strings_and_scalars(tmp_path):
    t = _sample_tensors()
    prefix = write_bundle(tmp_path / "ck" / "model.ckpt", t)
    r = CheckpointReader(prefix)
    assert sorted(r.keys()) == sorted(t)
    got = r.read_all()
    assert "d/strings" not in got and "d/scalar_string" not in got
    for k, v in t.items():
        if isinstance(v, BFloat16):
            np.testing.assert_array_equal(got[k], v.values)
            assert got[k].dtype == np.float32
        elif isinstance(v, np.ndarray):
            assert got[k].dtype == v.dtype and got[k].shape == v.shape, k
            np.testing.assert_array_equal(got[k], v)
    assert r.entries["d/strings"].dtype == "string"
    assert r.read_strings("d/strings") == t["d/strings"]
    assert r.read_strings("d/scalar_string") == [t["d/scalar_string"]]
    r.verify()
    assert resolve_checkpoint(tmp_path / "ck") == prefix


def test_round_trip_many_blocks_and_prefix_compression(tmp_path):
    """600 keys sharing long prefixes, in blocks of ~2 kB (many data blocks, restarts every 4 entries)."""
    t = {f"model/levels/{i:04d}/refiner/conv/kernel": np.full((2,), i, np.float32) for i in range(600)}
    prefix = write_bundle(tmp_path / "m.ckpt", t, block_size=2000, restart_interval=4)
    index = Path(f"{prefix}.index").read_bytes()
    # Keys are prefix-compressed: the full key only appears at restart points and in the index block.
    assert 150 + 10 <= index.count(b"model/levels/") < 250  # 150 restarts + one index key per block (>10)
    got = read_checkpoint(prefix)
    assert list(got) == sorted(t)
    for k, v in t.items():
        np.testing.assert_array_equal(got[k], v)


def test_round_trip_multiple_shards(tmp_path):
    t = {f"v{i}": np.arange(i + 1, dtype=np.float32) * i for i in range(10)}
    prefix = write_bundle(tmp_path / "s.ckpt", t, num_shards=3)
    r = CheckpointReader(prefix)
    assert r.num_shards == 3
    assert {e.shard_id for e in r.entries.values()} == {0, 1, 2}
    got = r.read_all()
    for k, v in t.items():
        np.testing.assert_array_equal(got[k], v)


def test_checkpoint_file_with_absolute_and_escaped_paths(tmp_path):
    """TensorFlow writes the state file in protobuf text format: quotes and backslashes escaped, non-ASCII bytes
    as octal escapes."""
    prefix = write_bundle(tmp_path / "weights" / 'wé"ird.ckpt', {"x": np.ones(2, np.float32)}, checkpoint_file=False)
    state_dir = tmp_path / "state"
    state_dir.mkdir()
    escaped = "".join(
        {ord('"'): '\\"', ord("\\"): "\\\\"}.get(b, chr(b)) if b < 128 else f"\\{b:03o}"
        for b in str(prefix).encode("utf-8")
    )
    assert "\\303\\251" in escaped and '\\"' in escaped
    (state_dir / "checkpoint").write_text(f'model_checkpoint_path: "{escaped}"\n', encoding="ascii")
    assert resolve_checkpoint(state_dir) == prefix


# ------------------------------------------------------------------------------------------------------------------
# Bad input: each is a CheckpointError naming the file and the problem


@pytest.fixture()
def small_ckpt(tmp_path):
    t = {"layer/kernel": np.arange(3000, dtype=np.float32).reshape(10, 300), "layer/bias": np.ones(10, np.float32)}
    return write_bundle(tmp_path / "ck" / "cp-0001.ckpt", t)


def _data(prefix: Path, shard: int = 0, n: int = 1) -> Path:
    return Path(f"{prefix}.data-{shard:05d}-of-{n:05d}")


def test_flipped_byte_in_data_is_a_crc_error_naming_the_file(small_ckpt):
    data = _data(small_ckpt)
    raw = bytearray(data.read_bytes())
    raw[100] ^= 0x01
    data.write_bytes(bytes(raw))
    r = CheckpointReader(small_ckpt)  # the index is fine
    with pytest.raises(CheckpointError, match="CRC32C mismatch") as e:
        r.read_all()
    assert str(data) in str(e.value)
    assert "layer/" in str(e.value)


def test_truncated_data_shard(small_ckpt):
    data = _data(small_ckpt)
    data.write_bytes(data.read_bytes()[:5000])
    with pytest.raises(CheckpointError, match="truncated data shard") as e:
        read_checkpoint(small_ckpt)
    assert str(data) in str(e.value)


def test_missing_data_shard(tmp_path):
    t = {"a": np.ones(3, np.float32), "b": np.zeros(2, np.float32)}
    prefix = write_bundle(tmp_path / "m.ckpt", t, num_shards=2)
    missing = _data(prefix, 1, 2)
    missing.unlink()
    with pytest.raises(CheckpointError, match="data shard of the checkpoint not found") as e:
        read_checkpoint(prefix)
    assert str(missing) in str(e.value)


def test_truncated_index_has_bad_magic(small_ckpt):
    index = Path(f"{small_ckpt}.index")
    index.write_bytes(index.read_bytes()[:-10])
    with pytest.raises(CheckpointError, match="bad magic number") as e:
        CheckpointReader(small_ckpt)
    assert str(index) in str(e.value)


def test_tiny_index(small_ckpt):
    index = Path(f"{small_ckpt}.index")
    index.write_bytes(b"short")
    with pytest.raises(CheckpointError, match="too short") as e:
        CheckpointReader(small_ckpt)
    assert str(index) in str(e.value)


def test_foreign_index_file(tmp_path):
    prefix = tmp_path / "foreign.ckpt"
    Path(f"{prefix}.index").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    with pytest.raises(CheckpointError, match="not a TensorFlow checkpoint index"):
        CheckpointReader(prefix)


def test_flipped_byte_in_index_block(small_ckpt):
    index = Path(f"{small_ckpt}.index")
    raw = bytearray(index.read_bytes())
    raw[10] ^= 0x40  # inside the first data block
    index.write_bytes(bytes(raw))
    with pytest.raises(CheckpointError, match="CRC32C mismatch in data block") as e:
        CheckpointReader(small_ckpt)
    assert str(index) in str(e.value)


def test_compressed_block_is_rejected(tmp_path):
    prefix = write_bundle(tmp_path / "c.ckpt", {"a": np.ones(2, np.float32)}, compression=1)
    with pytest.raises(CheckpointError, match=r"compressed \(type 1\)"):
        CheckpointReader(prefix)


def test_big_endian_bundle_is_rejected(tmp_path):
    prefix = write_bundle(tmp_path / "be.ckpt", {"a": np.ones(2, np.float32)}, endianness=1)
    with pytest.raises(CheckpointError, match="big-endian"):
        CheckpointReader(prefix)


def test_newer_bundle_version_is_rejected(tmp_path):
    prefix = write_bundle(tmp_path / "v.ckpt", {"a": np.ones(2, np.float32)}, min_consumer=2)
    with pytest.raises(CheckpointError, match="version 2"):
        CheckpointReader(prefix)


def test_table_without_bundle_header(tmp_path):
    prefix = tmp_path / "nohdr.ckpt"
    Path(f"{prefix}.index").write_bytes(table_bytes([(b"key", b"\x08\x01")]))
    with pytest.raises(CheckpointError, match="no bundle header"):
        CheckpointReader(prefix)


def test_size_not_matching_shape(tmp_path):
    prefix = write_bundle(tmp_path / "s.ckpt", {"a": np.ones(4, np.float32)})
    # Rewrite the index claiming shape [5] for the same 16 bytes.
    from tf_bundle_writer import entry_proto, header_proto

    data = _data(prefix).read_bytes()
    entries = [(b"", header_proto(1)), (b"a", entry_proto(1, [5], 0, 0, 16, masked_crc32c(data)))]
    Path(f"{prefix}.index").write_bytes(table_bytes(entries))
    with pytest.raises(CheckpointError, match="should take 20 bytes"):
        read_checkpoint(prefix)


def test_folder_without_checkpoint_file(tmp_path, small_ckpt):
    folder = small_ckpt.parent
    (folder / "checkpoint").unlink()
    with pytest.raises(CheckpointError, match="no 'checkpoint' file") as e:
        resolve_checkpoint(folder)
    assert str(folder) in str(e.value) and "cp-0001.ckpt" in str(e.value)  # names the prefix to use instead
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(CheckpointError, match="no 'checkpoint' file"):
        CheckpointReader(empty)


def test_checkpoint_file_naming_a_missing_prefix(small_ckpt):
    state = small_ckpt.parent / "checkpoint"
    state.write_text('model_checkpoint_path: "cp-0099.ckpt"\n')
    with pytest.raises(CheckpointError, match=r"cp-0099\.ckpt\.index does not exist") as e:
        resolve_checkpoint(small_ckpt.parent)
    assert str(state) in str(e.value)


def test_checkpoint_file_without_path_line(small_ckpt):
    state = small_ckpt.parent / "checkpoint"
    state.write_text("garbage\n")
    with pytest.raises(CheckpointError, match="model_checkpoint_path"):
        resolve_checkpoint(small_ckpt.parent)


def test_missing_checkpoint_paths(tmp_path):
    with pytest.raises(CheckpointError, match="does not exist"):
        resolve_checkpoint(tmp_path / "nowhere" / "cp-0000.ckpt")
    with pytest.raises(CheckpointError, match=r"\.index not found"):
        resolve_checkpoint(tmp_path / "cp-0000.ckpt")
    assert not is_tf_checkpoint(tmp_path / "cp-0000.ckpt")


def test_unknown_key_and_non_numeric_read(small_ckpt, tmp_path):
    r = CheckpointReader(small_ckpt)
    with pytest.raises(CheckpointError, match="no entry 'nope'"):
        r.read("nope")
    p = write_bundle(tmp_path / "str.ckpt", {"s": [b"x"]})
    with pytest.raises(CheckpointError, match="string tensor, not a numeric one"):
        CheckpointReader(p).read("s")


def test_corrupt_string_tensor(tmp_path):
    p = write_bundle(tmp_path / "str.ckpt", {"s": [b"hello", b"world"]})
    data = _data(p)
    raw = bytearray(data.read_bytes())
    raw[-1] ^= 0x20
    data.write_bytes(bytes(raw))
    with pytest.raises(CheckpointError, match="CRC32C mismatch for tensor 's'"):
        CheckpointReader(p).verify()


def test_reader_does_not_need_tensorflow():
    import sys

    import cosemdepth.checkpoints.tf_checkpoint  # noqa: F401

    assert "tensorflow" not in sys.modules
