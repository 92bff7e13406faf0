"""Checkpoints: our model folders (``config.json`` + ``model.safetensors``), the official TensorFlow checkpoints
(a reader that needs no TensorFlow) and their conversion into model folders.

Attributes are imported lazily (importing the package loads none of its modules)."""

from __future__ import annotations

from .._lazy import lazy_getattr as _lazy_getattr

_LAZY = {
    "load_model": ".model_io",
    "save_model": ".model_io",
    "save_weights": ".model_io",
    "read_weights": ".model_io",
    "convert_checkpoint": ".convert",
    "import_checkpoint": ".convert",
    "infer_config": ".convert",
    "CheckpointReader": ".tf_checkpoint",
    "read_checkpoint": ".tf_checkpoint",
    "is_tf_checkpoint": ".tf_checkpoint",
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = sorted(_LAZY)
