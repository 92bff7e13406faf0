"""Baseline-aware streaming: which frame a depth is estimated against, and what a frame without parallax gets.

M4Depth turns parallax into depth with the camera's translation since the frame its state holds. With no translation
(a hovering drone, a yaw in place) there is no parallax and the depth is undefined; with much less translation than the
model was trained with, the parallax is small and the depth poor. The paper's protocol estimates every frame from the
previous one (policy ``every-frame``). Policy ``baseline`` keeps a *reference frame* instead:

* the network's state is the reference frame's, and the network is given the motion composed from the reference to
  the current frame;
* a frame whose translation from the reference is at least ``min_baseline`` is estimated against it (status
  ``estimated``) and becomes the new reference;
* a frame closer to the reference is *held*: the reference's depth carried into the current view
  (:func:`cosemdepth.geometry.reproject.carry_depth`: rotation and the small translation applied), status ``held``;
  its semantic labels are the current frame's own (the semantic decoder has no temporal input);
* a held frame that sees less than ``min_overlap`` of the reference frame's view (distant points, the rotation from
  the reference: :func:`cosemdepth.geometry.overlap.view_overlap`) *re-anchors*: it becomes the reference, with its
  held depth, and the network's state restarts on it as after a reset (its features, no depth prior). The network's
  state describes the reference's view; after a turn in place most of the current view lies outside it, and an
  estimate made against it, through the whole composed rotation, is far worse than one from a fresh start. A hover
  (no rotation) keeps its reference and the network's own depth chain, which the next estimate continues;
* a reset (first frame, new trajectory) starts a new reference without depth: it and the frames held after it have
  status ``reset`` and nothing valid, until the camera has moved far enough.

The default ``min_baseline`` is 0.75 x the 5th percentile of the per-step translations the model was trained with (the
model folder's operating point, :mod:`cosemdepth.operating_point`): below the smallest baseline the model commonly saw,
so that a flight at the training speed is estimated on every frame (its slowest steps too), while a flight at half
that speed or slower is estimated against a reference frame (docs/motion.md). Every
output carries ``valid`` (the depth pixels that are estimates), ``status`` and ``baseline`` (see
:class:`~cosemdepth.models.outputs.StepOutput`). The state is explicit: a :class:`StreamerState` in, a new one out.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Iterator, Optional, Sequence

import torch

from ..defaults import DEPTH_CAP_M, MIN_DEPTH_M
from ..errors import ConfigError
from ..geometry.motion import baseline, compose_motion, identity_motion
from ..geometry.overlap import view_overlap
from ..geometry.reproject import carry_depth
from ..geometry.validity import MAX_CONDITIONING, depth_validity
from ..models.config import ModelConfig
from ..models.infer import infer_sequence
from ..models.outputs import ESTIMATED, HELD, RESET, StepOutput, StreamState
from ..models.protocol import StreamingModel, model_device
from ..operating_point import OperatingPoint

#: The two streaming policies: ``baseline`` estimates against a reference frame at least ``min_baseline`` away,
#: ``every-frame`` estimates every frame from the previous one (the paper's protocol).
BASELINE, EVERY_FRAME = "baseline", "every-frame"
#: Streaming policies (``--policy``).
POLICIES = (BASELINE, EVERY_FRAME)
#: The default ``min_baseline``: ``MIN_BASELINE_FACTOR`` x this quantile of the training steps' translations (the
#: operating point's ``p05``); calibrated on SynthAir (docs/motion.md).
MIN_BASELINE_STATISTIC = "p05"
MIN_BASELINE_FACTOR = 0.75
#: An estimate more than ``exp(MAX_LOG_RATIO)`` (2x) from the reference's carried depth is not valid: two estimates of
#: the same surface that far apart say that at least one of them is wrong; calibrated on SynthAir (docs/motion.md).
MAX_LOG_RATIO = 0.7
#: A held frame that sees less than this fraction of the reference frame's view (distant points, rotation only:
#: :func:`cosemdepth.geometry.overlap.view_overlap`) becomes the new reference, the network's state restarting on it
#: (docs/motion.md); calibrated on SynthAir.
MIN_OVERLAP = 0.9
#: Depths compared by the consistency check are clipped to this range (metres): beyond FAR_DEPTH both are "far"
#: (the evaluation's cap, design 10.1).
MIN_DEPTH, FAR_DEPTH = MIN_DEPTH_M, DEPTH_CAP_M


@dataclass(frozen=True)
class StreamPolicy:
    """How frames are streamed (see the module docstring).

    Attributes:
        mode: ``"baseline"`` (reference frames chosen by the camera's motion) or ``"every-frame"`` (the paper's).
        min_baseline: metres from the reference before a frame is estimated (``baseline`` mode); None: the model's
            (:func:`default_min_baseline`).
        max_conditioning: the largest inverse-depth error (1/m) per pixel of parallax error of a valid pixel
            (:mod:`cosemdepth.geometry.validity`).
        max_log_ratio: an estimate that differs from the reference frame's depth carried into its view by more than
            ``exp(max_log_ratio)`` is not valid (:func:`inconsistent`).
        min_overlap: a held frame that sees less than this fraction of the reference's view becomes the new
            reference (``baseline`` mode; 0: never).
    """

    mode: str = BASELINE
    min_baseline: Optional[float] = None
    max_conditioning: float = MAX_CONDITIONING
    max_log_ratio: float = MAX_LOG_RATIO
    min_overlap: float = MIN_OVERLAP

    def __post_init__(self) -> None:
        if self.mode not in POLICIES:
            raise ConfigError(f"streaming policy must be one of {', '.join(POLICIES)}, got {self.mode!r}")
        if self.min_baseline is not None and not (
            isinstance(self.min_baseline, (int, float)) and 0 <= self.min_baseline < float("inf")
        ):
            raise ConfigError(f"min_baseline must be a number of metres >= 0, got {self.min_baseline!r}")
        if not self.max_conditioning > 0:
            raise ConfigError(f"max_conditioning must be positive, got {self.max_conditioning!r}")
        if not self.max_log_ratio > 0:
            raise ConfigError(f"max_log_ratio must be positive, got {self.max_log_ratio!r}")
        if not (isinstance(self.min_overlap, (int, float)) and 0 <= self.min_overlap <= 1):
            raise ConfigError(f"min_overlap must be a fraction in [0, 1], got {self.min_overlap!r}")


def default_min_baseline(model: StreamingModel) -> float | None:
    """The ``min_baseline`` (metres) of ``model``: 0.75 x the 5th percentile of its training steps' translations, from its
    ``operating_point``; None when the model folder does not record them."""
    op = getattr(model, "operating_point", None)
    stats = getattr(op, "step_translation", None)
    return None if stats is None else MIN_BASELINE_FACTOR * float(getattr(stats, MIN_BASELINE_STATISTIC))


@dataclass
class StreamerState:
    """The streaming state of :class:`Streamer` (every tensor batch-first).

    Attributes:
        net: the network's state, that of the reference frame (``baseline``) or of the previous frame.
        rot, trans: ``[B, 4]``, ``[B, 3]`` the motion from the reference frame to the last frame.
        depth, valid: ``[B, 1, H, W]`` the reference frame's depth and its validity (None for M4Semantic).
        has_depth: ``[B]`` bool, the reference frame has a depth estimate (False from a reset to the first estimate).
    """

    net: StreamState
    rot: torch.Tensor
    trans: torch.Tensor
    depth: Optional[torch.Tensor]
    valid: Optional[torch.Tensor]
    has_depth: torch.Tensor

    def select(self, rows: Sequence[int]) -> "StreamerState":
        """The state of the samples ``rows`` (in that order)."""
        idx = torch.as_tensor(list(rows), device=self.rot.device, dtype=torch.long)
        pick = lambda t: None if t is None else t.index_select(0, idx.to(t.device))  # noqa: E731
        net = StreamState(**{k: tuple(pick(t) for t in v) for k, v in self.net.components.items()})
        return StreamerState(
            net, pick(self.rot), pick(self.trans), pick(self.depth), pick(self.valid), pick(self.has_depth)
        )

    @property
    def batch_size(self) -> int:
        return int(self.rot.shape[0])


def _where(mask: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Per-sample choice (``mask [B]``) between two batch-first tensors."""
    return torch.where(mask.view(-1, *([1] * (a.dim() - 1))).to(a.device), a, b)


