"""Fuzz tests of the TensorFlow checkpoint reader (``P.index`` + ``P.data-00000-of-00001``).

Bundles come from the independent test writer (tests/tf_bundle_writer.py) and from the real TensorFlow
checkpoint of the shared fixture; they are byte-mutated (index or data shard), or their protobuf entries are
replaced by random field lists (wrong wire types, huge shapes/offsets/sizes) inside a table whose CRCs are
right, so the parsing behind the CRC checks is reached. Allowed outcomes (tests/fuzzing.py): tensors whose
shapes and dtypes match the index (equal to what was written when nothing was changed), or a CheckpointError
naming the checkpoint (its index or one of its data shards, all named after the prefix).
"""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest
from fuzzing import fuzz_settings, mutate_bytes, outcome, write
from hypothesis import given
from hypothesis import strategies as st
from tf_bundle_writer import BFloat16, entry_proto, header_proto, pb_bytes, pb_varint, table_bytes, varint, write_bundle

from cosemdepth.checkpoints.tf_checkpoint import CheckpointReader, list_entries, read_checkpoint
from cosemdepth.errors import CheckpointError

TENSORS = {
    "a/kernel": np.arange(24, dtype=np.float32).reshape(2, 3, 4) - 7.5,
    "a/bias": np.array([1.5, -2.0, np.inf], np.float32),
    "b/half": np.array([[0.5, 65504.0]], np.float16),
    "b/bf16": BFloat16(np.array([1.0, -3.0, 0.25], np.float32)),
    "c/int": np.array(7, np.int64),
    "c/flags": np.array([True, False, True]),
    "d/names": [b"x", b"", b"yz"],
}


def expected(key):
    v = TENSORS[key]
    return v.values if isinstance(v, BFloat16) else v


def read_everything(prefix):
    """What a user of the reader does: list the entries, read every numeric tensor, verify every CRC."""
    entries = list_entries(prefix)
    tensors = read_checkpoint(prefix)
    CheckpointReader(prefix).verify()
    return entries, tensors


def check_consistent(result, unchanged: bool) -> None:
    entries, tensors = result
    by_key = {e.key: e for e in entries}
    for key, arr in tensors.items():
        e = by_key[key]
        assert e.numeric and isinstance(arr, np.ndarray) and arr.shape == tuple(e.shape)
        assert arr.dtype.kind in "biufc"
    if unchanged:
        assert set(by_key) == set(TENSORS)
        for key, arr in tensors.items():
            np.testing.assert_array_equal(arr, expected(key))


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    prefix = write_bundle(tmp_path_factory.mktemp("bundle") / "ckpt", TENSORS, block_size=64, restart_interval=2)
    return prefix, open(f"{prefix}.index", "rb").read(), open(f"{prefix}.data-00000-of-00001", "rb").read()


@fuzz_settings(max_examples=120)
@given(data=st.data(), which=st.sampled_from(("index", "data")))
def test_fuzz_bundle_bytes(tmp_path_factory, bundle, data, which):
    _, index, shard = bundle
    folder = tmp_path_factory.getbasetemp() / "fuzz_tf"
    prefix = folder / "ckpt"
    new_index = data.draw(mutate_bytes(index)) if which == "index" else index
    new_shard = data.draw(mutate_bytes(shard)) if which == "data" else shard
    write(folder / "ckpt.index", new_index)
    write(folder / "ckpt.data-00000-of-00001", new_shard)
    unchanged = new_index == index and new_shard[: len(shard)] == shard
    outcome(lambda: read_everything(prefix), [prefix], lambda r: check_consistent(r, unchanged))


# --------------------------------------------------------------------------------------------------------------
# Structural fuzzing: random protobuf fields in a table with correct CRCs

HUGE = (2**31 - 1, 2**32, 2**62, 2**63 - 1, 2**63, 2**64 - 1)


@st.composite
def proto_field(draw, number=None):
    n = number if number is not None else draw(st.integers(1, 9))
    wire = draw(st.sampled_from((0, 0, 1, 2, 2, 3, 5)))
    if wire == 0:
        return varint(n << 3) + varint(draw(st.one_of(st.integers(0, 40), st.sampled_from(HUGE))))
    if wire == 1:
        return varint((n << 3) | 1) + draw(st.binary(min_size=8, max_size=8))
    if wire == 5:
        return varint((n << 3) | 5) + draw(st.binary(min_size=4, max_size=4))
    if wire == 3:
        return varint((n << 3) | 3)
    return pb_bytes(n, draw(st.one_of(st.binary(max_size=12), shape_bytes())))


@st.composite
def shape_bytes(draw):
    dims = draw(st.lists(st.one_of(st.integers(0, 5), st.sampled_from(HUGE)), max_size=4))
    return b"".join(pb_bytes(2, pb_varint(1, d)) for d in dims)


