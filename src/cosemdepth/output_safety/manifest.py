"""Checksum manifests: the ``manifest.json`` a training checkpoint folder carries (sizes and SHA-256 of its files).

One mechanism for every reader of such a folder: resuming a run (:mod:`cosemdepth.training.checkpoint`) and loading
the folder as a model (:func:`cosemdepth.checkpoints.model_io.load_model`, ``--model RUN/checkpoints/ckpt-N``) both call
:func:`validate_manifest`, so a truncated or damaged file is refused with an error naming it.

:func:`file_digest` is the same SHA-256 for the output marker of :mod:`cosemdepth.output_safety.outdir`, remembered per file
state so that a check made twice in one run reads each file once.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any, Iterable

from ..errors import CheckpointError

MANIFEST_FILE = "manifest.json"
MANIFEST_FORMAT = "cosemdepth-checkpoint"
MANIFEST_VERSION = 1


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(chunk), b""):
            h.update(block)
    return h.hexdigest()


#: (device, inode, size, mtime, ctime) -> SHA-256 of files hashed by this process. Any write to a file changes its
#: ctime, which no tool can set back, so an entry never stands for other content.
_DIGESTS: dict[tuple[int, ...], str] = {}
_MAX_DIGESTS = 200_000


def file_digest(path: str | os.PathLike) -> tuple[int, str]:
    """``(size, SHA-256 hex)`` of the regular file ``path`` (symlinks followed)."""
    st = os.stat(path)
    key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
    digest = _DIGESTS.get(key)
    if digest is None:
        digest = sha256_file(Path(path))
        if len(_DIGESTS) >= _MAX_DIGESTS:
            _DIGESTS.clear()
        _DIGESTS[key] = digest
    return st.st_size, digest


def validate_manifest(path: str | os.PathLike, required: Iterable[str] = ()) -> dict[str, Any]:
    """Check the folder ``path`` against its ``manifest.json``; return the manifest.

    Raises:
        CheckpointError: no or unreadable manifest, ``required`` files not listed, a listed file missing, or a size
            or checksum mismatch.
    """
    path = Path(path)
    mpath = path / MANIFEST_FILE
    try:
        manifest = json.loads(mpath.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CheckpointError(f"{path}: incomplete checkpoint (no {MANIFEST_FILE})") from None
    except (OSError, UnicodeDecodeError, ValueError) as e:
        raise CheckpointError(f"{mpath}: unreadable manifest ({e})") from e
    if not isinstance(manifest, dict) or manifest.get("format") != MANIFEST_FORMAT:
        raise CheckpointError(f"{mpath}: not a cosemdepth checkpoint manifest")
    version = manifest.get("version", 0)
    if not isinstance(version, int) or isinstance(version, bool):
        raise CheckpointError(f"{mpath}: bad checkpoint version {version!r}")
    if version > MANIFEST_VERSION:
        raise CheckpointError(
            f"{mpath}: checkpoint version {version} is newer than this cosemdepth supports ({MANIFEST_VERSION})"
        )
    files = manifest.get("files")
    required = list(required)
    if not isinstance(files, dict) or set(required) - set(files):
        raise CheckpointError(f"{mpath}: the manifest must list {required}")
    for name, info in files.items():
        f = path / name
        if not isinstance(info, dict) or Path(name).is_absolute() or ".." in Path(name).parts:
            raise CheckpointError(f"{mpath}: bad entry for {name!r}")
        if not f.is_file():
            raise CheckpointError(f"{f}: missing (listed in the manifest)")
        size = f.stat().st_size
        if size != info.get("size"):
            raise CheckpointError(f"{f}: {size} bytes, the manifest says {info.get('size')} (truncated or changed)")
        if sha256_file(f) != info.get("sha256"):
            raise CheckpointError(f"{f}: checksum mismatch (corrupt)")
    return manifest


__all__ = ["MANIFEST_FILE", "MANIFEST_FORMAT", "MANIFEST_VERSION", "file_digest", "sha256_file", "validate_manifest"]
