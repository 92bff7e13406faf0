"""Fast inference: packed convolutions, the fast streaming engine, CUDA-graph streaming."""

from .engine import FastEngine

__all__ = ["FastEngine"]
