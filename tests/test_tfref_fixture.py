"""The compact form of a tfref fixture: the checkpoint's data shard without its seeded weights, rebuilt exactly."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from tf_bundle_writer import write_bundle
from tfref_fixture import (
    LAYOUT,
    STORED,
    compact_fixture,
    open_fixture,
    rebuild_fixture,
    seeded_weight,
)

from cosemdepth.checkpoints.tf_checkpoint import CheckpointReader
from cosemdepth.errors import CheckpointError

IN_REPO = Path(__file__).resolve().parent / "fixtures" / "tfref-64x96"
SHARD = "cp-0000.ckpt.data-00000-of-00001"


def test_the_in_repository_fixture_is_small_and_compact():
    files = [f for f in IN_REPO.rglob("*") if f.is_file()]
    assert sum(f.stat().st_size for f in files) <= 8 * 2**20
    assert not (IN_REPO / "ckpt" / SHARD).exists()
    assert {"README.md", "reference.npz", "weights.json", "meta.json", LAYOUT, STORED} <= {f.name for f in files}


def test_rebuilt_shard_passes_tensorflows_own_checksums(tmp_path):
    """The index TensorFlow wrote holds a CRC32C of every tensor: the rebuilt shard matches all of them."""
    out = rebuild_fixture(IN_REPO, tmp_path / "full")
    reader = CheckpointReader(out / "ckpt")
    reader.verify()
    layout = json.loads((IN_REPO / LAYOUT).read_text())
    data = (out / "ckpt" / SHARD).read_bytes()
    assert len(data) == layout["size"] and hashlib.sha256(data).hexdigest() == layout["sha256"]
    # nearly all of it comes from the rule: the 162 trainable tensors of the 5-level model
    rule = [p for p in layout["pieces"] if p[3] == "rule"]
    assert len(rule) == 162 and sum(p[2] for p in rule) == 4 * 5_202_528


@pytest.mark.parametrize("damage", ["stored byte", "seed", "bias_std", "size"])
def test_a_damaged_compact_fixture_is_refused(tmp_path, damage):
    src = tmp_path / "compact"
    shutil.copytree(IN_REPO, src)
    layout = json.loads((src / LAYOUT).read_text())
    if damage == "stored byte":
        stored = bytearray((src / STORED).read_bytes())
        stored[100] ^= 1
        (src / STORED).write_bytes(bytes(stored))
    elif damage == "size":
        layout["pieces"][-1][2] += 1
    else:
        layout[damage] = layout[damage] + 1
    (src / LAYOUT).write_text(json.dumps(layout))
    with pytest.raises(CheckpointError, match=r"not the one TensorFlow wrote|bytes, expected"):
        rebuild_fixture(src, tmp_path / "full")
    assert not (tmp_path / "full" / "ckpt" / SHARD).exists()  # nothing half-written


def _full_fixture(folder: Path) -> dict[str, object]:
    """A small checkpoint of our own writer: three weights by the rule (seed 4, biases N(0, 0.02)), one that is not,
    counters and a string tensor."""
    rule = {
        "enc/conv/0/kernel/.ATTRIBUTES/VARIABLE_VALUE": (3, 3, 2, 4),
        "enc/conv/0/bias/.ATTRIBUTES/VARIABLE_VALUE": (4,),
        "enc/dn_layers/0/scale/.ATTRIBUTES/VARIABLE_VALUE": (1, 1, 1, 4),
    }
    tensors: dict[str, object] = {k: seeded_weight(k, s, 4, 0.02) for k, s in rule.items()}
    tensors["enc/conv/1/kernel/.ATTRIBUTES/VARIABLE_VALUE"] = np.full((1, 1, 4, 2), 0.5, np.float32)  # trained
    tensors["step_counter/.ATTRIBUTES/VARIABLE_VALUE"] = np.array(7, np.int64)
    tensors["_CHECKPOINTABLE_OBJECT_GRAPH"] = b"an object graph"
    write_bundle(folder / "ckpt" / "cp-0000.ckpt", tensors)
    trainable = [*rule, "enc/conv/1/kernel/.ATTRIBUTES/VARIABLE_VALUE"]
    (folder / "weights.json").write_text(
        json.dumps({"variables": [{"checkpoint_key": k, "trainable": True} for k in trainable]})
    )
    (folder / "meta.json").write_text(json.dumps({"config": {"seed": 4, "bias_std": 0.02}}))
    np.savez(folder / "reference.npz", rgb=np.zeros((1, 1, 2, 2, 3), np.float32))
    return tensors


def test_compact_and_rebuild_round_trip(tmp_path):
    _full_fixture(tmp_path / "full")
    layout = compact_fixture(tmp_path / "full", tmp_path / "compact")
    assert [p[0] for p in layout["pieces"] if p[3] == "rule"] == sorted(
        [
            "enc/conv/0/kernel/.ATTRIBUTES/VARIABLE_VALUE",
            "enc/conv/0/bias/.ATTRIBUTES/VARIABLE_VALUE",
            "enc/dn_layers/0/scale/.ATTRIBUTES/VARIABLE_VALUE",
        ]
    )
    stored = (tmp_path / "compact" / STORED).read_bytes()
    assert b"an object graph" in stored and np.float32(0.5).tobytes() * 8 in stored
    assert not (tmp_path / "compact" / "ckpt" / SHARD).exists()
    rebuilt = rebuild_fixture(tmp_path / "compact", tmp_path / "again")
    for f in sorted((tmp_path / "full").rglob("*")):
        if f.is_file():
            assert (rebuilt / f.relative_to(tmp_path / "full")).read_bytes() == f.read_bytes(), f
    assert not (rebuilt / LAYOUT).exists() and not (rebuilt / STORED).exists()
    with pytest.raises(FileExistsError):
        compact_fixture(tmp_path / "full", tmp_path / "compact")


def test_open_fixture_rebuilds_once_and_leaves_a_full_fixture_alone(tmp_path):
    _full_fixture(tmp_path / "full")
    compact_fixture(tmp_path / "full", tmp_path / "compact")
    assert open_fixture(tmp_path / "full", tmp_path / "scratch") == tmp_path / "full"
    out = open_fixture(tmp_path / "compact", tmp_path / "scratch")
    assert out == tmp_path / "scratch" / "compact" and (out / "ckpt" / SHARD).is_file()
    stamp = (out / "ckpt" / SHARD).stat().st_mtime_ns
    assert open_fixture(tmp_path / "compact", tmp_path / "scratch") == out
    assert (out / "ckpt" / SHARD).stat().st_mtime_ns == stamp


def test_seeded_weight_rule():
    k = seeded_weight("a/kernel/.ATTRIBUTES/VARIABLE_VALUE", (3, 3, 8, 16), 0, 0.05)
    std = np.sqrt(2 / 72) / 0.87962566103423978
    assert k.dtype == np.float32 and k.shape == (3, 3, 8, 16) and np.abs(k).max() <= 2 * std * (1 + 1e-6)
    assert np.array_equal(k, seeded_weight("a/kernel/.ATTRIBUTES/VARIABLE_VALUE", (3, 3, 8, 16), 0, 0.05))
    assert not np.array_equal(k, seeded_weight("b/kernel/.ATTRIBUTES/VARIABLE_VALUE", (3, 3, 8, 16), 0, 0.05))
    assert not np.array_equal(k, seeded_weight("a/kernel/.ATTRIBUTES/VARIABLE_VALUE", (3, 3, 8, 16), 1, 0.05))
    scale = seeded_weight("e/dn_layers/0/scale/.ATTRIBUTES/VARIABLE_VALUE", (10000,), 0, 0.05)
    assert abs(scale.mean() - 1) < 0.01 and abs(scale.std() - 0.1) < 0.01
    with pytest.raises(ValueError, match="no seeded rule"):
        seeded_weight("x/moving_mean/.ATTRIBUTES/VARIABLE_VALUE", (3,), 0, 0.05)
