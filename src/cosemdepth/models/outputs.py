"""Output and state containers of the models."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

import torch

Tensor = torch.Tensor


@dataclass
class DepthLevelOutput:
    """One depth-decoder level for one frame: ``parallax``, ``depth`` ``[B,1,h,w]``, ``other`` ``[B,4,h,w]``."""

    parallax: Tensor
    depth: Tensor
    other: Tensor


@dataclass
class SemanticLevelOutput:
    """One semantic-decoder level for one frame: ``probs``/``logits`` ``[B,N,h,w]``, ``other`` ``[B,4,h,w]``."""

    probs: Tensor
    logits: Tensor
    other: Tensor


@dataclass
class StreamState:
    """Explicit streaming state: for every depth level (finest first), the normalised features of the last frame
    ``[B, C_l, h_l, w_l]`` and the depth it predicted ``[B, 1, h_l, w_l]``. Empty for M4Semantic (no temporal input).
    """

    features: tuple[Tensor, ...] = ()
    depths: tuple[Tensor, ...] = ()

    def flatten(self) -> tuple[Tensor, ...]:
        """``(f_1, ..., f_L, d_1, ..., d_L)`` e.g. for ONNX inputs/outputs or CUDA-graph buffers."""
        return (*self.features, *self.depths)

    @classmethod
    def unflatten(cls, tensors: tuple[Tensor, ...] | list[Tensor]) -> "StreamState":
        n = len(tensors) // 2
        return cls(tuple(tensors[:n]), tuple(tensors[n:]))

    @property
    def batch_size(self) -> Optional[int]:
        return self.features[0].shape[0] if self.features else None

    def detach(self) -> "StreamState":
        return StreamState(tuple(t.detach() for t in self.features), tuple(t.detach() for t in self.depths))


@dataclass
class StepOutput:
    """Output of one streaming step.

    Attributes:
        depth: ``[B, 1, H, W]`` metres at the input size (nearest-upsampled finest level), or None (M4Semantic).
        semantic: ``[B, N, H, W]`` class probabilities at the input size, or None (M4Depth).
        levels: per-level maps, finest first: keys ``depth``, ``parallax``, ``depth_other``, ``semantic``,
            ``semantic_logits``, ``semantic_other`` (those the model has).
    """

    depth: Optional[Tensor]
    semantic: Optional[Tensor]
    levels: dict[str, list[Tensor]] = field(default_factory=dict)

    @property
    def labels(self) -> Optional[Tensor]:
        """``[B, H, W]`` int64 argmax of ``semantic``."""
        return None if self.semantic is None else self.semantic.argmax(dim=1)


def step_output(
    depth_levels: Optional[Sequence[DepthLevelOutput]],
    semantic_levels: Optional[Sequence[SemanticLevelOutput]],
    upsample: Callable[[Tensor], Tensor],
) -> StepOutput:
    """Assemble a :class:`StepOutput` from the per-level outputs of one step (finest first; ``None`` for a decoder
    the model does not have): ``levels`` gets every per-level map, ``depth``/``semantic`` are the finest level's
    depth ``[B,1,h,w]`` / probabilities ``[B,N,h,w]`` passed through ``upsample`` (to the input size)."""
    levels: dict[str, list[Tensor]] = {}
    depth = semantic = None
    if depth_levels is not None:
        levels["depth"] = [o.depth for o in depth_levels]
        levels["parallax"] = [o.parallax for o in depth_levels]
        levels["depth_other"] = [o.other for o in depth_levels]
        depth = upsample(depth_levels[0].depth)
    if semantic_levels is not None:
        levels["semantic"] = [o.probs for o in semantic_levels]
        levels["semantic_logits"] = [o.logits for o in semantic_levels]
        levels["semantic_other"] = [o.other for o in semantic_levels]
        semantic = upsample(semantic_levels[0].probs)
    return StepOutput(depth, semantic, levels)


@dataclass
class SequenceOutput:
    """Training-mode output for a whole sequence; every list is finest level first, each entry ``[B, T, ...]``.

    ``depth``, ``parallax`` ``[B,T,1,h,w]``, ``depth_other`` ``[B,T,4,h,w]``, ``semantic`` (probabilities) and
    ``semantic_logits`` ``[B,T,N,h,w]``, ``semantic_other`` ``[B,T,4,h,w]``. Lists are empty for a missing decoder.
    """

    depth: list[Tensor] = field(default_factory=list)
    parallax: list[Tensor] = field(default_factory=list)
    depth_other: list[Tensor] = field(default_factory=list)
    semantic: list[Tensor] = field(default_factory=list)
    semantic_logits: list[Tensor] = field(default_factory=list)
    semantic_other: list[Tensor] = field(default_factory=list)
    features: list[Tensor] = field(default_factory=list)
