"""Decoder tasks: what each registered decoder learns, how it is measured, written and drawn
(:class:`~cosemdepth.tasks.base.DecoderTask`), for the depth and semantic decoders and any decoder registered with
:func:`register_task` (see docs/architecture.md, "A new decoder")."""

from . import base
from .base import *  # noqa: F403 (the names of base.__all__)
from .depth import DEPTH
from .semantic import SEMANTIC

__all__ = [*base.__all__, "DEPTH", "SEMANTIC"]
