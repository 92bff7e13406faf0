"""The built-in decoders, one folder each (its module, its task, its TF checkpoint names and one registration):
:mod:`.depth` and :mod:`.semantic`, imported in that order (the order of a model's ``<name>_decoder`` submodules).

This package sits above the tasks and below everything that runs them; nothing below imports it: the registry
(:mod:`cosemdepth.models.registry`) imports it by name on the first read of a table, which registers the decoders.
A decoder defined outside the package is a folder of the same shape loaded as a plugin (:mod:`cosemdepth.plugins`).
"""

from . import depth, semantic

__all__ = ["depth", "semantic"]
