"""The streaming commands as a library: each builds its source, its :class:`~cosemdepth.inference.policy.Streamer`
and its sinks from one frozen options value and runs them (``cosemdepth predict``, ``view`` and ``evaluate`` parse
their arguments into these options and call these functions).

* :mod:`~cosemdepth.jobs.predict`: :class:`PredictOptions`, :func:`run_predict`, and :func:`predict` (a loaded model
  over a source or a dataset into a folder);
* :mod:`~cosemdepth.jobs.view`: :class:`ViewOptions`, :func:`run_view`;
* :mod:`~cosemdepth.jobs.evaluate`: :class:`EvaluateOptions`, :func:`run_evaluate`;
* :mod:`~cosemdepth.jobs.model` (:class:`ModelOptions`, the model loaded once) and :mod:`~cosemdepth.jobs.options`
  (:class:`RunOptions`, the options every streaming command shares).

Attributes are imported lazily (importing the package loads none of its modules)."""

from __future__ import annotations

from .._lazy import lazy_getattr as _lazy_getattr

_LAZY = {
    "PredictOptions": ".predict",
    "run_predict": ".predict",
    "ViewOptions": ".view",
    "run_view": ".view",
    "EvaluateOptions": ".evaluate",
    "run_evaluate": ".evaluate",
    "ModelOptions": ".model",
    "RunOptions": ".options",
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = sorted(_LAZY)
