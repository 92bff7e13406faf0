"""Sequence windows over trajectories of frames, shared by every reader (design 7.3, 9.2, 11.3).

A reader turns its files into :class:`Trajectory` objects (ordered :class:`FrameRecord` rows) and a frame loader;
:class:`SequenceDataset` cuts the trajectories into windows and returns one dict per window:

==============  ==================  ==============================================================================
key             shape / type        meaning
==============  ==================  ==============================================================================
``rgb``         [T, 3, H, W] f32    colour in [0, 1] (augmentation may leave that range)
``depth``       [T, 1, H, W] f32    z-depth in metres (only when the dataset has depth)
``semantic``    [T, H, W] int64     class indices (only when the dataset has labels)
``rot``         [T, 4] f32          relative rotation (w, x, y, z): ``X_prev = R X_curr + t`` (design 2.2)
``trans``       [T, 3] f32          relative translation in metres, camera axes (x right, y down, z forward)
``intrinsics``  [4] f32             (fx, fy, cx, cy) in pixels of the output size
``reset``       [T] bool            start of a new trajectory (the model resets its state there)
``frame``       [T] int64           row index of each frame in its trajectory
``id``          [T] int64           the row's id column (CSV ``id``; row index for flights/Aeroscapes)
``trajectory``  str                 trajectory name (e.g. the CSV path relative to the split folder)
``timestamp``   [T] f64             only for datasets with timestamps (your own flights)
``source_valid`` [T, 1, H, W] bool  only for undistorted cameras: the pixels with a source pixel
                                    (:class:`cosemdepth.camera.Undistorter`); the depth elsewhere is not an estimate
==============  ==================  ==============================================================================

Window modes:

* ``"train"`` (design 9.2): each trajectory is cut into consecutive non-overlapping chunks of ``db_seq_len`` rows
  (remainder dropped); an item is a random window of ``seq_len`` rows inside its chunk (offset uniform in
  ``[0, db_seq_len - seq_len]``); ``reset = [True, False, ...]``, ignoring the CSV id.
* ``"windowed"`` (design 7.3, validation during training): consecutive non-overlapping windows of ``seq_len`` rows
  (remainder dropped), ``reset = [True, False, ...]``.
* ``"stream"`` (design 11.3, test/eval/predict): consecutive non-overlapping windows of ``seq_len`` rows, in file
  order, the remainder of each trajectory dropped (none when ``seq_len = 1``: every row is yielded, in order);
  ``reset`` comes from the rows (``id == 0`` for Mid-Air, and the first row of every trajectory).

Randomness (train windows and augmentation) is drawn from a ``torch.Generator`` seeded from
``(seed, epoch, index)``, so an item does not depend on the worker that loads it; call :meth:`set_epoch` (the
loader of :mod:`cosemdepth.data.loader` does) to get new draws each epoch.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import torch
from torch.utils.data import Dataset

from ..errors import ConfigError, DatasetError
from .augment import AugmentConfig, augment_sample

MODES = ("train", "windowed", "stream")


def default_mode(split: str | None, seq_len: int) -> str:
    """``"train"`` for the train split; ``"windowed"`` for the val split with ``seq_len > 1`` (design 7.3);
    ``"stream"`` otherwise (so ``seq_len = 1`` on val streams with the CSV resets, as on test)."""
    if split == "train":
        return "train"
    if split == "val" and seq_len > 1:
        return "windowed"
    return "stream"


@dataclass(frozen=True)
class FrameRecord:
    """One row: file paths (absolute, or ``None`` when the modality is absent) and the motion from the previous
    sampled frame (``rot`` w-first, ``trans`` metres, camera axes)."""

    rgb: Path
    depth: Path | None = None
    semantic: Path | None = None
    rot: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    trans: tuple[float, float, float] = (0.0, 0.0, 0.0)
    id: int = 0
    timestamp: float | None = None


class Trajectory:
    """An ordered list of rows in compact form (path strings and numpy arrays; a Mid-Air split of 100k rows takes
    a few tens of MB and pickles quickly to DataLoader workers) and, for stream mode, which rows are resets.

    Args:
        name: trajectory name (``item["trajectory"]``).
        rgb, depth, semantic: per-row paths, relative to ``root`` (or absolute when ``root`` is None);
            ``depth``/``semantic`` are None when the modality is absent.
        rot: ``[n, 4]`` (w, x, y, z); trans: ``[n, 3]``; ids: ``[n]``; timestamps: ``[n]`` or None.
        reset: ``[n]`` bool, stream-mode resets (default: only the first row).
    """

    def __init__(
        self,
        name: str,
        rgb: Sequence[str],
        rot,
        trans,
        ids,
        *,
        root: Path | None = None,
        depth: Sequence[str] | None = None,
        semantic: Sequence[str] | None = None,
        timestamps=None,
        reset=None,
    ) -> None:
        n = len(rgb)
        self.name = name
        self.root = root
        self.rgb = list(rgb)
        self.depth = list(depth) if depth is not None else None
        self.semantic = list(semantic) if semantic is not None else None
        self.rot = np.asarray(rot, dtype=np.float32).reshape(n, 4)
        self.trans = np.asarray(trans, dtype=np.float32).reshape(n, 3)
        self.ids = np.asarray(ids, dtype=np.int64).reshape(n)
        self.timestamps = None if timestamps is None else np.asarray(timestamps, dtype=np.float64).reshape(n)
        if reset is None:
            reset = np.zeros(n, dtype=bool)
            reset[:1] = True
        self.reset = np.asarray(reset, dtype=bool).reshape(n)
        for what, col in (("depth", self.depth), ("semantic", self.semantic)):
            if col is not None and len(col) != n:
                raise ValueError(f"{name}: {len(col)} {what} paths for {n} rows")

    @classmethod
    def from_records(cls, name: str, records: Sequence[FrameRecord], reset=None) -> "Trajectory":
        """Build from :class:`FrameRecord` rows (paths kept as given)."""
        has_depth = records[0].depth is not None
        has_sem = records[0].semantic is not None
        return cls(
            name,
            [str(r.rgb) for r in records],
            [r.rot for r in records],
            [r.trans for r in records],
            [r.id for r in records],
            depth=[str(r.depth) for r in records] if has_depth else None,
            semantic=[str(r.semantic) for r in records] if has_sem else None,
            timestamps=[r.timestamp for r in records] if records[0].timestamp is not None else None,
            reset=reset,
        )

    def __len__(self) -> int:
        return len(self.rgb)

    def _path(self, rel: str) -> Path:
        return self.root / rel if self.root is not None else Path(rel)

    def frame(self, i: int) -> FrameRecord:
        """Row ``i`` as a :class:`FrameRecord` (absolute paths)."""
        return FrameRecord(
            rgb=self._path(self.rgb[i]),
            depth=self._path(self.depth[i]) if self.depth is not None else None,
            semantic=self._path(self.semantic[i]) if self.semantic is not None else None,
            rot=tuple(float(v) for v in self.rot[i]),
            trans=tuple(float(v) for v in self.trans[i]),
            id=int(self.ids[i]),
            timestamp=float(self.timestamps[i]) if self.timestamps is not None else None,
        )

    @property
    def frames(self) -> list[FrameRecord]:
        """All rows as :class:`FrameRecord` objects (built on demand)."""
        return [self.frame(i) for i in range(len(self))]


FrameLoader = Callable[[FrameRecord], Mapping[str, torch.Tensor]]


def item_seed(seed: int, epoch: int, index: int) -> int:
    """A 63-bit seed mixing ``(seed, epoch, index)`` (stable across processes and Python versions)."""
    digest = hashlib.blake2b(f"{seed}:{epoch}:{index}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little") & ((1 << 63) - 1)


class SequenceDataset(Dataset):
    """Windows of ``seq_len`` frames over trajectories; see the module docstring for the item layout and modes.

    Args:
        trajectories: the trajectories, in the order items are yielded.
        load_frame: ``FrameRecord -> {"rgb": [3,H,W], "depth": [1,H,W] (optional), "semantic": [H,W] (optional)}``
            at the output size.
        intrinsics: ``[4]`` (fx, fy, cx, cy) at the output size.
        seq_len: frames per item (T).
        mode: ``"train"``, ``"windowed"`` or ``"stream"``.
        db_seq_len: chunk length of train mode (default ``seq_len``).
        augment: per-sequence augmentation (``None``: none).
        seed: base seed of the per-item random draws.
        name: dataset name (stored in ``self.name``).
        size_at: ``size -> (H, W)``, the size the reader opens these images at for a ``size`` argument (an
            ``(H, W)``, a :class:`~cosemdepth.data.frames.FocalSize` rule, None) (:meth:`opened_size`).
    """

    def __init__(
        self,
        trajectories: Sequence[Trajectory],
        load_frame: FrameLoader,
        intrinsics: torch.Tensor,
        seq_len: int = 1,
        mode: str = "stream",
        db_seq_len: int | None = None,
        augment: AugmentConfig | None = None,
        seed: int = 0,
        name: str = "",
        size_at: Callable[[Any], tuple[int, int]] | None = None,
    ) -> None:
        if mode not in MODES:
            raise ConfigError(f"window mode must be one of {MODES}, got {mode!r}")
        if not isinstance(seq_len, int) or seq_len < 1:
            raise ConfigError(f"seq_len must be a positive integer, got {seq_len!r}")
        db_seq_len = seq_len if db_seq_len is None else db_seq_len
        if not isinstance(db_seq_len, int) or db_seq_len < seq_len:
            raise ConfigError(f"db_seq_len must be an integer >= seq_len ({seq_len}), got {db_seq_len!r}")
        self.trajectories = list(trajectories)
        self.load_frame = load_frame
        self.intrinsics = torch.as_tensor(intrinsics, dtype=torch.float32)
        self.seq_len = seq_len
        self.db_seq_len = db_seq_len if mode == "train" else seq_len
        self.mode = mode
        self.augment = augment
        self.seed = int(seed)
        self.epoch = 0
        self.name = name
        self._size_at = size_at
        chunk = self.db_seq_len
        #: (trajectory index, first row) of every window/chunk
        self.windows: list[tuple[int, int]] = [
            (ti, start) for ti, traj in enumerate(self.trajectories) for start in range(0, len(traj) - chunk + 1, chunk)
        ]
        if self.trajectories and not self.windows:
            longest = max(len(t) for t in self.trajectories)
            raise DatasetError(
                f"{name or 'dataset'}: no window of {chunk} rows fits in any trajectory (the longest has {longest} "
                "rows); lower seq_len/db_seq_len"
            )

    def opened_size(self, size) -> tuple[int, int] | None:
        """``(H, W)`` the reader of these images opens them at for the ``size`` argument (an ``(H, W)``, a
        :class:`~cosemdepth.data.frames.FocalSize` rule, None: its default), computed as the reader does; None when
        the reader does not say. E.g. the size a run without ``--size`` has."""
        return None if self._size_at is None else tuple(self._size_at(size))

    def set_epoch(self, epoch: int) -> None:
        """Select the random draws of ``epoch`` (train windows and augmentation)."""
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self.windows)

    @property
    def num_frames(self) -> int:
        return sum(len(t) for t in self.trajectories)

    def step_translations(self) -> np.ndarray:
        """``[N]`` float64: the norms ``||t||`` (metres) of the motions the model is given between two frames of a
        window, read from the trajectories (no image is decoded).

        ``"train"`` mode: rows ``1 .. db_seq_len - 1`` of every chunk (each is a frame after the first of some window
        drawn from the chunk; the first row of a window is a reset, its motion unused); ``"windowed"``: rows
        ``1 .. seq_len - 1`` of every window; ``"stream"``: every row of the windows that is not a reset.
        """
        parts = []
        for ti, start in self.windows:
            traj = self.trajectories[ti]
            rows = np.arange(start, start + self.db_seq_len)
            rows = rows[~traj.reset[rows]] if self.mode == "stream" else rows[1:]
            parts.append(traj.trans[rows])
        trans = np.concatenate(parts) if parts else np.zeros((0, 3), dtype=np.float32)
        return np.linalg.norm(trans.astype(np.float64), axis=1)

    def generator(self, index: int) -> torch.Generator:
        return torch.Generator().manual_seed(item_seed(self.seed, self.epoch, index))

    def rows(self, index: int, generator: torch.Generator | None = None) -> tuple[int, list[int]]:
        """``(trajectory index, row indices)`` of item ``index`` (train mode draws the window offset)."""
        ti, start = self.windows[index]
        offset = 0
        if self.mode == "train" and self.db_seq_len > self.seq_len:
            g = generator if generator is not None else self.generator(index)
            offset = int(torch.randint(0, self.db_seq_len - self.seq_len + 1, (1,), generator=g))
        return ti, list(range(start + offset, start + offset + self.seq_len))

    def __getitem__(self, index: int) -> dict:
        if not isinstance(index, (int, np.integer)):
            raise TypeError(f"index must be an integer, got {type(index).__name__}")
        index = int(index)
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for a dataset of {len(self)} items")
        g = self.generator(index)
        ti, rows = self.rows(index, g)
        traj = self.trajectories[ti]
        records = [traj.frame(r) for r in rows]
        frames = [self.load_frame(rec) for rec in records]
        sample: dict = {"rgb": torch.stack([f["rgb"] for f in frames])}
        for key in ("depth", "semantic", "source_valid"):
            present = [key in f for f in frames]
            if all(present):
                sample[key] = torch.stack([f[key] for f in frames])
            elif any(present):
                raise ValueError(f"{traj.name}: modality {key!r} present in some frames of a window only")
        sample["rot"] = torch.from_numpy(traj.rot[rows])
        sample["trans"] = torch.from_numpy(traj.trans[rows])
        sample["intrinsics"] = self.intrinsics.clone()
        if self.mode == "stream":
            reset = torch.from_numpy(traj.reset[rows].copy())
        else:
            reset = torch.zeros(self.seq_len, dtype=torch.bool)
            reset[0] = True
        sample["reset"] = reset
        if self.augment is not None:
            sample = augment_sample(sample, self.augment, g)
        sample["frame"] = torch.tensor(rows, dtype=torch.int64)
        sample["id"] = torch.from_numpy(traj.ids[rows])
        sample["trajectory"] = traj.name
        if traj.timestamps is not None:
            sample["timestamp"] = torch.from_numpy(traj.timestamps[rows])
        return sample
