"""A tiny procedural dataset held in memory, for smoke tests of the training loop (dataset name ``"toy"``).

Each item is a short nadir flight over a flat ground made of class patches: the camera looks straight down from an
altitude of ``altitude`` metres and moves sideways by a constant step per frame, so the image content slides left
by ``shift`` pixels per frame. Each class has a colour (the Mid-Air palette), a height above the ground (trees
stand higher than water), and its own texture, so depth and labels are learnable from the pixels. The motion follows
the model's convention (``X_prev = R X_curr + t``, camera axes x right, y down, z forward), with the identity
rotation and ``t = (dx, 0, 0)``, ``dx = shift * altitude / f``.

Items have the layout of :func:`cosemdepth.data.open_dataset` (``rgb`` [T,3,H,W], ``depth`` [T,1,H,W], ``semantic``
[T,H,W] int64, ``rot`` [T,4], ``trans`` [T,3], ``intrinsics`` [4], ``reset`` [T] bool) and depend only on
``(seed, split, index)``: no files, no randomness across epochs. It is a dataset of the dataset table like the others
(:func:`open_toy` is its opener; no root, its labels take the model's class count).
"""

from __future__ import annotations

import zlib

import numpy as np
import torch
from torch.utils.data import Dataset

from .midair.format import PALETTE_7


class ToyDataset(Dataset):
    """Procedural flights; see the module docstring.

    Args:
        length: number of items.
        seq_len: frames per item (T).
        size: ``(H, W)`` of the frames.
        num_classes: number of classes (labels in ``[0, num_classes - 1]``).
        seed: base seed; items of different ``split`` names differ.
        split: any name (``"train"``, ``"val"``...), mixed into the seed.
        shift: image motion in pixels per frame.
        altitude: flying height in metres.
    """

    def __init__(
        self,
        length: int = 24,
        seq_len: int = 4,
        size: tuple[int, int] = (32, 32),
        num_classes: int = 7,
        seed: int = 0,
        split: str = "train",
        shift: int = 2,
        altitude: float = 40.0,
    ) -> None:
        if length < 0 or seq_len < 1:
            raise ValueError(f"ToyDataset: length must be >= 0 and seq_len >= 1, got {length}, {seq_len}")
        self.length = int(length)
        self.seq_len = int(seq_len)
        self.size = (int(size[0]), int(size[1]))
        self.num_classes = int(num_classes)
        self.seed = int(seed)
        self.split = str(split)
        self.shift = int(shift)
        self.altitude = float(altitude)
        self.name = "toy"

    def __len__(self) -> int:
        return self.length

    def set_epoch(self, epoch: int) -> None:
        """Items do not change across epochs (present for the loader protocol)."""

    def step_translations(self) -> np.ndarray:
        """``[length * (seq_len - 1)]`` norms of the per-step translations of the items (metres): every frame after
        the first moves ``shift * altitude / f`` metres sideways."""
        dx = self.shift * self.altitude / (self.size[1] / 2.0)
        return np.full(self.length * (self.seq_len - 1), abs(float(np.float32(dx))))

    def _rng(self, index: int) -> np.random.Generator:
        key = zlib.crc32(f"{self.seed}/{self.split}/{index}".encode())
        return np.random.default_rng(key)

    def __getitem__(self, index: int) -> dict:
        if not 0 <= index < self.length:
            raise IndexError(f"index {index} out of range for {self.length} toy items")
        rng = self._rng(index)
        h, w = self.size
        t = self.seq_len
        wide = w + self.shift * (t - 1)
        n = self.num_classes

        # Class patches: a coarse random grid upsampled by blocks of 4-8 pixels.
        block = int(rng.integers(4, 9))
        gh, gw = -(-h // block), -(-wide // block)
        grid = rng.integers(0, n, size=(gh, gw))
        labels = np.kron(grid, np.ones((block, block), dtype=np.int64))[:h, :wide]

        heights = np.linspace(0.0, 0.5 * self.altitude, n)[rng.permutation(n)] if n > 1 else np.zeros(1)
        depth = self.altitude - heights[labels]

        palette = _palette(n)
        texture = rng.normal(0.0, 0.04, size=(h, wide, 3))
        stripes = 0.05 * np.sin(np.arange(wide)[None, :, None] * (0.5 + labels[..., None] % 3))
        rgb = np.clip(palette[labels] / 255.0 + texture + stripes, 0.0, 1.0)

        f = w / 2.0
        dx = self.shift * self.altitude / f
        frames = [slice(k * self.shift, k * self.shift + w) for k in range(t)]
        trans = np.zeros((t, 3), dtype=np.float32)
        trans[1:, 0] = dx
        rot = np.zeros((t, 4), dtype=np.float32)
        rot[:, 0] = 1.0
        reset = np.zeros(t, dtype=bool)
        reset[0] = True
        return {
            "rgb": torch.from_numpy(np.stack([rgb[:, s] for s in frames]).transpose(0, 3, 1, 2).astype(np.float32)),
            "depth": torch.from_numpy(np.stack([depth[None, :, s] for s in frames]).astype(np.float32)),
            "semantic": torch.from_numpy(np.stack([labels[:, s] for s in frames]).astype(np.int64)),
            "rot": torch.from_numpy(rot),
            "trans": torch.from_numpy(trans),
            "intrinsics": torch.tensor([f, f, w / 2.0, h / 2.0], dtype=torch.float32),
            "reset": torch.from_numpy(reset),
        }


def open_toy(
    root,
    split_dir,
    split,
    seq_len,
    size,
    augment,
    *,
    seed: int = 0,
    num_classes: int = 7,
    length: int = 24,
    shift: int = 2,
    altitude: float = 40.0,
) -> ToyDataset:
    """The opener of the ``"toy"`` dataset (:mod:`cosemdepth.data.registry`): ``root`` and ``split_dir`` are unused
    (nothing is read), ``augment`` too (the items are fixed); ``size`` is an int (square) or ``(H, W)``."""
    if isinstance(size, int):
        size = (size, size)
    return ToyDataset(
        length=length,
        seq_len=seq_len,
        size=size,
        num_classes=num_classes,
        seed=seed,
        split=split,
        shift=shift,
        altitude=altitude,
    )


def _palette(n: int) -> np.ndarray:
    """``[n, 3]`` colours: the Mid-Air palette, then grey levels for extra classes."""
    extra = max(0, n - len(PALETTE_7))
    greys = np.linspace(30, 225, extra)[:, None].repeat(3, axis=1) if extra else np.zeros((0, 3))
    return np.concatenate([PALETTE_7.astype(np.float64), greys])[:n]


__all__ = ["ToyDataset", "open_toy"]
