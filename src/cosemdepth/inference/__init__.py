"""Fast inference: packed convolutions, the fast streaming engine (registered as ``SceneModel.optimize("fast")``),
CUDA-graph streaming."""

from .engine import FastEngine

__all__ = ["FastEngine"]
