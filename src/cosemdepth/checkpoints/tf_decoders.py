"""The official TensorFlow checkpoints' names of a decoder (:class:`TfDecoder`): the scope of its refiners
(``<root>/levels/{j}/<scope>/(prep|est_*)_conv_layers/{k}``) and the :class:`ModelConfig` fields its weights
determine. Each decoder the TF checkpoints hold declares its own in its folder (``cosemdepth/decoders/<name>/``) and
registers it with the decoder; :data:`TF_DECODERS` (the registry's view, keyed by the decoder's name, in
registration order) is what :mod:`cosemdepth.checkpoints.convert` loops over. A decoder without TF names has no TF
weights."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Mapping

from ..models.registry import TF_DECODERS

#: Our parameter names -> their TF shapes (``[kh, kw, C_in, C_out]`` for a kernel).
Shapes = Mapping[str, tuple[int, ...]]


@dataclass(frozen=True)
class TfDecoder:
    """A decoder's TF names: ``refiner`` its refiners' scope; ``config(shapes, levels, origin)`` the config fields
    its converted weights determine, from our parameter names and their TF shapes (``[kh, kw, C_in, C_out]``),
    keyed by field (the keys are the fields read from the shapes)."""

    refiner: str
    config: Callable[[Shapes, int, str], dict[str, Any]]


__all__ = ["Shapes", "TF_DECODERS", "TfDecoder"]
