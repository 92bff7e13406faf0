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
from .sequence import SequenceDataset

DATASETS = ("midair", "synthair", "topair", "aeroscapes", "flight")


def open_dataset(
    name: str,
    root: str | Path,
    split_dir: str | Path | None = None,
    split: str | None = None,
    seq_len: int = 1,
    size: int | tuple[int, int] | None = None,
    augment: bool | str | AugmentConfig = False,
    **kwargs,
) -> SequenceDataset:
    """Open a dataset as a sequence dataset of item dicts.

    Args:
        name: ``"midair"``, ``"synthair"``, ``"topair"``, ``"aeroscapes"`` or ``"flight"``.
        root: dataset root (for ``"flight"``: the folder of images).
        split_dir: folder of the split files. Required for ``"midair"`` (``<split_dir>/<split>_data/**/*.csv``);
            ``"synthair"`` and ``"topair"`` default to ``<root>/splits``, ``"aeroscapes"`` to
            ``<root>/ImageSets``; ignored for ``"flight"``.
        split: ``"train"``, ``"val"`` or ``"test"`` (default ``"test"``; ``"val"`` for Aeroscapes; ignored for
            flights).
        seq_len: frames per item (T). With ``seq_len=1`` on a test split every CSV row is yielded, in order.
        size: output size, an int or ``(H, W)``. Default: 384 for Mid-Air/SynthAir/TopAir, the native size for
            Aeroscapes and flights.
        augment: ``False`` (default), ``True`` (the paper's augmentation, spec 8.3), a preset name
            (``"train"``, ``"finetune"``, ``"geometric"``) or an :class:`AugmentConfig`.
        **kwargs: reader options: ``mode`` (``"train"``/``"windowed"``/``"stream"``), ``db_seq_len``, ``seed``,
            ``labels`` and ``modalities`` (Mid-Air/SynthAir), and the flight options of
            :func:`cosemdepth.data.flight.open_flight` (``poses``, ``intrinsics``, ``fov``, ``convention``,
            ``match``, ``frame_skip``...).

    Returns:
        a :class:`SequenceDataset`; ``dataset[i]`` is a dict with ``rgb`` [T,3,H,W], ``depth`` [T,1,H,W] (when
        known), ``semantic`` [T,H,W] int64 (when known), ``rot`` [T,4], ``trans`` [T,3], ``intrinsics`` [4],
        ``reset`` [T] bool, plus ``frame``, ``id``, ``trajectory`` (and ``timestamp`` for flights).
    """
    if name not in DATASETS:
        raise ConfigError(f"unknown dataset {name!r}; choose one of {DATASETS}")
    if name in ("midair", "synthair"):
        from .midair.dataset import open_midair

        if split_dir is None:
            if name == "midair":
                raise ConfigError("open_dataset('midair', ...) needs split_dir (the folder holding <split>_data/)")
            split_dir = Path(root) / "splits"
        _check_kwargs(open_midair, name, kwargs)
        return open_midair(root, split_dir, split or "test", seq_len, 384 if size is None else size, augment,
                           **{"name": name, **kwargs})
    if name == "topair":
        from .topair import open_topair

        _check_kwargs(open_topair, name, kwargs)
        return open_topair(root, split_dir, split or "test", seq_len, 384 if size is None else size, augment, **kwargs)
    if name == "aeroscapes":
        from .aeroscapes import open_aeroscapes

        _check_kwargs(open_aeroscapes, name, kwargs)
        return open_aeroscapes(root, split_dir, split or "val", seq_len, size, augment, **kwargs)
    if name == "flight":
        from .flight import open_flight

        _check_kwargs(open_flight, name, kwargs)
        return open_flight(root, split_dir, split, seq_len, size, augment, **kwargs)
    raise AssertionError(name)


def _check_kwargs(fn, name: str, kwargs: dict) -> None:
    params = inspect.signature(fn).parameters
    allowed = [p for p, v in params.items() if v.kind == inspect.Parameter.KEYWORD_ONLY]
    unknown = sorted(set(kwargs) - set(allowed))
    if unknown:
        raise ConfigError(f"unknown option(s) {unknown} for dataset {name!r}; valid options: {allowed}")


__all__ = [
    "DATASETS", "AugmentConfig", "MixedDataset", "SeededLoader", "SequenceDataset", "collate", "make_loader",
    "open_dataset",
]
