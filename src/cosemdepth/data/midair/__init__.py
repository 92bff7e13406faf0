"""Mid-Air: on-disk encodings, split CSVs and the sequence dataset.

Attributes are imported lazily (importing the package loads none of its modules)."""

from __future__ import annotations

from ..._lazy import lazy_getattr as _lazy_getattr

_LAZY = {
    "open_midair": ".dataset",
    "read_depth": ".dataset",
    "read_labels": ".dataset",
    "generate_splits": ".splits",
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = sorted(_LAZY)
