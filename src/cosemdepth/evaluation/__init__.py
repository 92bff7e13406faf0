"""Evaluation: the test protocol (:mod:`~cosemdepth.evaluation.evaluator`), the fidelity check against
the TF reference; the metrics it reports are in :mod:`cosemdepth.measures`.

Attributes are imported lazily (importing the package loads none of its modules)."""

from __future__ import annotations

from .._lazy import lazy_getattr as _lazy_getattr

_LAZY = {
    "evaluate": ".evaluator",
    "compare_with_reference": ".fidelity",
    "class_info": "cosemdepth.measures.classes",
    "DepthMetrics": "cosemdepth.measures.metrics",
    "ValidDepthMetrics": "cosemdepth.measures.metrics",
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = sorted(_LAZY)
