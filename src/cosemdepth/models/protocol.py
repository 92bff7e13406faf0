"""The streaming model's contract, declared once: :class:`StreamingModel`.

Everything the package streams frames through implements it: the model's own modules
(:class:`~cosemdepth.models.SceneModel`), the fast path (:class:`~cosemdepth.inference.FastModel`), an exported graph
run by ONNX Runtime (:class:`~cosemdepth.export.runtime.OnnxModel`), and the baseline-aware policy on top of any of
them (:class:`~cosemdepth.inference.Streamer`, whose state is a
:class:`~cosemdepth.inference.policy.StreamerState`). Each describes itself with the attributes named here, none by
forwarding to another object's attributes.
"""

from __future__ import annotations

from typing import Any, Collection, Iterator, Optional, Protocol, Sequence, TypeVar, runtime_checkable

import torch

from ..errors import ConfigError
from ..operating_point import OperatingPoint
from .config import ModelConfig
from .outputs import StepOutput

#: The state a streaming model carries from one step to the next (:class:`~cosemdepth.models.outputs.StreamState`
#: for the model's paths, :class:`~cosemdepth.inference.policy.StreamerState` for the policy).
State = TypeVar("State")


@runtime_checkable
class StreamingModel(Protocol[State]):
    """A model that streams frames with an explicit state.

    Attributes:
        config: the model's :class:`~cosemdepth.models.config.ModelConfig` (architecture, decoders, classes).
        decoders: its decoders' registered names, in order (a mapping keyed by them is one).
        operating_point: the model folder's :class:`~cosemdepth.operating_point.OperatingPoint` (the focal length and
            motion it was trained with), or None.
    """

    config: ModelConfig
    operating_point: Optional[OperatingPoint]

    @property
    def decoders(self) -> Collection[str]: ...

    def parameters(self) -> Iterator[torch.nn.Parameter]:
        """The weights (their device and dtype are the model's)."""
        ...

    def step(
        self,
        rgb: torch.Tensor,
        rot: torch.Tensor,
        trans: torch.Tensor,
        intrinsics: torch.Tensor,
        reset: Optional[torch.Tensor] = None,
        state: Optional[State] = None,
        decoders: Optional[Sequence[str]] = None,
        guide_depth: Optional[torch.Tensor] = None,
    ) -> tuple[StepOutput, State]:
        """The streaming step: one frame per sample, the state in and a new one out.

        Args:
            rgb: ``[B, 3, H, W]`` in [0, 1].
            rot: ``[B, 4]`` quaternion (w, x, y, z); trans: ``[B, 3]`` metres; relative motion previous -> current in
                camera axes, ``X_prev = R X_curr + t`` (ignored for samples that reset).
            intrinsics: ``[B, 4]`` = (fx, fy, cx, cy) in pixels of the input size.
            reset: ``[B]`` bool, True where a sample starts a new trajectory (None: no reset).
            state: the state returned by the previous call, or None for a fresh start (every sample resets).
            decoders: run only these decoders (names of :attr:`decoders`, e.g. ``("semantic",)``); the state of the
                others passes through unchanged (default: all), and so does that of a temporal semantic decoder when
                the depth decoder does not run (its state is of the frame the depth state holds; design 6.3).
            guide_depth: ``[B, 1, H, W]`` the frame's ground-truth depth (metres), for a model whose semantic decoder
                warps with it (``config.needs_depth_input``); refused otherwise.
        Returns:
            ``(out, new_state)``: ``out.depth [B,1,H,W]`` metres and ``out.semantic [B,N,H,W]`` probabilities at the
            input size (nearest upsampling of the finest level), ``out.heads`` every decoder's, ``out.levels`` the
            per-level maps (where the implementation has them); ``out.valid`` ``[B,1,H,W]`` the depth pixels that are
            estimates, ``out.status`` per sample ``"reset"``, ``"estimated"`` or ``"held"`` and ``out.baseline``.
        """
        ...

    def infer(
        self,
        frames: Any,
        motions: Any,
        intrinsics: Any,
        reset: Optional[torch.Tensor] = None,
        guide_depth: Optional[torch.Tensor] = None,
    ) -> StepOutput:
        """A whole sequence streamed with :meth:`step`, every frame's full-resolution outputs.

        Args:
            frames: ``[T, 3, H, W]`` or ``[B, T, 3, H, W]`` in [0, 1] (numpy arrays accepted).
            motions: ``(rot [.., T, 4], trans [.., T, 3])`` or one ``[.., T, 7]`` tensor ``(qw qx qy qz tx ty tz)``;
                the motion of frame 0 is ignored.
            intrinsics: ``[4]`` or ``[B, 4]`` (fx, fy, cx, cy) at the frame size.
            reset: optional ``[T]`` / ``[B, T]`` bool; frame 0 always resets.
            guide_depth: ``[T, 1, H, W]`` / ``[B, T, 1, H, W]`` ground-truth depth (``config.needs_depth_input``).
        Returns:
            :class:`~cosemdepth.models.outputs.StepOutput` whose ``depth`` is ``[.., T, 1, H, W]`` and ``semantic``
            ``[.., T, N, H, W]`` (and ``heads`` every decoder's output), without per-level maps.
        """
        ...


def model_config(model: StreamingModel, what: str = "this") -> ModelConfig:
    """``model.config``; a :class:`~cosemdepth.errors.ConfigError` naming ``what`` (the command that needs it) when
    ``model`` has no :class:`~cosemdepth.models.config.ModelConfig` there."""
    cfg = getattr(model, "config", None)
    if cfg is None or not hasattr(cfg, "decoders"):
        raise ConfigError(f"{what} needs a cosemdepth model with a ModelConfig in .config, got {type(model).__name__}")
    return cfg


def model_device(model: StreamingModel) -> torch.device:
    """The device of ``model``'s weights (the CPU for a model without any)."""
    for p in model.parameters():
        return p.device
    return torch.device("cpu")


def model_dtype(model: StreamingModel) -> torch.dtype:
    """The dtype of ``model``'s first floating-point weight (float32 without any)."""
    for p in model.parameters():
        if p.is_floating_point():
            return p.dtype
    return torch.float32


__all__ = ["State", "StreamingModel", "model_config", "model_device", "model_dtype"]