@st.composite
def entry_or_random(draw, dtype: int, shape, offset: int, size: int, crc: int):
    """A valid entry proto, the valid one with random fields appended (later fields win), or only random fields."""
    valid = entry_proto(dtype, shape, 0, offset, size, crc)
    kind = draw(st.sampled_from(("valid", "append", "append", "random")))
    extra = b"".join(draw(st.lists(proto_field(), min_size=1, max_size=4)))
    return {"valid": valid, "append": valid + extra, "random": extra}[kind]


@fuzz_settings(max_examples=120)
@given(data=st.data())
def test_fuzz_bundle_entries(tmp_path_factory, bundle, data):
    """Entries and header of random protobuf fields (wrong wire types, huge dims/offsets/sizes, unknown dtypes) in
    a well-formed table: the parsing behind the CRC checks."""
    _, _, shard = bundle
    folder = tmp_path_factory.getbasetemp() / "fuzz_tf_entries"
    write(folder / "ckpt.data-00000-of-00001", shard)
    good = CheckpointReader(bundle[0])
    entries = []
    for e in sorted(good.entries.values(), key=lambda e: e.key.encode()):
        entries.append((e.key.encode(), data.draw(entry_or_random(e.dtype_code, e.shape, e.offset, e.size, e.crc32c))))
    header = header_proto(1)
    if data.draw(st.booleans()):
        header = data.draw(st.sampled_from((header, b""))) + b"".join(data.draw(st.lists(proto_field(), max_size=3)))
    write(folder / "ckpt.index", table_bytes([(b"", header)] + entries, block_size=64, restart_interval=2))
    prefix = folder / "ckpt"
    outcome(lambda: read_everything(prefix), [prefix], lambda r: check_consistent(r, False))


def test_entry_field_of_wrong_wire_type(tmp_path):
    """Found by the fuzzer: a field of the wrong wire type (a varint where bytes are expected, bytes where a number
    is expected) raised TypeError or ValueError instead of CheckpointError."""
    for header, entry in [
        (pb_varint(1, 1) + pb_varint(3, 5), None),  # version given as a varint
        (pb_bytes(1, b"12"), None),  # shard count given as bytes
        (header_proto(1), pb_varint(1, 1) + pb_varint(2, 9)),  # shape given as a varint
        (header_proto(1), pb_varint(1, 1) + pb_bytes(3, b"\x00")),  # shard id given as bytes
        (header_proto(1), pb_bytes(1, b"\x01")),  # dtype given as bytes
        (header_proto(1), pb_varint(1, 1) + pb_bytes(2, pb_bytes(2, pb_varint(1, 2**32)) * 2)),  # 2^64 values
    ]:
        pairs = [(b"", header)] + ([(b"k", entry)] if entry is not None else [])
        write(tmp_path / "ckpt.index", table_bytes(pairs))
        write(tmp_path / "ckpt.data-00000-of-00001", b"")
        with pytest.raises(CheckpointError) as e:
            read_everything(tmp_path / "ckpt")
        assert str(tmp_path / "ckpt") in str(e.value)


# --------------------------------------------------------------------------------------------------------------
# The real checkpoint written by TensorFlow


@fuzz_settings(max_examples=25, deadline_s=20)
@given(data=st.data())
def test_fuzz_real_checkpoint_index(tfref_dir, tmp_path_factory, data):
    """The TensorFlow-written checkpoint of the fixture with a mutated index (the 20 MB data shard is linked, not
    copied; the tensors checked are the small ones, read through the mutated index)."""
    src = tfref_dir / "ckpt" / "cp-0000.ckpt"
    index = open(f"{src}.index", "rb").read()
    folder = tmp_path_factory.getbasetemp() / "fuzz_tf_real"
    folder.mkdir(exist_ok=True)
    shard = folder / "cp-0000.ckpt.data-00000-of-00001"
    if not shard.exists():
        os.symlink(f"{src}.data-00000-of-00001", shard)
    new_index = data.draw(mutate_bytes(index))
    write(folder / "cp-0000.ckpt.index", new_index)
    prefix = folder / "cp-0000.ckpt"

    def run():
        reader = CheckpointReader(prefix)
        small = sorted((e.key for e in reader.entries.values() if e.numeric and e.size <= 4096))[:20]
        return reader, reader.read_all(small)

    def check(result) -> None:
        reader, tensors = result
        for key, arr in tensors.items():
            assert arr.shape == tuple(reader.entries[key].shape)

    outcome(run, [prefix], check)


