"""Fast inference: :class:`FastModel` (the fast streaming path of a model, what ``load_model`` returns by default)
over :class:`FastEngine` (packed convolutions feeding the models' own level loop), CUDA-graph streaming
(:class:`StaticStreamer`), and baseline-aware streaming (:class:`Streamer`)."""

from .engine import FastEngine
from .fast_model import FastModel, reference_model
from .graphs import StaticStreamer, make_streamer
from .policy import (
    BASELINE,
    EVERY_FRAME,
    POLICIES,
    Streamer,
    StreamerState,
    StreamPolicy,
    default_min_baseline,
    policy_info,
)

__all__ = [
    "BASELINE",
    "EVERY_FRAME",
    "POLICIES",
    "FastEngine",
    "FastModel",
    "StaticStreamer",
    "StreamPolicy",
    "Streamer",
    "StreamerState",
    "default_min_baseline",
    "make_streamer",
    "policy_info",
    "reference_model",
]
