"""Datasets and batches of a training run: opening the configured datasets, a resumable distributed sampler, and
batch collation / device transfer.

Training items come from :func:`cosemdepth.data.open_dataset` in ``"train"`` window mode (design 9.2: chunks of
``db_seq_len``, a random ``seq_len`` window in each, the paper's augmentations); validation items in ``"windowed"``
mode (design 7.3: non-overlapping windows of ``val_seq_len``, no augmentation). A mix of datasets samples items with
the configured weights. The order of the items of an epoch follows ``(seed, epoch)`` exactly as
:class:`torch.utils.data.DistributedSampler`, so a run can resume in the middle of an epoch by skipping the batches
it already consumed, without loading them.

Training batches come from one continuous stream (:func:`make_train_stream`) that runs across epoch boundaries:
its batch sampler (:class:`EpochBatchSampler`) yields the full batches of epoch after epoch as ``(epoch, index)``
pairs, and :class:`EpochItems` selects the item's epoch in whichever process loads it (``set_epoch`` before the
fetch). The worker processes therefore start once per stream (once per run, and again after a rollback) and load
the next epoch's first batches while the current epoch ends, is validated and checkpointed; the batches are those
of one loader per epoch (``ResumableSampler.set_position`` + the dataset's ``set_epoch`` + full batches only).
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import torch
from torch.utils.data import DataLoader, Dataset, DistributedSampler, Sampler

from ..data import MixedDataset, dataset_spec, open_dataset
from ..errors import ConfigError, DatasetError
from ..models.config import ARCHITECTURES, ModelConfig
from ..operating_point import MotionStats, OperatingPoint
from ..tasks import tasks_for
from ..workers import check_workers
from .config import DataConfig, DatasetSource, key_path

#: Seed stride between the sample orders of successive rollbacks (a rollback re-shuffles the rest of the epoch).
SALT_STRIDE = 1_000_003


def open_source(
    src: DatasetSource,
    key: str,
    *,
    split: str,
    seq_len: int,
    size: tuple[int, int],
    augment: bool | str,
    mode: str,
    db_seq_len: int | None,
    seed: int,
    num_classes: int,
    decode: str = "exact",
) -> Dataset:
    """Open one configured dataset. ``key`` (e.g. ``data.train[0]``) names it in error messages. ``decode``
    (``data.train_decode``, given for the training datasets only): ``"reduced"`` opens a reader that has the
    ``reduced_decode`` option with it on (:mod:`cosemdepth.data.decode`); other readers decode exactly.

    Raises:
        DatasetError: the dataset folder (or split folder) is missing.
        ConfigError: an option is invalid.
    """
    spec = dataset_spec(src.name)
    if spec.needs_root:
        if src.root is None:
            raise ConfigError(
                f"{key}.root: the folder of the {src.name!r} dataset is required (set it in the config "
                f"file, or with --data-root / --set {key_path(key)}.root=PATH)"
            )
        root = Path(src.root)
        if not root.exists():
            raise DatasetError(f"{key}.root: dataset folder {root} not found")
        if not root.is_dir():
            raise DatasetError(f"{key}.root: {root} is not a folder")
    if src.split_dir is not None and not Path(src.split_dir).is_dir():
        raise DatasetError(f"{key}.split_dir: split folder {src.split_dir} not found")
    kwargs: dict[str, Any] = {"seed": seed}
    if spec.windows:  # (not for single images)
        kwargs.update(mode=mode, db_seq_len=db_seq_len)
    if "reduced_decode" in src.options:
        raise ConfigError(
            f"{key}.options.reduced_decode: set data.train_decode instead (it applies to the training "
            "datasets only, never to validation)"
        )
    if spec.model_classes:
        kwargs.update(num_classes=num_classes)
    kwargs.update(src.options)
    if decode == "reduced" and "reduced_decode" in inspect.signature(spec.opener).parameters:
        kwargs["reduced_decode"] = True
    try:
        return open_dataset(
            src.name,
            src.root,
            split_dir=src.split_dir,
            split=split,
            seq_len=seq_len,
            size=size,
            augment=augment,
            **kwargs,
        )
    except (ConfigError, DatasetError) as e:
        where = f" at {src.root}" if src.root is not None else ""
        raise type(e)(f"{key} ({src.name}{where}, split {split!r}): {e}") from e


def build_train_dataset(data: DataConfig, model: ModelConfig, seed: int) -> Dataset:
    """The training dataset of a run: one dataset, or a weighted mix of the ``data.train`` datasets."""
    sets = [
        open_source(
            src,
            f"data.train[{i}]",
            split=data.train_split,
            seq_len=data.seq_len,
            size=data.size,
            augment=data.augment,
            mode="train",
            db_seq_len=data.db_seq_len,
            seed=seed,
            num_classes=model.num_classes,
            decode=data.train_decode,
        )
        for i, src in enumerate(data.train)
    ]
    for i, ds in enumerate(sets):
        if len(ds) == 0:
            raise DatasetError(
                f"data.train[{i}] ({data.train[i].name}, split {data.train_split!r}) has no "
                f"training sequence of {data.seq_len} frames"
            )
    if len(sets) == 1:
        return sets[0]
    weights = [src.weight for src in data.train]
    return MixedDataset(sets, weights, length=data.mix_length, seed=seed)


def build_val_dataset(data: DataConfig, model: ModelConfig, seed: int) -> Dataset | None:
    """The validation dataset (design 7.3 windows), or None when validation is off."""
    src = data.val_source
    if src is None:
        return None
    key = "data.val" if data.val is not None else "data.train[0] (validation)"
    ds = open_source(
        src,
        key,
        split=data.val_split,
        seq_len=data.val_seq_len,
        size=data.size,
        augment=False,
        mode="windowed",
        db_seq_len=None,
        seed=seed,
        num_classes=model.num_classes,
    )
    if len(ds) == 0:
        raise DatasetError(
            f"{key} ({src.name}, split {data.val_split!r}) has no validation window of "
            f"{data.val_seq_len} frames; set data.validate: false to train without validation"
        )
    return ds


def training_operating_point(dataset: Dataset, size: tuple[int, int], what: str = "data.train") -> OperatingPoint:
    """The operating point a run trains at: the input ``size`` (``data.size``), the focal length in pixels of the
    training data's intrinsics at that size, and the statistics of the per-step translations of its training windows
    (``dataset.step_translations()``, read from the trajectories without decoding images; none when the dataset
    cannot tell them). The intrinsics are the dataset's ``intrinsics`` (the first dataset's for a mix), else those
    of its first item."""
    intr = getattr(dataset, "intrinsics", None)
    if intr is None and isinstance(dataset, MixedDataset):
        intr = getattr(dataset.datasets[0], "intrinsics", None)
    if intr is None:
        intr = dataset[0]["intrinsics"]
    fx, fy = (float(v) for v in torch.as_tensor(intr).reshape(-1)[:2])
    steps = getattr(dataset, "step_translations", None)
    norms = steps() if steps is not None else None
    motion = MotionStats.from_samples(norms) if norms is not None and len(norms) else None
    return OperatingPoint(
        (int(size[0]), int(size[1])),
        (fx, fy),
        motion,
        f"cosemdepth train: {what} at {size[0]}x{size[1]}"
        + (f", {motion.count} window steps" if motion is not None else ""),
    )


def check_modalities(dataset: Dataset, model: ModelConfig, what: str) -> None:
    """Raise :class:`DatasetError` unless the items of ``dataset`` carry the ground truth ``model`` learns from (that
    of each of its decoders' tasks, :attr:`~cosemdepth.tasks.DecoderTask.gt_key`)."""
    item = dataset[0]
    missing = [t.gt_key for t in tasks_for(model) if t.ground_truth(item) is None]
    if model.needs_depth_input and "depth" not in model.decoders and item.get("depth") is None:
        raise DatasetError(
            f"{what} has no depth ground truth, which the {model.arch} model with semantic_time 'gt' "
            "warps its previous labels with (choose a dataset with depth, or semantic_time 'off')"
        )
    if missing:
        others = [a for a, decoders in ARCHITECTURES.items() if not set(decoders) & set(missing)]
        hint = f"choose another dataset, or the {others[0]} model" if others else "choose another dataset"
        raise DatasetError(
            f"{what} has no {' and no '.join(missing)} ground truth, which the {model.arch} model needs ({hint})"
        )


class ResumableSampler(DistributedSampler):
    """:class:`DistributedSampler` that can start in the middle of an epoch, and re-shuffle after a rollback.

    The order of an epoch depends on ``(seed + SALT_STRIDE * salt, epoch)``; this rank's indices are
    ``order[rank::world_size]`` as in ``DistributedSampler`` (tail dropped to a multiple of ``world_size``), and the
    first ``start`` of them are skipped.
    """

    def __init__(
        self, dataset: Dataset, *, num_replicas: int = 1, rank: int = 0, shuffle: bool = True, seed: int = 0
    ) -> None:
        super().__init__(dataset, num_replicas=num_replicas, rank=rank, shuffle=shuffle, seed=seed, drop_last=True)
        self.base_seed = int(seed)
        self.start = 0

    def set_position(self, epoch: int, start: int = 0, salt: int = 0) -> None:
        """Epoch ``epoch``, skipping this rank's first ``start`` items, with the order salted by ``salt``."""
        self.set_epoch(int(epoch))
        self.seed = self.base_seed + SALT_STRIDE * int(salt)
        self.start = int(start)

    def __iter__(self) -> Iterator[int]:
        return iter(list(super().__iter__())[self.start :])

    def __len__(self) -> int:
        return max(0, self.num_samples - self.start)


def collate(items: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Stack the tensors of the items (``rgb [T,3,H,W]`` -> ``[B,T,3,H,W]``...); other values become lists."""
    out: dict[str, Any] = {}
    for k, v in items[0].items():
        vals = [it[k] for it in items]
        out[k] = torch.stack(vals) if isinstance(v, torch.Tensor) else vals
    return out


def _loader(dataset: Dataset, num_workers: int, seed: int, pin_memory: bool, **kwargs) -> DataLoader:
    """A DataLoader with our collation and its worker seeds from ``seed`` (without touching the global RNG)."""
    return DataLoader(
        dataset,
        num_workers=check_workers(num_workers, "data.num_workers"),
        collate_fn=collate,
        pin_memory=pin_memory,
        generator=torch.Generator().manual_seed(seed),
        **kwargs,
    )


def make_loader(dataset: Dataset, batch_size: int, num_workers: int, seed: int, pin_memory: bool = False) -> DataLoader:
    """One pass over ``dataset`` in order, in batches of ``batch_size`` (the last may be short): validation."""
    return _loader(dataset, num_workers, seed, pin_memory, batch_size=batch_size, shuffle=False)


class EpochBatchSampler(Sampler[list[tuple[int, int]]]):
    """The training batches of epoch after epoch, as lists of ``(epoch, index)``, for one continuous DataLoader.

    Epoch ``epoch`` (the first) starts at this rank's item ``start``; every epoch's order is the one ``sampler``
    gives after ``set_position(e, start, salt)``, cut into full batches of ``batch_size`` (the tail is dropped, as a
    ``drop_last`` DataLoader of that epoch does). Stops after ``num_batches`` batches (None: never).
    """

    def __init__(
        self,
        sampler: ResumableSampler,
        batch_size: int,
        *,
        epoch: int,
        start: int = 0,
        salt: int = 0,
        num_batches: int | None = None,
    ) -> None:
        if batch_size < 1:
            raise ValueError(f"batch_size must be positive, got {batch_size}")
        self.sampler = sampler
        self.batch_size = int(batch_size)
        self.epoch, self.start, self.salt = int(epoch), int(start), int(salt)
        self.num_batches = num_batches

    def __iter__(self) -> Iterator[list[tuple[int, int]]]:
        left = self.num_batches
        epoch, start = self.epoch, self.start
        b = self.batch_size
        while left is None or left > 0:
            self.sampler.set_position(epoch, start, self.salt)
            order = list(self.sampler)
            full = len(order) // b
            if full == 0 and start == 0:
                raise ValueError(f"epoch {epoch} has no full batch of {b} items ({len(order)} items for this rank)")
            take = full if left is None else min(full, left)
            for k in range(take):
                yield [(epoch, i) for i in order[k * b : (k + 1) * b]]
            if left is not None:
                left -= take
            epoch, start = epoch + 1, 0

    def __len__(self) -> int:
        if self.num_batches is None:
            raise TypeError("an endless EpochBatchSampler has no length")
        return int(self.num_batches)


class EpochItems(Dataset):
    """``items[(epoch, index)]`` is ``dataset[index]`` of ``epoch``: calls ``dataset.set_epoch(epoch)`` (when it has
    one) in the process that loads the item, so long-lived DataLoader workers follow the epochs of the stream."""

    def __init__(self, dataset: Dataset) -> None:
        self.dataset = dataset

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, key: tuple[int, int]):
        epoch, index = key
        if hasattr(self.dataset, "set_epoch"):
            self.dataset.set_epoch(epoch)
        return self.dataset[index]


def make_train_stream(
    dataset: Dataset,
    sampler: ResumableSampler,
    batch_size: int,
    num_workers: int,
    *,
    epoch: int,
    start_batch: int,
    salt: int,
    num_batches: int | None,
    seed: int,
    pin_memory: bool = False,
) -> DataLoader:
    """The training batches from batch ``start_batch`` of ``epoch`` on, across epochs (see :class:`EpochBatchSampler`),
    ``num_batches`` of them; one iterator of it keeps its ``num_workers`` worker processes for the whole stream."""
    batches = EpochBatchSampler(
        sampler, batch_size, epoch=epoch, start=start_batch * batch_size, salt=salt, num_batches=num_batches
    )
    return _loader(EpochItems(dataset), num_workers, seed, pin_memory, batch_sampler=batches)


def to_device(batch: Mapping[str, Any], device: torch.device) -> dict[str, Any]:
    """Move the tensors of a batch to ``device`` (non-blocking); leave other values."""
    return {k: v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v for k, v in batch.items()}


def steps_per_epoch(dataset: Dataset, batch_size: int, world_size: int) -> int:
    """Optimizer steps in one epoch: each rank gets ``len // world_size`` items, in full batches."""
    return (len(dataset) // world_size) // batch_size


def total_steps(epochs: int, per_epoch: int, max_steps: int) -> int:
    total = epochs * per_epoch
    return min(total, max_steps) if max_steps > 0 else total


__all__ = [
    "SALT_STRIDE",
    "EpochBatchSampler",
    "EpochItems",
    "ResumableSampler",
    "build_train_dataset",
    "build_val_dataset",
    "check_modalities",
    "collate",
    "make_loader",
    "make_train_stream",
    "open_source",
    "steps_per_epoch",
    "to_device",
    "total_steps",
    "training_operating_point",
]