class Streamer:
    """Stream frames through ``model`` under a :class:`StreamPolicy`; ``step`` is the streaming step of
    :class:`~cosemdepth.models.protocol.StreamingModel` with a :class:`StreamerState` (the policy chooses the decoders
    each frame runs, so it takes no ``decoders``). It describes itself as its model does (:attr:`config`,
    :attr:`operating_point`, :meth:`parameters`; :attr:`decoders` their names).

    Args:
        model: a :class:`~cosemdepth.models.protocol.StreamingModel` (any inference path), or a stand-in with its
            ``step`` and ``config``.
        policy: a :class:`StreamPolicy`, or a mode name (``"baseline"``, ``"every-frame"``); None: ``baseline``
            when the model records the motion it was trained with (or ``min_baseline`` is given), else
            ``every-frame`` (whose validity mask still marks the frames without parallax).
        min_baseline: overrides the policy's ``min_baseline`` (metres).
    """

    def __init__(
        self, model: StreamingModel, policy: StreamPolicy | str | None = BASELINE, *, min_baseline: float | None = None
    ):
        if policy is None:
            policy = BASELINE if min_baseline is not None or default_min_baseline(model) is not None else EVERY_FRAME
        if isinstance(policy, str):
            policy = StreamPolicy(mode=policy)
        if min_baseline is not None:
            policy = replace(policy, min_baseline=min_baseline)
        self.model = model
        self.policy = policy
        names = getattr(model, "decoders", None)
        self.decoders = tuple(names) if names is not None else tuple(model.config.decoders)
        self.has_depth = "depth" in self.decoders
        mb = 0.0 if policy.mode == EVERY_FRAME else policy.min_baseline
        if self.has_depth and mb is None:
            mb = default_min_baseline(model)
            if mb is None:
                raise ConfigError(
                    "baseline-aware streaming needs a minimum baseline: this model folder records no "
                    "training motion (operating_point.step_translation_m); give min_baseline "
                    "(--min-baseline METRES) or use the every-frame policy (--policy every-frame)"
                )
        self.min_baseline = mb

    # ------------------------------------------------------------------ what the model is
    @property
    def config(self) -> ModelConfig:
        return self.model.config

    @property
    def operating_point(self) -> Optional[OperatingPoint]:
        return getattr(self.model, "operating_point", None)

    def parameters(self) -> Iterator[torch.nn.Parameter]:
        """The model's parameters."""
        return self.model.parameters()

    # ------------------------------------------------------------------ streaming
    def step(
        self,
        rgb: torch.Tensor,
        rot: torch.Tensor,
        trans: torch.Tensor,
        intrinsics: torch.Tensor,
        reset: Optional[torch.Tensor] = None,
        state: Optional[StreamerState] = None,
        guide_depth: Optional[torch.Tensor] = None,
        *,
        source_valid: Optional[torch.Tensor] = None,
    ) -> tuple[StepOutput, StreamerState]:
        """The streaming step (:class:`~cosemdepth.models.protocol.StreamingModel`) under the policy; ``state`` None
        starts every sample afresh; ``guide_depth`` is handed to the model's step. Returns ``(out, new_state)`` with
        ``out.valid``, ``out.status`` and ``out.baseline``. ``source_valid``: ``[B, 1, H, W]`` (or ``[B, H, W]``)
        bool, the pixels of an undistorted image that have a source pixel (:class:`cosemdepth.camera.Undistorter`);
        the others are never valid, whatever the policy (an estimate or a carried depth there describes
        edge-replicated or black pixels)."""
        guide = {} if guide_depth is None else {"guide_depth": guide_depth}
        b = rgb.shape[0]
        dev = rgb.device
        rot, trans, intrinsics = (x.to(dev, torch.float32) for x in (rot, trans, intrinsics))
        fresh = state is None
        if fresh or reset is None:
            reset = torch.full((b,), fresh, dtype=torch.bool, device=dev)
        reset = reset.to(dev) | fresh
        if not fresh and state.batch_size != b:
            raise ValueError(
                f"state holds {state.batch_size} samples but this frame has {b}; pass state=None to start over"
            )
        net_prev = None if fresh else state.net
        if not self.has_depth:  # M4Semantic: no depth, no policy
            out, net = self.model.step(rgb, rot, trans, intrinsics, reset, net_prev, **guide)
            one, zero = identity_motion(b, dev)
            return out, StreamerState(net, one, zero, None, None, torch.zeros(b, dtype=torch.bool, device=dev))

        # the motion from the reference frame (every-frame: the previous frame) to this one; a reset starts afresh
        one, zero = identity_motion(b, dev)
        if fresh:
            q, t = one, zero
        else:
            q, t = compose_motion(state.rot.to(dev), state.trans.to(dev), rot, trans)
            # the reference is the previous frame: its motion as given, bit for bit (the paper's protocol)
            at_ref = (state.rot.to(dev) == one).all(-1) & (state.trans.to(dev) == 0).all(-1)
            q, t = _where(at_ref, rot, q), _where(at_ref, trans, t)
        q, t = _where(reset, one, q), _where(reset, zero, t)
        base = baseline(t)
        estimate = ~reset & (base >= self.min_baseline)
        # a held frame turned away from the reference re-anchors: it becomes the reference (its depth the carried
        # one) and the network's state restarts on it, as after a reset
        reanchor = ~reset & ~estimate
        if self.policy.mode == BASELINE and self.policy.min_overlap > 0 and bool(reanchor.any()):
            reanchor &= view_overlap(q, intrinsics, *rgb.shape[-2:]).to(dev) < self.policy.min_overlap
        else:
            reanchor = torch.zeros_like(reset)
        restart = reset | reanchor  # the network starts afresh on these samples
        run_depth = restart | estimate
        decoders = None if bool(run_depth.any()) else tuple(n for n in self.decoders if n != "depth")
        if decoders is None:  # a model's plain step (any backend, or a stand-in with only step())
            out, net = self.model.step(rgb, q, t, intrinsics, restart, net_prev, **guide)
        else:
            out, net = self.model.step(rgb, q, t, intrinsics, restart, net_prev, decoders=decoders, **guide)
        if fresh:
            ref_depth, ref_valid = out.depth, torch.zeros_like(out.depth, dtype=torch.bool)
            has_depth = torch.zeros(b, dtype=torch.bool, device=dev)
        else:
            ref_depth, ref_valid, has_depth = state.depth.to(dev), state.valid.to(dev), state.has_depth.to(dev)
        # the reference's depth seen from this frame: the held frames' depth, the estimates' consistency check
        carried, carried_valid = ref_depth, torch.zeros_like(ref_valid)
        if bool(has_depth.any()):
            carried, carried_valid = carry_depth(ref_depth, ref_valid, q, t, intrinsics)
            carried_valid &= has_depth.view(-1, 1, 1, 1)
        if decoders is None:  # the depth decoder ran: its results for the samples that needed it
            new_valid = getattr(out, "valid", None)
            if new_valid is None or self.policy.max_conditioning != MAX_CONDITIONING:
                new_valid = depth_validity(out.depth.float(), q, t, intrinsics, reset, self.policy.max_conditioning)
            new_valid = new_valid & ~inconsistent(out.depth, carried, carried_valid, self.policy.max_log_ratio)
            if not fresh:
                net = StreamState(
                    **{
                        k: tuple(_where(run_depth, n, o) for n, o in zip(v, net_prev.components[k]))
                        for k, v in net.components.items()
                    }
                )
            new_depth = out.depth
        else:
            new_depth, new_valid = ref_depth, ref_valid
        hold = ~(reset | estimate)
        depth = _where(hold, carried, new_depth)
        valid = _where(hold, carried_valid, new_valid)
        if source_valid is not None:
            valid = valid & source_valid.to(device=valid.device, dtype=torch.bool).reshape(valid.shape)
        status = [
            RESET if r else ESTIMATED if e else HELD if h else RESET
            for r, e, h in zip(reset.tolist(), estimate.tolist(), has_depth.tolist())
        ]
        out.heads = {**out.heads, "depth": depth}
        out.valid, out.status, out.baseline = valid, status, _where(reset, torch.zeros_like(base), base)
        # the new reference: this frame where it was estimated, reset or re-anchored (with its held depth)
        new_state = StreamerState(
            net=net,
            rot=_where(run_depth, one, q),
            trans=_where(run_depth, zero, t),
            depth=_where(run_depth, depth, ref_depth),
            valid=_where(run_depth, valid, ref_valid),
            has_depth=torch.where(reset, torch.zeros_like(has_depth), has_depth | estimate),
        )
        return out, new_state

    @torch.no_grad()
    def infer(
        self,
        frames,
        motions,
        intrinsics,
        reset: Optional[torch.Tensor] = None,
        guide_depth: Optional[torch.Tensor] = None,
    ) -> StepOutput:
        """A whole sequence, :meth:`StreamingModel.infer <cosemdepth.models.protocol.StreamingModel.infer>`:
        :meth:`step` in a loop (``out.heads`` as the policy gives them)."""
        return infer_sequence(
            self.step, frames, motions, intrinsics, reset, guide_depth, device=model_device(self), dtype=torch.float32
        )


