"""Class names and colour palettes of the datasets (design 10.5, 10.8, 10.9), by dataset name or class count."""

from __future__ import annotations

import colorsys

import numpy as np

from ..data.registry import DATASETS


def dataset_classes() -> dict[str, int]:
    """Number of classes of each registered dataset's labels (as the readers return them; datasets with labels)."""
    return {name: spec.num_classes for name, spec in DATASETS.items() if spec.classes}


def _table(spec) -> tuple[tuple[str, ...], np.ndarray]:
    palette = spec.palette if spec.palette is not None else generic_palette(spec.num_classes)
    return tuple(spec.classes), np.asarray(palette, dtype=np.uint8)


def generic_palette(num_classes: int) -> np.ndarray:
    """A fixed, distinct-looking ``[N, 3]`` uint8 palette for class sets without one (golden-ratio hues)."""
    out = []
    for i in range(num_classes):
        h = (i * 0.618033988749895) % 1.0
        s = 0.55 + 0.35 * ((i // 3) % 2)
        v = 0.95 - 0.3 * ((i // 2) % 2)
        out.append([round(255 * c) for c in colorsys.hsv_to_rgb(h, s, v)])
    return np.array(out, dtype=np.uint8)


def class_info(num_classes: int, dataset: str | None = None) -> tuple[tuple[str, ...], np.ndarray]:
    """``(class names, palette [N, 3] uint8)`` for a model with ``num_classes`` classes (on ``dataset``).

    The class names and palette of ``dataset`` (a registered one, :mod:`cosemdepth.data.registry`) when its class
    count matches, else those of the first registered dataset with that many classes (Mid-Air/SynthAir's 7,
    TopAir's 9, Aeroscapes' 12); other counts get ``class 0``, ... and :func:`generic_palette`.
    """
    spec = DATASETS.get(dataset or "")
    if spec is not None and spec.num_classes == num_classes:
        return _table(spec)
    for spec in DATASETS.values():
        if spec.classes and spec.num_classes == num_classes:
            return _table(spec)
    return tuple(f"class {i}" for i in range(num_classes)), generic_palette(num_classes)


__all__ = ["dataset_classes", "class_info", "generic_palette"]
