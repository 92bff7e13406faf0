"""cosemdepth: Co-SemDepth, M4Depth and M4Semantic in PyTorch.

Five lines::

    from cosemdepth import load_model
    model = load_model("weights/synthair-cosemdepth")          # a folder with config.json + model.safetensors
    out, state = model.step(rgb, rot, trans, intrinsics, reset, None)   # one frame; keep `state` for the next
    out = model.infer(frames, motions, intrinsics)                       # or a whole sequence at once
    out.depth, out.semantic                                               # metres [B,1,H,W], probabilities [B,N,H,W]
"""

from __future__ import annotations

from ._lazy import lazy_getattr as _lazy_getattr

__version__ = "0.1.0"

_LAZY = {
    "load_model": ("cosemdepth.checkpoints.model_io", "load_model"),
    "save_model": ("cosemdepth.checkpoints.model_io", "save_model"),
    "build_model": ("cosemdepth.models", "build_model"),
    "ModelConfig": ("cosemdepth.models.config", "ModelConfig"),
    "Streamer": ("cosemdepth.inference.policy", "Streamer"),
    "StreamPolicy": ("cosemdepth.inference.policy", "StreamPolicy"),
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = ["__version__", *_LAZY]
