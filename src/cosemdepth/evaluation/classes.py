"""Class names and colour palettes of the datasets (spec 9.5, 9.8, 9.9), looked up by dataset name or class count."""

from __future__ import annotations

import numpy as np

#: Number of classes of each dataset's labels (as the readers return them).
DATASET_CLASSES = {"midair": 7, "synthair": 7, "topair": 9, "aeroscapes": 12}


def _tables() -> dict[int, tuple[tuple[str, ...], np.ndarray]]:
    from ..data import aeroscapes, topair
    from ..data.midair import format as midair

    return {
        7: (tuple(midair.CLASSES_7), np.asarray(midair.PALETTE_7, dtype=np.uint8)),
        9: (tuple(topair.CLASSES), np.asarray(topair.PALETTE, dtype=np.uint8)),
        12: (tuple(aeroscapes.CLASSES), np.asarray(aeroscapes.PALETTE, dtype=np.uint8)),
    }


def generic_palette(num_classes: int) -> np.ndarray:
    """A fixed, distinct-looking ``[N, 3]`` uint8 palette for class sets without one (golden-ratio hues)."""
    import colorsys

    out = []
    for i in range(num_classes):
        h = (i * 0.618033988749895) % 1.0
        s = 0.55 + 0.35 * ((i // 3) % 2)
        v = 0.95 - 0.3 * ((i // 2) % 2)
        out.append([round(255 * c) for c in colorsys.hsv_to_rgb(h, s, v)])
    return np.array(out, dtype=np.uint8)


def class_info(num_classes: int, dataset: str | None = None) -> tuple[tuple[str, ...], np.ndarray]:
    """``(class names, palette [N, 3] uint8)`` for a model with ``num_classes`` classes (on ``dataset``).

    The Mid-Air/SynthAir 7 classes, TopAir's 9 and Aeroscapes' 12 have their own names and palettes (the one of the
    dataset when it matches the count, else the one of that count); other counts get ``class 0``, ... and
    :func:`generic_palette`.
    """
    tables = _tables()
    n = DATASET_CLASSES.get(dataset or "", num_classes)
    if n != num_classes:
        n = num_classes
    if n in tables:
        return tables[n]
    return tuple(f"class {i}" for i in range(num_classes)), generic_palette(num_classes)


__all__ = ["DATASET_CLASSES", "class_info", "generic_palette"]
