"""Evaluation: depth and segmentation metrics, best-checkpoint rules, results tables
(:mod:`cosemdepth.evaluation.metrics`).

Attributes are imported lazily (importing the package loads none of its modules)."""

from __future__ import annotations

from .._lazy import lazy_getattr as _lazy_getattr

_LAZY = {
    "evaluate": ".evaluator",
    "compare_with_reference": ".fidelity",
    "class_info": ".classes",
    "DepthMetrics": ".metrics",
    "ValidDepthMetrics": ".metrics",
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = sorted(_LAZY)
