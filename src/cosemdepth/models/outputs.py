"""Output and state containers of the models."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Optional, Sequence

import torch

Tensor = torch.Tensor


class StreamState:
    """Explicit streaming state: named components, each a tuple of per-level tensors (finest first), contributed by
    the model's temporal decoders in order (their ``state_names``). The depth decoder's are ``"feat"`` (the
    normalised features of the last frame ``[B, C_l, h_l, w_l]``) and ``"depth"`` (the depth it predicted
    ``[B, 1, h_l, w_l]``), a temporal semantic decoder's ``"semantic"``. Empty for M4Semantic (no temporal input).

    Built from the components by name, ``StreamState(feat=..., depth=...)`` or ``StreamState({"feat": ...})``;
    empty components are left out. :attr:`features` and :attr:`depths` read the depth decoder's.
    """

    def __init__(self, components: Optional[Mapping[str, Sequence[Tensor]]] = None, **more: Sequence[Tensor]):
        if components is not None and not isinstance(components, Mapping):
            raise TypeError(f"StreamState takes its components by name, got {type(components).__name__}")
        named = {**(components or {}), **more}
        self.components: dict[str, tuple[Tensor, ...]] = {k: tuple(v) for k, v in named.items() if len(v)}

    @property
    def features(self) -> tuple[Tensor, ...]:
        """The ``"feat"`` component (read-only)."""
        return self.components.get("feat", ())

    @property
    def depths(self) -> tuple[Tensor, ...]:
        """The ``"depth"`` component (read-only)."""
        return self.components.get("depth", ())

    def flatten(self) -> tuple[Tensor, ...]:
        """``(f_1, ..., f_L, d_1, ..., d_L, ...)`` component after component, e.g. for ONNX inputs/outputs or CUDA-graph
        buffers."""
        return tuple(t for comp in self.components.values() for t in comp)

    @classmethod
    def unflatten(cls, tensors: Sequence[Tensor], names: Sequence[str] = ("feat", "depth")) -> "StreamState":
        """Inverse of :meth:`flatten` for components ``names`` of equal length."""
        n = len(tensors) // len(names)
        return cls({name: tuple(tensors[k * n : (k + 1) * n]) for k, name in enumerate(names)})

    @property
    def batch_size(self) -> Optional[int]:
        flat = self.flatten()
        return flat[0].shape[0] if flat else None

    def detach(self) -> "StreamState":
        return StreamState({k: tuple(t.detach() for t in v) for k, v in self.components.items()})

    def __eq__(self, other) -> bool:
        if not isinstance(other, StreamState) or self.components.keys() != other.components.keys():
            return False
        return all(torch.equal(a, b) for a, b in zip(self.flatten(), other.flatten()))


#: Per-frame depth status (``StepOutput.status``): no depth (a reset frame, and the frames after it until the camera
#: has moved far enough), depth estimated from parallax, depth carried from the reference frame.
RESET, ESTIMATED, HELD = "reset", "estimated", "held"
STATUSES = (RESET, ESTIMATED, HELD)


@dataclass
class StepOutput:
    """Output of one streaming step, keyed by decoder: every decoder's output by its head name.

    Attributes:
        heads: the input-size output of every decoder by its head name (``depth``: ``[B, 1, H, W]`` metres;
            ``semantic``: ``[B, N, H, W]`` class probabilities; those of any further decoder), nearest-upsampled
            from the finest level. ``infer`` stacks frames: ``[B, T, C, H, W]`` (``[T, C, H, W]`` for one sequence).
        levels: per-level maps, finest first, by the decoders' map keys (``depth``, ``parallax``, ``depth_other``,
            ``semantic``, ``semantic_logits``, ``semantic_other``, and those of any further decoder).
        valid: ``[B, 1, H, W]`` bool, the depth pixels that are estimates: False on every pixel of a reset frame, where
            the depth is not finite or not positive, and where parallax -> depth is ill-conditioned (near the focus of
            expansion, too little translation; :mod:`cosemdepth.geometry.validity`). None without depth.
        status: per sample, :data:`RESET`, :data:`ESTIMATED` or :data:`HELD` (empty without depth).
        baseline: ``[B]`` metres, the translation from the frame the depth was estimated against (the previous frame,
            or the streaming policy's reference frame; 0 on reset frames). None without depth.

    ``depth``, ``semantic`` and ``labels`` read the heads (None when the model has no such decoder); a change of an
    output goes through ``heads``.
    """

    heads: dict[str, Tensor] = field(default_factory=dict)
    levels: dict[str, list[Tensor]] = field(default_factory=dict)
    valid: Optional[Tensor] = None
    status: list[str] = field(default_factory=list)
    baseline: Optional[Tensor] = None

    @property
    def depth(self) -> Optional[Tensor]:
        """``heads["depth"]``: metres ``[B, 1, H, W]``, or None (no depth decoder)."""
        return self.heads.get("depth")

    @property
    def semantic(self) -> Optional[Tensor]:
        """``heads["semantic"]``: class probabilities ``[B, N, H, W]``, or None (no semantic decoder)."""
        return self.heads.get("semantic")

    @property
    def labels(self) -> Optional[Tensor]:
        """int64 argmax of ``semantic`` over its class axis: ``[B, N, H, W]`` -> ``[B, H, W]``, ``[B, T, N, H, W]`` ->
        ``[B, T, H, W]``."""
        return None if self.semantic is None else class_labels(self.semantic)


def class_labels(scores: Tensor) -> Tensor:
    """The argmax over the class axis (the third from the end) of class scores ``[..., N, H, W]`` -> ``[..., H, W]``."""
    return scores.argmax(dim=-3)


@dataclass
class SequenceOutput:
    """Training-mode output for a whole sequence, keyed by the decoders' map keys; every list is finest level first,
    each entry ``[B, T, ...]``.

    Attributes:
        levels: map key -> per-level maps: the depth decoder's ``depth``, ``parallax`` ``[B,T,1,h,w]`` and
            ``depth_other`` ``[B,T,4,h,w]``, the semantic decoder's ``semantic`` (probabilities) and
            ``semantic_logits`` ``[B,T,N,h,w]`` and ``semantic_other`` ``[B,T,4,h,w]``, those of any further decoder.
        features: the encoder's features ``[B,T,C_l,h_l,w_l]``.

    ``depth`` and ``semantic`` read ``levels`` (empty lists when the model has no such decoder).
    """

    levels: dict[str, list[Tensor]] = field(default_factory=dict)
    features: list[Tensor] = field(default_factory=list)

    @property
    def depth(self) -> list[Tensor]:
        """``levels["depth"]`` (read-only; empty without a depth decoder)."""
        return self.levels.get("depth", [])

    @property
    def semantic(self) -> list[Tensor]:
        """``levels["semantic"]`` (read-only; empty without a semantic decoder)."""
        return self.levels.get("semantic", [])

    def maps(self, key: str) -> list[Tensor]:
        """The per-level maps of ``key``; KeyError naming the keys this output has."""
        if key not in self.levels:
            raise KeyError(f"no maps {key!r} in this output; it has {sorted(self.levels)}")
        return self.levels[key]
