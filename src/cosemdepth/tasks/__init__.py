"""Decoder tasks: what each registered decoder learns, how it is measured, written and drawn
(:class:`~cosemdepth.tasks.base.DecoderTask`), and the one registration of a decoder (:func:`register_decoder`).
The built-in decoders (depth, semantic) are folders of :mod:`cosemdepth.decoders`; see docs/architecture.md,
"A new decoder"."""

from . import base
from .base import *  # noqa: F403 (the names of base.__all__)

__all__ = list(base.__all__)
