"""The dataset table: every dataset by name, with its reader and its defaults (like :mod:`cosemdepth.models.registry`
for decoders).

Everything that lists datasets reads this table: :func:`cosemdepth.data.open_dataset`, the training config's
dataset names, the CLI's ``--dataset`` choices and ``cosemdepth splits``, and the evaluation's class names and
palettes. Adding a dataset is a reader module plus one :func:`register_dataset` call (below for the built-in ones,
or at run time); see ``docs/contributing.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from ..errors import ConfigError
from ..models.config import MIDAIR_IMAGE_SIZE
from . import aeroscapes, flight, topair
from .midair import format as midair_format
from .midair.dataset import open_midair
from .midair.splits import generate_splits
from .topair_splits import generate_topair_splits
from .toy import open_toy

#: ``opener(root, split_dir, split, seq_len, size, augment, **options) -> SequenceDataset``.
Opener = Callable[..., Any]
#: ``split_generator(root, out_dir, rule=None) -> {split: [written CSV paths]}`` (``rule``: ``--rule`` or None).
SplitGenerator = Callable[..., Mapping[str, list[Path]]]


@dataclass(frozen=True)
class DatasetSpec:
    """One dataset: its reader and its defaults.

    Attributes:
        name: the name used by ``open_dataset``, the config (``data.train[i].name``) and ``--dataset``.
        opener: the reader, called as ``opener(root, split_dir, split, seq_len, size, augment, **options)``; its
            keyword-only parameters are the options a user may pass (others are refused by name).
        split: default split (None: the reader has no splits, e.g. a flight folder).
        size: default output size (None: the native size).
        split_dir: folder of the split files under the root when none is given (None: the reader decides).
        needs_split_dir: ``open_dataset`` refuses to guess the split folder (Mid-Air: it is kept outside the root).
        classes: the class names of its labels, as the reader returns them (empty: no labels, or labels of the
            model's class count, ``model_classes``).
        palette: ``[len(classes), 3]`` uint8 colours of the classes (None: a generic palette).
        has_depth: its items carry ground-truth depth.
        has_splits: it has split files and ground truth, so evaluate / predict offer it as ``--dataset``.
        windows: its reader takes the ``mode`` / ``db_seq_len`` window options (False for single images and the toy).
        split_generator: writes its split files (``cosemdepth splits NAME``), or None.
        splits_into_root: ``cosemdepth splits NAME ROOT`` without OUT_DIR writes ``ROOT/<split_dir>``.
        options: reader options always passed (before the user's).
        needs_root: it is read from a folder (False: generated in memory, no ``root``; ``"toy"``).
        model_classes: its labels take the model's class count: a training run passes ``num_classes`` to its
            opener (procedural labels, ``"toy"``).
    """

    name: str
    opener: Opener
    split: str | None = "test"
    size: int | tuple[int, int] | None = MIDAIR_IMAGE_SIZE
    split_dir: str | None = None
    needs_split_dir: bool = False
    classes: tuple[str, ...] = ()
    palette: np.ndarray | None = field(default=None, compare=False)
    has_depth: bool = True
    has_splits: bool = True
    windows: bool = True
    split_generator: SplitGenerator | None = None
    splits_into_root: bool = False
    options: Mapping[str, Any] = field(default_factory=dict)
    needs_root: bool = True
    model_classes: bool = False

    @property
    def num_classes(self) -> int:
        return len(self.classes)


#: Dataset name -> spec, in registration order.
DATASETS: dict[str, DatasetSpec] = {}


def register_dataset(name: str, opener: Opener, **spec: Any) -> DatasetSpec:
    """Make dataset ``name`` available everywhere (``open_dataset``, the config, the CLI, class names and palettes).

    ``spec``: the other fields of :class:`DatasetSpec`. Registering an existing name replaces its entry.
    """
    if not isinstance(name, str) or not name.isidentifier():
        raise ConfigError(f"dataset name must be an identifier, got {name!r}")
    if not callable(opener):
        raise TypeError(f"dataset {name!r}: opener must be callable, got {opener!r}")
    classes = tuple(spec.pop("classes", ()))
    palette = spec.pop("palette", None)
    if palette is not None:
        palette = np.asarray(palette, dtype=np.uint8)
        if palette.shape != (len(classes), 3):
            raise ConfigError(
                f"dataset {name!r}: palette must have shape ({len(classes)}, 3) (one colour per "
                f"class), got {palette.shape}"
            )
    entry = DatasetSpec(name=name, opener=opener, classes=classes, palette=palette, **spec)
    DATASETS[name] = entry
    return entry


def dataset_spec(name: str) -> DatasetSpec:
    """The spec of dataset ``name``; ConfigError naming the registered ones if unknown."""
    if name not in DATASETS:
        raise ConfigError(f"unknown dataset {name!r}; choose one of {tuple(DATASETS)}")
    return DATASETS[name]


def split_datasets() -> tuple[str, ...]:
    """Datasets with split files and ground truth (the ``--dataset`` choices of evaluate / predict)."""
    return tuple(n for n, s in DATASETS.items() if s.has_splits)


def _midair_format_splits(default_rule: str) -> SplitGenerator:
    def generate(root, out_dir, rule: str | None = None):
        return generate_splits(root, out_dir, rule=rule or default_rule)

    return generate


def _topair_splits(root, out_dir, rule: str | None = None):  # one rule: TopAir's fixed environments
    return generate_topair_splits(root, out_dir)


# --- the built-in datasets -------------------------------------------------------------------------------------
_MIDAIR_CLASSES = dict(classes=midair_format.CLASSES_7, palette=midair_format.PALETTE_7)
register_dataset(
    "midair",
    open_midair,
    needs_split_dir=True,
    options={"name": "midair"},
    split_generator=_midair_format_splits("midair"),
    **_MIDAIR_CLASSES,
)
register_dataset(
    "synthair",
    open_midair,
    split_dir="splits",
    options={"name": "synthair"},
    split_generator=_midair_format_splits("generic"),
    splits_into_root=True,
    **_MIDAIR_CLASSES,
)
register_dataset(
    "topair",
    topair.open_topair,
    split_dir="splits",
    classes=topair.CLASSES,
    palette=topair.PALETTE,
    split_generator=_topair_splits,
)
register_dataset(
    "aeroscapes",
    aeroscapes.open_aeroscapes,
    split="val",
    size=None,
    split_dir="ImageSets",
    classes=aeroscapes.CLASSES,
    palette=aeroscapes.PALETTE,
    has_depth=False,
    windows=False,
)
register_dataset("flight", flight.open_flight, split=None, size=None, has_depth=False, has_splits=False)
register_dataset(
    "toy", open_toy, split="train", size=(32, 32), has_splits=False, windows=False, needs_root=False, model_classes=True
)

__all__ = ["DATASETS", "DatasetSpec", "dataset_spec", "register_dataset", "split_datasets"]
