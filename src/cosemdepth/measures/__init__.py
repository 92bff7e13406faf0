"""Measures: what the tasks score a prediction with, below the tasks that use them.

* :mod:`~cosemdepth.measures.losses`: the training losses (design 8);
* :mod:`~cosemdepth.measures.metrics`: the depth and segmentation metrics, best-checkpoint rules, results tables
  (design 11, 9.5, 15);
* :mod:`~cosemdepth.measures.temporal`: the labels' temporal consistency (design 11.5);
* :mod:`~cosemdepth.measures.classes`: the datasets' class names and palettes.

They import the maths, the models' outputs and the dataset table, nothing above. Attributes are imported lazily
(importing the package loads none of its modules)."""

from __future__ import annotations

from .._lazy import lazy_getattr as _lazy_getattr

_LAZY = {
    "depth_loss": ".losses",
    "semantic_loss": ".losses",
    "DepthMetrics": ".metrics",
    "ValidDepthMetrics": ".metrics",
    "ConfusionMatrix": ".metrics",
    "TemporalConsistency": ".temporal",
    "class_info": ".classes",
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = sorted(_LAZY)
