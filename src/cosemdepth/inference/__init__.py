"""Fast inference: packed convolutions, the fast streaming engine (registered as ``SceneModel.optimize("fast")``),
CUDA-graph streaming, and baseline-aware streaming (:class:`Streamer`)."""

from .engine import FastEngine
from .policy import POLICIES, StreamPolicy, Streamer, StreamerState

__all__ = ["FastEngine", "POLICIES", "StreamPolicy", "Streamer", "StreamerState"]
