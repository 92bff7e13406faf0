"""Output and state containers of the models."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

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


class StreamState:
    """Explicit streaming state: named components, each a tuple of per-level tensors (finest first), contributed by
    the model's temporal decoders in order. The depth decoder's are ``features`` (component ``"feat"``: the
    normalised features of the last frame ``[B, C_l, h_l, w_l]``) and ``depths`` (``"depth"``: the depth it
    predicted ``[B, 1, h_l, w_l]``). Empty for M4Semantic (no temporal input).
    """

    def __init__(self, features: Sequence[Tensor] = (), depths: Sequence[Tensor] = (), **components: Sequence[Tensor]):
        named = {"feat": features, "depth": depths, **components}
        self.components: dict[str, tuple[Tensor, ...]] = {k: tuple(v) for k, v in named.items() if len(v)}

    @property
    def features(self) -> tuple[Tensor, ...]:
        return self.components.get("feat", ())

    @property
    def depths(self) -> tuple[Tensor, ...]:
        return self.components.get("depth", ())

    def flatten(self) -> tuple[Tensor, ...]:
        """``(f_1, ..., f_L, d_1, ..., d_L, ...)`` component after component, e.g. for ONNX inputs/outputs or CUDA-graph
        buffers."""
        return tuple(t for comp in self.components.values() for t in comp)

    @classmethod
    def unflatten(cls, tensors: Sequence[Tensor], names: Sequence[str] = ("feat", "depth")) -> "StreamState":
        """Inverse of :meth:`flatten` for components ``names`` of equal length."""
        n = len(tensors) // len(names)
        return cls(**{name: tuple(tensors[k * n : (k + 1) * n]) for k, name in enumerate(names)})

    @property
    def batch_size(self) -> Optional[int]:
        flat = self.flatten()
        return flat[0].shape[0] if flat else None

    def detach(self) -> "StreamState":
        return StreamState(**{k: tuple(t.detach() for t in v) for k, v in self.components.items()})

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
    """Output of one streaming step.

    Attributes:
        depth: ``[B, 1, H, W]`` metres at the input size (nearest-upsampled finest level), or None (M4Semantic).
        semantic: ``[B, N, H, W]`` class probabilities at the input size, or None (M4Depth).
        levels: per-level maps, finest first: keys ``depth``, ``parallax``, ``depth_other``, ``semantic``,
            ``semantic_logits``, ``semantic_other`` (those the model has, and those of any further decoder).
        heads: the input-size output of every decoder by its head name (``depth``, ``semantic``, ...).
        valid: ``[B, 1, H, W]`` bool, the depth pixels that are estimates: False on every pixel of a reset frame, where
            the depth is not finite or not positive, and where parallax -> depth is ill-conditioned (near the focus of
            expansion, too little translation; :mod:`cosemdepth.geometry.validity`). None without depth.
        status: per sample, :data:`RESET`, :data:`ESTIMATED` or :data:`HELD` (empty without depth).
        baseline: ``[B]`` metres, the translation from the frame the depth was estimated against (the previous frame,
            or the streaming policy's reference frame; 0 on reset frames). None without depth.
    """

    depth: Optional[Tensor]
    semantic: Optional[Tensor]
    levels: dict[str, list[Tensor]] = field(default_factory=dict)
    heads: dict[str, Tensor] = field(default_factory=dict)
    valid: Optional[Tensor] = None
    status: list[str] = field(default_factory=list)
    baseline: Optional[Tensor] = None

    def __post_init__(self) -> None:
        # the two named outputs are heads too (an output built from them alone, e.g. by a stand-in model)
        for name, value in (("depth", self.depth), ("semantic", self.semantic)):
            if value is not None:
                self.heads.setdefault(name, value)

    @property
    def labels(self) -> Optional[Tensor]:
        """int64 argmax of ``semantic`` over its class axis (third from last, whatever the rank): ``[B, H, W]`` for a
        step, ``[T, H, W]`` / ``[B, T, H, W]`` for a sequence from ``infer``."""
        return None if self.semantic is None else self.semantic.argmax(dim=-3)


@dataclass
class SequenceOutput:
    """Training-mode output for a whole sequence; every list is finest level first, each entry ``[B, T, ...]``.

    ``depth``, ``parallax`` ``[B,T,1,h,w]``, ``depth_other`` ``[B,T,4,h,w]``, ``semantic`` (probabilities) and
    ``semantic_logits`` ``[B,T,N,h,w]``, ``semantic_other`` ``[B,T,4,h,w]``. Lists are empty for a missing decoder;
    ``extra`` holds the maps of further decoders by key.
    """

    depth: list[Tensor] = field(default_factory=list)
    parallax: list[Tensor] = field(default_factory=list)
    depth_other: list[Tensor] = field(default_factory=list)
    semantic: list[Tensor] = field(default_factory=list)
    semantic_logits: list[Tensor] = field(default_factory=list)
    semantic_other: list[Tensor] = field(default_factory=list)
    features: list[Tensor] = field(default_factory=list)
    extra: dict[str, list[Tensor]] = field(default_factory=dict)

    def maps(self, key: str) -> list[Tensor]:
        """The per-level maps of ``key`` (a field, or a further decoder's key in ``extra``)."""
        if key in self.extra:
            return self.extra[key]
        if key in self.__dataclass_fields__ and key not in ("features", "extra"):
            return getattr(self, key)
        raise KeyError(f"no maps {key!r} in this output; maps of further decoders: {sorted(self.extra)}")

    def put(self, key: str, maps: list[Tensor]) -> None:
        if key in self.__dataclass_fields__ and key not in ("features", "extra"):
            setattr(self, key, maps)
        else:
            self.extra[key] = maps
