"""Training checkpoints: written atomically, validated by a manifest, the newest K kept.

Layout of one checkpoint, ``RUN_DIR/checkpoints/ckpt-<step, 8 digits>/``::

    model.safetensors   the weights   } our model format (cosemdepth.checkpoints.model_io): the folder itself loads
    config.json         model config  } with ``load_model``
    optimizer.pt        optimizer state dict (torch.save; loads with ``weights_only=True``)
    rng.pt              RNG states: python, numpy, torch CPU (and CUDA)
    trainer_state.json  loop state: step, epoch, position in the epoch, best metrics, ...
    manifest.json       written last: the list of files with their sizes and SHA-256

Writing: every file goes into a temporary sibling folder ``.tmp-ckpt-<step>-<pid>``; the manifest is written last,
then the folder is renamed to its final name (an atomic rename on POSIX file systems) and the parent folder is
fsynced. A crash (even SIGKILL) at any moment leaves either a temporary folder (removed at the next start) or a
complete checkpoint. A checkpoint is *valid* when its manifest parses and every listed file exists with the listed
size and checksum, so a truncated or damaged checkpoint is detected even if it got its final name by other means
(a partial copy, a disk error). An invalid checkpoint is never deleted: it is renamed aside to
``ckpt-<step>.corrupt-<n>`` (out of the ``ckpt-*`` namespace, so never resumed from nor pruned) for the user to look
at or remove.

The environment variable ``COSEMDEPTH_DEBUG_CHECKPOINT_DELAY`` (seconds) makes the writer sleep after each file;
tests use it to kill a run while a checkpoint is being written.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import random
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import torch

from ..checkpoints.model_io import read_model_files, save_weights
from ..errors import CheckpointError
from ..models.config import ModelConfig
from ..operating_point import OperatingPoint
from ..output_safety.atomic import _fsync_dir, atomic_write_bytes, atomic_write_text
from ..output_safety.manifest import MANIFEST_FILE, MANIFEST_FORMAT, MANIFEST_VERSION, sha256_file, validate_manifest

STATE_FILE = "trainer_state.json"
OPTIMIZER_FILE = "optimizer.pt"
RNG_FILE = "rng.pt"
WEIGHTS_FILE = "model.safetensors"
CONFIG_FILE = "config.json"
REQUIRED_FILES = (WEIGHTS_FILE, CONFIG_FILE, OPTIMIZER_FILE, RNG_FILE, STATE_FILE)
DELAY_ENV = "COSEMDEPTH_DEBUG_CHECKPOINT_DELAY"

_NAME = re.compile(r"^ckpt-(\d{8,})$")
_ASIDE = re.compile(r"^ckpt-(\d{8,})\.corrupt-\d+$")


def checkpoint_name(step: int) -> str:
    return f"ckpt-{step:08d}"


def _torch_bytes(obj) -> bytes:
    """``torch.save(obj)`` in memory: written by Python, a failed write (a full disk) is an OSError naming the file
    (torch's own writer reports it as an internal assertion)."""
    buf = io.BytesIO()
    torch.save(obj, buf)
    return buf.getvalue()


def _debug_delay() -> None:
    value = os.environ.get(DELAY_ENV)
    if value:
        time.sleep(float(value))


# ---------------------------------------------------------------------------------------------------------------
# Model weights: our model format (cosemdepth.checkpoints.model_io), so that every checkpoint is also a loadable model folder.
# ---------------------------------------------------------------------------------------------------------------


def save_model_files(
    state_dict: Mapping[str, torch.Tensor],
    config: ModelConfig,
    folder: Path,
    source: Mapping[str, Any],
    operating_point: OperatingPoint | None = None,
) -> None:
    """Write ``model.safetensors`` + ``config.json`` (with the run's ``operating_point``) into ``folder`` (our model
    format)."""
    save_weights(state_dict, config, folder, source=source, operating_point=operating_point)


def read_model_state(folder: Path) -> dict[str, torch.Tensor]:
    """The weights of the model folder ``folder``, checked against its config."""
    state, _, _ = read_model_files(folder)
    return state


# ---------------------------------------------------------------------------------------------------------------
# RNG states
# ---------------------------------------------------------------------------------------------------------------


def get_rng_state() -> dict[str, Any]:
    """The states of python's, numpy's and torch's global generators, in types ``torch.load(weights_only=True)``
    accepts."""
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    state = {
        "python": random.getstate(),
        "numpy": {
            "kind": kind,
            "keys": torch.from_numpy(keys.astype("int64")),
            "pos": int(pos),
            "has_gauss": int(has_gauss),
            "cached_gaussian": float(cached),
        },
        "torch": torch.get_rng_state(),
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: Mapping[str, Any]) -> None:
    random.setstate(state["python"])
    n = state["numpy"]
    np.random.set_state((n["kind"], n["keys"].numpy().astype("uint32"), n["pos"], n["has_gauss"], n["cached_gaussian"]))
    torch.set_rng_state(state["torch"])
    if "cuda" in state and torch.cuda.is_available():
        with contextlib.suppress(RuntimeError):
            torch.cuda.set_rng_state_all(state["cuda"])


# ---------------------------------------------------------------------------------------------------------------
# Checkpoints
# ---------------------------------------------------------------------------------------------------------------


@dataclass
class LoadedCheckpoint:
    """The contents of a checkpoint: ``model`` (state dict), ``optimizer`` (state dict), ``state`` (loop state),
    ``rng`` (generator states), and its ``path``."""

    path: Path
    model: dict[str, torch.Tensor]
    optimizer: dict[str, Any]
    state: dict[str, Any]
    rng: dict[str, Any]

    @property
    def step(self) -> int:
        return int(self.state["step"])


def validate_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Check a checkpoint folder against its manifest; return the manifest.

    Raises:
        CheckpointError: no or unreadable manifest, a listed file missing, or a size or checksum mismatch.
    """
    return validate_manifest(path, REQUIRED_FILES)


def load_checkpoint(
    path: str | os.PathLike, device: str | torch.device = "cpu", validate: bool = True
) -> LoadedCheckpoint:
    """Read a checkpoint folder (validated against its manifest first unless ``validate=False``)."""
    path = Path(path)
    if validate:
        validate_checkpoint(path)
    try:
        model = read_model_state(path)
        optimizer = torch.load(path / OPTIMIZER_FILE, map_location=device, weights_only=True)
        rng = torch.load(path / RNG_FILE, map_location="cpu", weights_only=True)
        state = json.loads((path / STATE_FILE).read_text(encoding="utf-8"))
    except CheckpointError:
        raise
    except Exception as e:  # noqa: BLE001 - any read failure means an unusable checkpoint
        raise CheckpointError(f"{path}: cannot read the checkpoint ({type(e).__name__}: {e})") from e
    return LoadedCheckpoint(path=path, model=model, optimizer=optimizer, state=state, rng=rng)


class CheckpointManager:
    """The checkpoints of one run, in ``folder``.

    Args:
        folder: ``RUN_DIR/checkpoints``.
        keep_last: how many of the newest checkpoints to keep.
        log: ``log(kind, **fields)`` called for removals and invalid checkpoints (the run's event log).
    """

    def __init__(self, folder: str | os.PathLike, keep_last: int = 5, log: Callable[..., None] | None = None) -> None:
        self.folder = Path(folder)
        self.keep_last = int(keep_last)
        self.log = log or (lambda kind, **fields: None)
        #: the invalid checkpoints :meth:`latest_valid` moved aside (their new paths), in the order it found them
        self.moved_aside: list[Path] = []

    def list(self) -> list[tuple[int, Path]]:
        """``(step, path)`` of the folders named like checkpoints, oldest first (valid or not)."""
        if not self.folder.is_dir():
            return []
        out = []
        for p in self.folder.iterdir():
            m = _NAME.match(p.name)
            if m and p.is_dir():
                out.append((int(m.group(1)), p))
        return sorted(out)

    def set_aside(self) -> list[Path]:
        """The invalid checkpoints moved aside so far (``ckpt-*.corrupt-*``, by this manager or an earlier run)."""
        if not self.folder.is_dir():
            return []
        return sorted(p for p in self.folder.iterdir() if _ASIDE.match(p.name))

    def cleanup(self) -> None:
        """Remove temporary folders left by an interrupted write."""
        if not self.folder.is_dir():
            return
        for p in self.folder.iterdir():
            if p.name.startswith((".tmp-ckpt-", ".old-ckpt-")):
                shutil.rmtree(p, ignore_errors=True)
                self.log("checkpoint_temp_removed", path=str(p))

    def latest_valid(self, move_invalid: bool = True) -> Path | None:
        """The newest checkpoint that validates; newer invalid ones are logged and (``move_invalid``) renamed aside
        to ``<name>.corrupt-<n>`` (:attr:`moved_aside`), never deleted."""
        for step, path in reversed(self.list()):
            try:
                validate_checkpoint(path)
            except CheckpointError as e:
                aside = self._move_aside(path) if move_invalid else None
                self.log(
                    "checkpoint_invalid",
                    path=str(path),
                    step=step,
                    error=str(e),
                    moved_to=None if aside is None else str(aside),
                )
                continue
            return path
        return None

    def _move_aside(self, path: Path) -> Path:
        """Rename the checkpoint ``path`` to the first free ``<name>.corrupt-<n>`` beside it (n = 1, 2, ...)."""
        n = 1
        while True:
            aside = path.with_name(f"{path.name}.corrupt-{n}")
            if not aside.exists() and not aside.is_symlink():
                break
            n += 1
        os.rename(path, aside)
        _fsync_dir(self.folder)
        self.moved_aside.append(aside)
        return aside

    def save(
        self,
        *,
        model_state: Mapping[str, torch.Tensor],
        model_config: ModelConfig,
        optimizer_state: Mapping[str, Any],
        trainer_state: Mapping[str, Any],
        rng_state: Mapping[str, Any],
        source: Mapping[str, Any] | None = None,
        operating_point: OperatingPoint | None = None,
    ) -> Path:
        """Write the checkpoint of ``trainer_state["step"]`` atomically, then remove the oldest beyond
        ``keep_last``. Returns its path. ``operating_point`` goes into its ``config.json``."""
        step = int(trainer_state["step"])
        final = self.folder / checkpoint_name(step)
        tmp = self.folder / f".tmp-{final.name}-{os.getpid()}"
        self.folder.mkdir(parents=True, exist_ok=True)
        if tmp.exists():
            shutil.rmtree(tmp)
        tmp.mkdir()
        try:
            save_model_files(model_state, model_config, tmp, dict(source or {}, step=step), operating_point)
            _debug_delay()
            atomic_write_bytes(tmp / OPTIMIZER_FILE, _torch_bytes(optimizer_state))
            _debug_delay()
            atomic_write_bytes(tmp / RNG_FILE, _torch_bytes(dict(rng_state)))
            _debug_delay()
            atomic_write_text(tmp / STATE_FILE, json.dumps(_jsonable(trainer_state), indent=2) + "\n")
            _debug_delay()
            files = {}
            for p in sorted(tmp.iterdir()):
                files[p.name] = {"size": p.stat().st_size, "sha256": sha256_file(p)}
            manifest = {
                "format": MANIFEST_FORMAT,
                "version": MANIFEST_VERSION,
                "step": step,
                "epoch": trainer_state.get("epoch"),
                "files": files,
            }
            atomic_write_text(tmp / MANIFEST_FILE, json.dumps(manifest, indent=2) + "\n")
            _debug_delay()
            if final.exists():  # the same step written before (e.g. after a rollback): swap it out
                old = self.folder / f".old-{final.name}-{os.getpid()}"
                os.replace(final, old)
                os.replace(tmp, final)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.replace(tmp, final)
            _fsync_dir(self.folder)
        except BaseException as e:
            shutil.rmtree(tmp, ignore_errors=True)
            if (
                isinstance(e, OSError)
                and e.errno is not None
                and e.filename is not None
                and e.filename2 is None
                and Path(os.fsdecode(e.filename)).parent == tmp
            ):  # name the file the user will look for
                raise OSError(e.errno, e.strerror, str(final / Path(os.fsdecode(e.filename)).name)) from None
            raise
        self.prune()
        return final

    def prune(self) -> None:
        """Remove the oldest checkpoints beyond ``keep_last``."""
        ckpts = self.list()
        for step, path in ckpts[: max(0, len(ckpts) - self.keep_last)]:
            self._remove(path)
            self.log("checkpoint_removed", path=str(path), step=step)

    def _remove(self, path: Path) -> None:
        """Rename a checkpoint out of the ``ckpt-*`` namespace first (atomic), then delete it: a crash in the middle
        of the deletion leaves an ``.old-ckpt-*`` folder (removed at the next start), never a half-deleted
        ``ckpt-*``."""
        old = self.folder / f".old-{path.name}-{os.getpid()}"
        try:
            os.replace(path, old)
        except OSError:
            old = path
        shutil.rmtree(old, ignore_errors=True)


def _jsonable(x: Any) -> Any:
    """Plain JSON values; NaN and infinities become None (strict JSON has no NaN)."""
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, float) and (x != x or x in (float("inf"), float("-inf"))):
        return None
    if isinstance(x, torch.Tensor) and x.numel() == 1:
        return _jsonable(x.item())
    return x


__all__ = [
    "CheckpointManager",
    "LoadedCheckpoint",
    "MANIFEST_FILE",
    "REQUIRED_FILES",
    "checkpoint_name",
    "get_rng_state",
    "load_checkpoint",
    "read_model_state",
    "save_model_files",
    "set_rng_state",
    "validate_checkpoint",
]
