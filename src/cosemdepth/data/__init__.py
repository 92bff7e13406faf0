"""Datasets: Mid-Air, SynthAir (procedural, Mid-Air format), TopAir, Aeroscapes and your own flights.

One entry point, :func:`open_dataset`; a DataLoader factory, :func:`make_loader`; and a weighted mix of datasets,
:class:`MixedDataset`. Items are dicts of tensors (layout in :mod:`cosemdepth.data.sequence`); see ``docs/data.md``.
"""

from __future__ import annotations

import inspect
from pathlib import Path

from ..errors import ConfigError
from .augment import AugmentConfig
from .loader import MixedDataset, SeededLoader, collate, make_loader
from .registry import DATASETS, DatasetSpec, dataset_spec, register_dataset
from .sequence import SequenceDataset


def open_dataset(
    name: str,
    root: str | Path | None,
    split_dir: str | Path | None = None,
    split: str | None = None,
    seq_len: int = 1,
    size: int | tuple[int, int] | None = None,
    augment: bool | str | AugmentConfig = False,
    **kwargs,
) -> SequenceDataset:
    """Open a dataset as a sequence dataset of item dicts.

    Args:
        name: a registered dataset (:mod:`cosemdepth.data.registry`): ``"midair"``, ``"synthair"``, ``"topair"``,
            ``"aeroscapes"``, ``"flight"``, ``"toy"`` (procedural, in memory), or one added with
            :func:`register_dataset`.
        root: dataset root (for ``"flight"``: the folder of images; None for ``"toy"``).
        split_dir: folder of the split files. Required for ``"midair"`` (``<split_dir>/<split>_data/**/*.csv``);
            ``"synthair"`` and ``"topair"`` default to ``<root>/splits``, ``"aeroscapes"`` to
            ``<root>/ImageSets``; ignored for ``"flight"``.
        split: ``"train"``, ``"val"`` or ``"test"`` (default ``"test"``; ``"val"`` for Aeroscapes; ignored for
            flights).
        seq_len: frames per item (T). With ``seq_len=1`` on a test split every CSV row is yielded, in order.
        size: output size, an int or ``(H, W)``. Default: 384 for Mid-Air/SynthAir/TopAir, the native size for
            Aeroscapes and flights.
        augment: ``False`` (default), ``True`` (the paper's augmentation, design 9.3), a preset name
            (``"train"``, ``"finetune"``, ``"geometric"``) or an :class:`AugmentConfig`.
        **kwargs: reader options: ``mode`` (``"train"``/``"windowed"``/``"stream"``), ``db_seq_len``, ``seed``,
            ``labels`` and ``modalities`` (Mid-Air/SynthAir), ``calibration`` (flights, Mid-Air, SynthAir: a lens
            to undistort, :mod:`cosemdepth.camera`), and the flight options of
            :func:`cosemdepth.data.flight.open_flight` (``poses``, ``intrinsics``, ``fov``, ``convention``,
            ``match``, ``frame_skip``...).

    Returns:
        a :class:`SequenceDataset`; ``dataset[i]`` is a dict with ``rgb`` [T,3,H,W], ``depth`` [T,1,H,W] (when
        known), ``semantic`` [T,H,W] int64 (when known), ``rot`` [T,4], ``trans`` [T,3], ``intrinsics`` [4],
        ``reset`` [T] bool, plus ``frame``, ``id``, ``trajectory`` (and ``timestamp`` for flights, ``source_valid``
        [T,1,H,W] bool for undistorted cameras).
    """
    spec = dataset_spec(name)
    if split_dir is None and spec.split_dir is not None:
        split_dir = Path(root) / spec.split_dir
    if split_dir is None and spec.needs_split_dir:
        raise ConfigError(f"open_dataset({name!r}, ...) needs split_dir (the folder holding <split>_data/)")
    _check_kwargs(spec.opener, name, kwargs)
    return spec.opener(
        root,
        split_dir,
        split or spec.split,
        seq_len,
        spec.size if size is None else size,
        augment,
        **{**spec.options, **kwargs},
    )


def _check_kwargs(fn, name: str, kwargs: dict) -> None:
    params = inspect.signature(fn).parameters
    allowed = [p for p, v in params.items() if v.kind == inspect.Parameter.KEYWORD_ONLY]
    unknown = sorted(set(kwargs) - set(allowed))
    if unknown:
        raise ConfigError(f"unknown option(s) {unknown} for dataset {name!r}; valid options: {allowed}")


__all__ = [
    "DATASETS",
    "AugmentConfig",
    "DatasetSpec",
    "dataset_spec",
    "register_dataset",
    "MixedDataset",
    "SeededLoader",
    "SequenceDataset",
    "collate",
    "make_loader",
    "open_dataset",
]
