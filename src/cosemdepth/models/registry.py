"""Decoders and architectures by name (like segmentation_models.pytorch's encoders): an architecture is the shared
encoder plus registered decoders.

Adding a decoder is a module with a :class:`~cosemdepth.models.pyramid.PyramidDecoder` subclass plus one entry here
(or :func:`register_decoder` at run time); its weights live under ``<name>_decoder.`` in the state dict.
"""

from __future__ import annotations

from ..errors import ConfigError
from .config import ARCHITECTURES
from .depth_decoder import DepthDecoder
from .pyramid import PyramidDecoder
from .semantic_decoder import SemanticDecoder

#: Decoder name -> class (built from a ModelConfig).
DECODERS: dict[str, type[PyramidDecoder]] = {"depth": DepthDecoder, "semantic": SemanticDecoder}


def register_decoder(name: str, cls: type[PyramidDecoder]) -> None:
    """Make decoder ``cls`` available to architectures as ``name``."""
    if not (isinstance(cls, type) and issubclass(cls, PyramidDecoder)):
        raise TypeError(f"decoder {name!r} must be a PyramidDecoder subclass, got {cls!r}")
    DECODERS[name] = cls


def register_architecture(name: str, decoders: tuple[str, ...]) -> None:
    """Make ``ModelConfig(arch=name)`` the shared encoder plus ``decoders`` (registered names, in order)."""
    unknown = [d for d in decoders if d not in DECODERS]
    if unknown or not decoders:
        raise ConfigError(f"architecture {name!r}: unknown decoder(s) {unknown}; registered: {sorted(DECODERS)}")
    heads = [DECODERS[d].head for d in decoders]
    states = [s for d in decoders for s in DECODERS[d].state_names]
    if len(set(heads)) != len(heads) or len(set(states)) != len(states):
        raise ConfigError(f"architecture {name!r}: decoders {decoders} share a head or state name")
    ARCHITECTURES[name] = tuple(decoders)