def policy_info(streamer: Streamer) -> dict:
    """The settings of ``streamer`` as recorded in outputs (``predictions.json``, evaluation reports)."""
    p = streamer.policy
    return {
        "mode": p.mode,
        "min_baseline_m": streamer.min_baseline,
        "max_conditioning": p.max_conditioning,
        "max_log_ratio": p.max_log_ratio,
        "min_overlap": p.min_overlap if p.mode == BASELINE else None,
    }


def inconsistent(
    depth: torch.Tensor, other: torch.Tensor, other_valid: torch.Tensor, max_log_ratio: float
) -> torch.Tensor:
    """``[B, 1, H, W]`` bool: where ``depth`` and a valid ``other`` estimate of the same view (the reference frame's
    depth carried into it) differ by more than a factor ``exp(max_log_ratio)``, both clipped to
    ``[MIN_DEPTH, FAR_DEPTH]`` (two depths beyond ``FAR_DEPTH`` agree: both are far)."""
    a = depth.float().clamp(MIN_DEPTH, FAR_DEPTH)
    o = other.float().clamp(MIN_DEPTH, FAR_DEPTH)
    return other_valid & ((a / o).log().abs() > max_log_ratio)


__all__ = [
    "BASELINE",
    "EVERY_FRAME",
    "POLICIES",
    "StreamPolicy",
    "Streamer",
    "StreamerState",
    "default_min_baseline",
    "policy_info",
]
