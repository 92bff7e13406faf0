"""DataLoader factory with reproducible shuffling and per-worker seeding, and a weighted mix of datasets.

Items draw their randomness (train window offsets, augmentation) from a generator seeded with
``(dataset seed, epoch, index)`` (:func:`cosemdepth.data.sequence.item_seed`), so results do not depend on the
number of workers. :class:`SeededLoader` advances the epoch at every ``iter()`` and seeds its shuffling from
``(seed, epoch)``; worker processes additionally get ``random``/``numpy``/``torch`` global seeds derived from the
loader's seed, for third-party code that uses global generators.
"""

from __future__ import annotations

import random
from typing import Sequence

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from ..errors import ConfigError
from ..workers import check_workers
from .sequence import item_seed


def _worker_init(worker_id: int) -> None:
    seed = torch.initial_seed() % 2**32  # DataLoader sets base_seed + worker_id
    random.seed(seed)
    np.random.seed(seed)


def collate(items: list[dict]) -> dict:
    """Stack the tensors of a list of items (strings become lists). Items must have the same keys."""
    keys = items[0].keys()
    for it in items[1:]:
        if it.keys() != keys:
            raise ValueError(f"cannot batch items with different keys: {sorted(keys)} vs {sorted(it.keys())}")
    out = {}
    for k in keys:
        v = items[0][k]
        out[k] = torch.stack([it[k] for it in items]) if isinstance(v, torch.Tensor) else [it[k] for it in items]
    return out


class SeededLoader(DataLoader):
    """A DataLoader whose shuffling and item randomness follow ``(seed, epoch)``; each ``iter()`` is one epoch
    (call :meth:`set_epoch` to jump, e.g. when resuming training)."""

    def __init__(self, dataset: Dataset, *, seed: int = 0, **kwargs) -> None:
        self._gen = torch.Generator()
        super().__init__(dataset, generator=self._gen, **kwargs)
        self.seed = int(seed)
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __iter__(self):
        epoch = self.epoch
        self.epoch += 1
        if hasattr(self.dataset, "set_epoch"):
            self.dataset.set_epoch(epoch)
        self._gen.manual_seed(item_seed(self.seed, epoch, -1))
        return super().__iter__()


def make_loader(
    dataset: Dataset,
    batch_size: int = 1,
    *,
    shuffle: bool = False,
    num_workers: int = 0,
    seed: int = 0,
    drop_last: bool = False,
    pin_memory: bool = False,
    prefetch_factor: int | None = None,
) -> SeededLoader:
    """A :class:`SeededLoader` over ``dataset``.

    Args:
        dataset: any dataset of item dicts (e.g. from :func:`cosemdepth.data.open_dataset`).
        batch_size: items per batch; tensors get a leading batch axis (``rgb`` -> ``[B, T, 3, H, W]``).
        shuffle: reshuffle every epoch (training, design 9.2 step 3); order from ``(seed, epoch)``.
        num_workers: worker processes (0 loads in the main process).
        seed: seed of the shuffling and of the workers' global generators.
        drop_last: drop the last incomplete batch (the original trains with ``drop_remainder``).
        pin_memory: pin batches for faster host-to-GPU copies.
        prefetch_factor: batches prefetched per worker (DataLoader default when None).
    """
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ConfigError(f"batch_size must be a positive integer, got {batch_size!r}")
    check_workers(num_workers, "num_workers")
    kwargs = {}
    if num_workers > 0:
        kwargs["worker_init_fn"] = _worker_init
        if prefetch_factor is not None:
            kwargs["prefetch_factor"] = prefetch_factor
    return SeededLoader(
        dataset,
        seed=seed,
        batch_size=batch_size,
        shuffle=shuffle,
        num_workers=num_workers,
        drop_last=drop_last,
        pin_memory=pin_memory,
        collate_fn=collate,
        persistent_workers=False,
        **kwargs,
    )


class MixedDataset(Dataset):
    """A weighted mix of datasets (e.g. Mid-Air + SynthAir): item ``i`` comes from dataset ``d`` with probability
    ``weights[d] / sum(weights)``, and is a uniformly drawn item of it; draws are seeded by ``(seed, epoch, i)``.

    Items get a ``source`` key (the index of the dataset they came from). The datasets should produce items with
    the same keys and shapes (same ``size`` and ``seq_len``) so that they can be batched.

    Args:
        datasets: the datasets to mix.
        weights: non-negative sampling weights, one per dataset (not all zero).
        length: items per epoch (default: the sum of the datasets' lengths).
        seed: base seed of the draws.
    """

    def __init__(
        self, datasets: Sequence[Dataset], weights: Sequence[float], length: int | None = None, seed: int = 0
    ) -> None:
        if len(datasets) == 0 or len(datasets) != len(weights):
            raise ConfigError(f"need one weight per dataset, got {len(datasets)} datasets and {len(weights)} weights")
        w = np.asarray(weights, dtype=np.float64)
        if not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
            raise ConfigError(f"mix weights must be non-negative and not all zero, got {list(weights)}")
        for i, d in enumerate(datasets):
            if w[i] > 0 and len(d) == 0:
                raise ConfigError(f"dataset {i} of the mix is empty but has weight {w[i]}")
        self.datasets = list(datasets)
        self.weights = torch.tensor(w / w.sum())
        self.length = int(length) if length is not None else sum(len(d) for d in datasets)
        self.seed = int(seed)
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)
        for d in self.datasets:
            if hasattr(d, "set_epoch"):
                d.set_epoch(epoch)

    def __len__(self) -> int:
        return self.length

    def step_translations(self):
        """``[N]`` per-step translation norms of the mixed datasets' windows, pooled (each dataset with a positive
        weight and a ``step_translations`` method; its windows once each, whatever its weight), or None when one
        of them has no such method."""
        parts = []
        for d, w in zip(self.datasets, self.weights.tolist()):
            if w <= 0:
                continue
            fn = getattr(d, "step_translations", None)
            if fn is None:
                return None
            parts.append(np.asarray(fn(), dtype=np.float64))
        return np.concatenate(parts) if parts else None

    def pick(self, index: int) -> tuple[int, int]:
        """``(dataset index, item index)`` of mixed item ``index`` in the current epoch."""
        g = torch.Generator().manual_seed(item_seed(self.seed, self.epoch, index))
        d = int(torch.multinomial(self.weights, 1, generator=g))
        j = int(torch.randint(0, len(self.datasets[d]), (1,), generator=g))
        return d, j

    def __getitem__(self, index: int) -> dict:
        if not 0 <= index < self.length:
            raise IndexError(f"index {index} out of range for a mix of {self.length} items")
        d, j = self.pick(index)
        item = dict(self.datasets[d][j])
        item["source"] = torch.tensor(d, dtype=torch.int64)
        return item