def test_real_checkpoint_truncated_everywhere(tfref_dir, tmp_path):
    """Every truncation length of the real index's tail (footer, index block) is a CheckpointError."""
    src = tfref_dir / "ckpt" / "cp-0000.ckpt"
    index = open(f"{src}.index", "rb").read()
    os.symlink(f"{src}.data-00000-of-00001", tmp_path / "cp-0000.ckpt.data-00000-of-00001")
    for cut in range(len(index) - 200, len(index)):
        write(tmp_path / "cp-0000.ckpt.index", index[:cut])
        with pytest.raises(CheckpointError) as e:
            CheckpointReader(tmp_path / "cp-0000.ckpt")
        assert "cp-0000.ckpt.index" in str(e.value)
    shutil.rmtree(tmp_path)


# --------------------------------------------------------------------------------------------------------------
# The converter behind the reader: a readable checkpoint whose tensors are not the expected ones


@st.composite
def model_variant(draw):
    """TF tensors of a small model with a few random changes: a tensor dropped, reshaped, retyped (int, float16,
    bool, string), renamed, or given an extra unexpected key."""
    from tf_bundle_writer import model_tensors

    t = model_tensors(levels=2, semantic=draw(st.booleans()), extras=False, zeros=True)
    keys = sorted(t)
    for _ in range(draw(st.integers(0, 3))):
        key = draw(st.sampled_from(keys))
        if key not in t or isinstance(t[key], list):  # dropped or already a string tensor
            continue
        op = draw(st.sampled_from(("drop", "reshape", "retype", "rename", "extra")))
        arr = np.asarray(t[key])
        if op == "drop":
            del t[key]
        elif op == "reshape":
            t[key] = np.zeros(draw(st.sampled_from(((), (1,), (arr.size,), (*arr.shape, 1), (2, 2, 2, 2)))), np.float32)
        elif op == "retype":
            kind = draw(st.sampled_from(("int32", "float16", "bool", "string")))
            t[key] = [b"x"] * max(1, min(arr.size, 3)) if kind == "string" else arr.astype(kind)
        elif op == "rename":
            t[key.replace("/0/", "/7/").replace("kernel", "kernal")] = t.pop(key)
        else:
            t[
                draw(st.sampled_from(("encoder/conv_layers_s1/9/kernel", "d_estimator/levels/0/x/bias")))
                + "/.ATTRIBUTES/VARIABLE_VALUE"
            ] = arr
    return t


@fuzz_settings(max_examples=25, deadline_s=10)
@given(tensors=model_variant())
def test_fuzz_checkpoint_conversion(tmp_path_factory, tensors):
    from cosemdepth.checkpoints.convert import expected_param_shapes, import_checkpoint

    folder = tmp_path_factory.getbasetemp() / "fuzz_convert"
    shutil.rmtree(folder, ignore_errors=True)
    prefix = write_bundle(folder / "ckpt", tensors)

    def check(conv) -> None:
        shapes = expected_param_shapes(conv.config)
        assert {k: tuple(v.shape) for k, v in conv.state_dict.items() if k in shapes} == shapes
        assert all(v.dtype.is_floating_point for k, v in conv.state_dict.items() if k in shapes)

    outcome(lambda: import_checkpoint(prefix), [prefix], check)


@fuzz_settings(max_examples=40)
@given(data=st.data())
def test_fuzz_checkpoint_state_file(tmp_path_factory, bundle, data):
    """The ``checkpoint`` text file of a checkpoint folder (which names the prefix), damaged."""
    from fuzzing import text_file_bytes

    from cosemdepth.checkpoints.tf_checkpoint import resolve_checkpoint

    folder = bundle[0].parent
    text = f'model_checkpoint_path: "{bundle[0].name}"\nall_model_checkpoint_paths: "{bundle[0].name}"\n'
    raw = data.draw(text_file_bytes(text, separators=' :"\n'))
    state = write(folder / "checkpoint", raw)

    def check(prefix) -> None:
        assert os.path.isfile(f"{prefix}.index")
        if raw == text.encode():
            assert prefix == bundle[0]

    try:
        outcome(lambda: resolve_checkpoint(folder), [state], check)
    finally:
        write(state, text.encode())


def test_checkpoint_state_naming_too_long_a_path(tmp_path):
    """Found by the fuzzer: a state file naming a prefix longer than the file system allows raised OSError."""
    from cosemdepth.checkpoints.tf_checkpoint import resolve_checkpoint

    state = write(tmp_path / "checkpoint", f'model_checkpoint_path: "{"1" * 5000}"\n'.encode())
    with pytest.raises(CheckpointError) as e:
        resolve_checkpoint(tmp_path)
    assert str(state) in str(e.value)
    with pytest.raises(CheckpointError, match="cannot access"):
        resolve_checkpoint(tmp_path / ("y" * 5000))
