"""Training: the training loop and its parts (the losses of design 8 are in :mod:`cosemdepth.measures.losses`).

* :mod:`~cosemdepth.training.trainer`: :class:`Trainer` (the loop, resume, non-finite guard, validation, best model);
* :mod:`~cosemdepth.training.config`: the run config (the ``data``, ``train`` and ``debug`` sections around the
  model config, their defaults), its YAML files and ``KEY=VALUE`` overrides (:func:`resolve_config`);
* :mod:`~cosemdepth.training.checkpoint`: atomic, manifest-validated checkpoints;
* :mod:`~cosemdepth.training.data`, :mod:`~cosemdepth.training.validation`, :mod:`~cosemdepth.training.distributed`,
  :mod:`~cosemdepth.training.events`, :mod:`~cosemdepth.training.board`, :mod:`~cosemdepth.training.rundir`
  (its pictures: :mod:`cosemdepth.render.examples`).

Three lines::

    from cosemdepth.training import Trainer, resolve_config
    cfg = resolve_config("synthair-small", ["data.train.0.root=data/synthair"])
    Trainer(cfg, "runs/small").fit()
"""

from __future__ import annotations

from .._lazy import lazy_getattr as _lazy_getattr

_LAZY = {
    "Trainer": ("cosemdepth.training.trainer", "Trainer"),
    "resolve_config": ("cosemdepth.training.config", "resolve_config"),
    "validate": ("cosemdepth.training.validation", "validate"),
    "load_checkpoint": ("cosemdepth.training.checkpoint", "load_checkpoint"),
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = list(_LAZY)
