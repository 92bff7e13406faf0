"""Test support (not part of the package): tfref fixtures in their compact form: the checkpoint's data shard stored without its seeded weights.

A tfref fixture (``reference.npz``, ``weights.json``, ``meta.json`` and a TensorFlow checkpoint in ``ckpt/``, written
by the harness ``make_reference.py`` of ``../shared/tools/tfref``) draws every trainable weight from a seeded rule of
its checkpoint key (:func:`seeded_weight`). Those bytes are most of the data shard (20 MB for 5 levels) and follow
from the seed, so the compact form keeps every file of the fixture but the shard, and of the shard:

* ``shard.json``: its path, size and SHA-256, the seed and bias deviation of the rule, and its layout, one piece per
  checkpoint entry in file order: ``[key, offset, size, "rule", shape]`` (float32 bytes the rule gives) or
  ``[key, offset, size, "stored"]`` (the next ``size`` bytes of ``shard_stored.bin``: counters, metrics, the object
  graph, any weight that does not follow the rule; a gap between entries has the key ``null``);
* ``shard_stored.bin``: those stored bytes, in file order.

:func:`rebuild_fixture` writes the whole fixture back and checks the shard against the SHA-256 of the one TensorFlow
wrote, so a test reads exactly TensorFlow's bytes. :func:`open_fixture` gives a usable folder for either form.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import zlib
from pathlib import Path

import numpy as np

from cosemdepth.errors import CheckpointError
from cosemdepth.output_safety.atomic import atomic_open, atomic_write_bytes, atomic_write_text

LAYOUT = "shard.json"
STORED = "shard_stored.bin"
#: the truncated normal's standard deviation for a unit normal cut at 2 sigma: the rule divides by it
TRUNCATED_STD = 0.87962566103423978


def seeded_weight(key: str, shape: tuple[int, ...], seed: int, bias_std: float) -> np.ndarray:
    """The harness's value of one trainable variable, from its checkpoint key alone (float32, ``shape``).

    numpy's generator seeded with ``[seed, crc32(key)]``; convolution kernels ``[kh, kw, C_in, C_out]`` He-normal
    truncated at 2 sigma (out-of-range draws redrawn until in range, then scaled by ``sqrt(2 / fan_in) / 0.8796``),
    convolution biases ``N(0, bias_std)``, the DINL scales ``1 + N(0, 0.1)`` and biases ``N(0, 0.1)``.
    """
    rng = np.random.default_rng([seed, zlib.crc32(key.encode())])
    leaf = key.split("/.ATTRIBUTES")[0].rsplit("/", 1)[-1]
    if leaf == "kernel":
        z = rng.standard_normal(shape)
        out = np.abs(z) > 2.0
        while out.any():
            z[out] = rng.standard_normal(int(out.sum()))
            out = np.abs(z) > 2.0
        return (z * (math.sqrt(2.0 / int(np.prod(shape[:-1]))) / TRUNCATED_STD)).astype(np.float32)
    if leaf == "bias":
        return ((0.1 if "dn_layers" in key else bias_std) * rng.standard_normal(shape)).astype(np.float32)
    if leaf == "scale":
        return (1.0 + 0.1 * rng.standard_normal(shape)).astype(np.float32)
    raise ValueError(f"no seeded rule for {key}")


def _shard_of(fixture: Path) -> Path:
    shards = sorted((fixture / "ckpt").glob("*.data-*-of-*"))
    if len(shards) != 1 or not shards[0].name.endswith("-00000-of-00001"):
        raise CheckpointError(f"{fixture / 'ckpt'}: expected one checkpoint data shard, found {len(shards)}")
    return shards[0]


def compact_fixture(src: str | Path, dst: str | Path) -> dict:
    """Write the compact form of the full fixture ``src`` into ``dst`` (created; must not hold a fixture yet).

    Returns the layout written to ``shard.json``.
    """
    from cosemdepth.checkpoints.tf_checkpoint import list_entries

    src, dst = Path(src), Path(dst)
    if dst.exists() and any(dst.iterdir()):
        raise FileExistsError(f"{dst}: not empty")
    config = json.loads((src / "meta.json").read_text())["config"]
    seed, bias_std = int(config["seed"]), float(config["bias_std"])
    trainable = {
        v["checkpoint_key"] for v in json.loads((src / "weights.json").read_text())["variables"] if v["trainable"]
    }
    shard = _shard_of(src)
    data = shard.read_bytes()
    pieces, stored, pos = [], bytearray(), 0
    for e in sorted(list_entries(shard.parent), key=lambda e: e.offset):
        if e.size == 0:
            continue
        if e.offset > pos:  # a gap between entries: kept as it is
            pieces.append([None, pos, e.offset - pos, "stored"])
            stored += data[pos : e.offset]
        raw = data[e.offset : e.offset + e.size]
        if (
            e.key in trainable
            and e.dtype == "float32"
            and seeded_weight(e.key, e.shape, seed, bias_std).tobytes() == raw
        ):
            pieces.append([e.key, e.offset, e.size, "rule", list(e.shape)])
        else:
            pieces.append([e.key, e.offset, e.size, "stored"])
            stored += raw
        pos = e.offset + e.size
    if pos < len(data):
        pieces.append([None, pos, len(data) - pos, "stored"])
        stored += data[pos:]
    layout = {
        "shard": shard.relative_to(src).as_posix(),
        "size": len(data),
        "sha256": hashlib.sha256(data).hexdigest(),
        "seed": seed,
        "bias_std": bias_std,
        "pieces": pieces,
    }
    for f in sorted(src.rglob("*")):
        if f.is_file() and f != shard:
            target = dst / f.relative_to(src)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(f, target)
    atomic_write_bytes(dst / STORED, bytes(stored))
    head = ",\n".join(f" {json.dumps(k)}: {json.dumps(v)}" for k, v in layout.items() if k != "pieces")
    body = ",\n".join(f"  {json.dumps(p)}" for p in pieces)  # one piece a line
    atomic_write_text(dst / LAYOUT, f'{{\n{head},\n "pieces": [\n{body}\n ]\n}}\n')
    return layout


def rebuild_fixture(src: str | Path, dst: str | Path) -> Path:
    """Write the full fixture of the compact fixture ``src`` into ``dst`` (created) and return ``dst``.

    Raises :class:`CheckpointError` when the rebuilt data shard is not, byte for byte, the one TensorFlow wrote
    (its size and SHA-256 in ``shard.json``).
    """
    src, dst = Path(src), Path(dst)
    layout = json.loads((src / LAYOUT).read_text())
    stored = (src / STORED).read_bytes()
    for f in sorted(src.rglob("*")):
        if f.is_file() and f.name not in (LAYOUT, STORED):
            target = dst / f.relative_to(src)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(f, target)
    shard = dst / layout["shard"]
    digest, pos, used = hashlib.sha256(), 0, 0
    with atomic_open(shard, "wb") as out:
        for key, offset, size, source, *shape in layout["pieces"]:
            if offset != pos:
                raise CheckpointError(f"{src / LAYOUT}: piece {key} at offset {offset}, expected {pos}")
            if source == "rule":
                raw = seeded_weight(key, tuple(shape[0]), layout["seed"], layout["bias_std"]).tobytes()
            else:
                raw, used = stored[used : used + size], used + size
            if len(raw) != size:
                raise CheckpointError(f"{src / LAYOUT}: piece {key} has {len(raw)} bytes, expected {size}")
            out.write(raw)
            digest.update(raw)
            pos += size
        if pos != layout["size"] or used != len(stored) or digest.hexdigest() != layout["sha256"]:
            raise CheckpointError(
                f"{src}: the rebuilt {layout['shard']} is not the one TensorFlow wrote ({pos} bytes, SHA-256 "
                f"{digest.hexdigest()}; expected {layout['size']} bytes, {layout['sha256']})"
            )
    return dst


def open_fixture(path: str | Path, scratch: str | Path) -> Path:
    """A folder holding the whole fixture: ``path`` itself for a full fixture, else its rebuild in
    ``scratch/<name>`` (made once; ``scratch`` is the caller's temporary folder)."""
    path = Path(path)
    if not (path / LAYOUT).is_file():
        return path
    out = Path(scratch) / path.name
    shard = json.loads((path / LAYOUT).read_text())["shard"]
    if not (out / shard).is_file():  # written last, and only when it checks out
        rebuild_fixture(path, out)
    return out
