"""M4Semantic segmentation decoder (design 6): per level, the encoder features with the upsampled class probabilities
and "other" channels of the coarser level go through a refiner; softmax gives the probabilities.

Two optional inputs of the paper's architecture study (design 6.3, ``ModelConfig.semantic_sncv`` and
``semantic_time``): a spatial cost volume of the features, and the previous frame's probabilities at the level,
warped into the current frame with a depth (the ground truth's, or the model's own: Co-SemDepth-T) and the motion,
with their validity.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import torch

from ...geometry.camera import level_intrinsics
from ...geometry.correspondence import previous_points
from ...geometry.parallax import epipolar_geometry
from ...geometry.rotation import quaternion_to_matrix
from ...geometry.warp import sample_bilinear
from ...models.config import SEMANTIC_TIME_GT, SEMANTIC_TIME_OFF, SEMANTIC_TIME_OWN, ModelConfig
from ...models.layers import Refiner
from ...models.pyramid import GT_DEPTH, LevelOps, PyramidDecoder, PyramidLevel

#: Search range of the semantic decoder's spatial cost volume (7x7 window, as the depth decoder's; one group).
SEMANTIC_SNCV_RADIUS = 3
#: The level map a temporal semantic decoder warps with (``PyramidDecoder.reads``): the depth decoder's depth of
#: the same frame and level ("own"), or the ground-truth depth resized to the level ("gt",
#: :func:`~cosemdepth.models.pyramid.depth_pyramid`).
GUIDE_MAPS = {SEMANTIC_TIME_OWN: "depth", SEMANTIC_TIME_GT: GT_DEPTH}


def semantic_refiner_inputs(channels: int, cfg: ModelConfig) -> tuple[tuple[str, int], ...]:
    """The blocks of a semantic refiner's input, ``(name, channels)`` in the order :meth:`SemanticLevel.refine`
    concatenates them: the coarser level's probabilities (N) and "other" channels (4), the level's features
    (``channels``), then the cost volume (49, ``semantic_sncv``) and the warped previous probabilities and their
    validity (N, 1; a ``semantic_time``). The optional blocks come last, so a model with a switch turned on holds the
    inputs of the model without it as its leading channels (:mod:`cosemdepth.training.init` relies on it)."""
    n = cfg.num_classes
    blocks = [("probs", n), ("other", 4), ("features", channels)]
    if cfg.semantic_sncv:
        blocks.append(("sncv", (2 * SEMANTIC_SNCV_RADIUS + 1) ** 2))
    if cfg.semantic_time != SEMANTIC_TIME_OFF:
        blocks += [("previous_probs", n), ("previous_valid", 1)]
    return tuple(blocks)


def semantic_refiner_in_channels(level: int, channels: int, cfg: ModelConfig) -> int:
    """``N + 4 + C_l`` plus 49 with ``semantic_sncv`` plus ``N + 1`` (warped probabilities, validity) with a
    ``semantic_time`` (design 6.3, :func:`semantic_refiner_inputs`); ``level`` is unused (one group at every level)."""
    return sum(c for _, c in semantic_refiner_inputs(channels, cfg))


@dataclass
class SemanticLevelOutput:
    """One semantic-decoder level for one frame: ``probs``/``logits`` ``[B,N,h,w]``, ``other`` ``[B,4,h,w]``."""

    probs: torch.Tensor
    logits: torch.Tensor
    other: torch.Tensor


@dataclass(frozen=True)
class SemanticFrame:
    """Per-frame context of a temporal semantic decoder.

    Attributes:
        rot: ``[B, 3, 3]`` rotation, trans ``[B, 3]``, intrinsics ``[B, 4]`` (input size): the motion from the frame
            the state holds to this one.
        fresh: ``[B]`` bool, samples without a previous frame (a reset, no state); None: none.
        depth: per level (finest first) ``[B, 1, h_l, w_l]`` the depth to warp with, or None: the depth decoder did
            not run on this frame (a frame the streaming policy holds), the warp follows the rotation alone.
    """

    rot: torch.Tensor
    trans: torch.Tensor
    intrinsics: torch.Tensor
    fresh: Optional[torch.Tensor]
    depth: Optional[Sequence[torch.Tensor]]


def fuse_previous(probs: torch.Tensor, warped: torch.Tensor, valid: torch.Tensor, weight: float) -> torch.Tensor:
    """``(1 - a V) P + a V W``: the probabilities ``P`` averaged with the warped previous ones ``W`` where the warp is
    valid (``V`` = 1), untouched elsewhere (``ModelConfig.semantic_fusion``).

    Args:
        probs: ``[B, N, h, w]`` this frame's probabilities.
        warped: ``[B, N, h, w]`` the previous output warped into this frame, zero where not valid.
        valid: ``[B, 1, h, w]`` 1 where the warp is valid, else 0.
        weight: ``a`` in [0, 1).
    Returns:
        ``[B, N, h, w]``, each pixel's probabilities summing to one as ``P``'s and ``W``'s do.
    """
    return torch.lerp(probs, warped.to(probs.dtype), valid.to(probs.dtype) * weight)


class SemanticLevel(PyramidLevel):
    """One level l (absolute, 1 = finest) of the semantic decoder."""

    def __init__(self, level: int, channels: int, cfg: ModelConfig):
        super().__init__()
        self.level = level
        self.channels = channels
        self.num_classes = cfg.num_classes
        self.normalize = cfg.feature_normalization
        self.use_sncv = cfg.semantic_sncv
        self.time = cfg.semantic_time
        #: the output's running-average weight (``ModelConfig.semantic_fusion``): the finest level only
        self.fusion = cfg.semantic_fusion if level == 1 else 0.0
        self.refiner = Refiner(semantic_refiner_in_channels(level, channels, cfg), cfg.num_classes + 4)

    def coarse_inputs(
        self, coarse: SemanticLevelOutput | None, f_hat: torch.Tensor, ops: LevelOps
    ) -> SemanticLevelOutput:
        """The coarser level's probabilities and "other" channels (NN1 upsampling), or the one-hot of the last class
        ("others") and zeros at the coarsest level; ``logits`` are not used as inputs (the probabilities stand in)."""
        n = self.num_classes
        b, _, h, w = f_hat.shape
        if coarse is None:
            probs_in = f_hat.new_zeros(b, n, h, w)
            probs_in[:, n - 1] = 1.0
            return SemanticLevelOutput(probs_in, probs_in, f_hat.new_zeros(b, 4, h, w))
        probs_in = ops.nearest(coarse.probs, (h, w))
        return SemanticLevelOutput(probs_in, probs_in, ops.nearest(coarse.other, (h, w)))

    def refine(
        self, f_hat, inputs: SemanticLevelOutput, frame: Optional[SemanticFrame], prev, ops: LevelOps
    ) -> SemanticLevelOutput:
        blocks = [inputs.probs, inputs.other, f_hat]
        if self.use_sncv:
            blocks.append(ops.sncv(f_hat, 1, SEMANTIC_SNCV_RADIUS))
        previous = None
        if self.time != SEMANTIC_TIME_OFF:
            previous = self.previous_probs(f_hat, frame, None if prev is None else prev[0])
            blocks.extend(previous)
        y = (ops.refiner or self.refiner)(ops.concat(blocks))
        logits = y[:, : self.num_classes]
        probs = torch.softmax(logits, dim=1)
        if self.fusion and previous is not None:
            probs = fuse_previous(probs, *previous, self.fusion)
        return SemanticLevelOutput(probs, logits, y[:, self.num_classes :])

    def previous_probs(
        self, f_hat: torch.Tensor, frame: SemanticFrame, prev: Optional[torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(V * warped [B, N, h, w], V [B, 1, h, w])``: the previous probabilities of this level sampled (bilinear)
        where the current pixels' points were in the previous frame (design 2.6), and their validity ``V`` (1: the
        point is in front of both cameras and lands inside the previous view; 0 elsewhere and on every pixel of a
        sample without a previous frame). Neither the probabilities nor the depth carry gradients."""
        b, _, h, w = f_hat.shape
        dtype = f_hat.dtype
        if prev is None:
            return f_hat.new_zeros(b, self.num_classes, h, w), f_hat.new_zeros(b, 1, h, w)
        depth = None if frame.depth is None else frame.depth[self.level - 1].detach().to(dtype)
        geom = epipolar_geometry(
            h,
            w,
            frame.rot.to(dtype),
            frame.trans.to(dtype),
            level_intrinsics(frame.intrinsics.to(dtype), self.level),
            guard=False,
        )
        points, ok = previous_points(depth, geom)
        if frame.fresh is not None:
            ok = ok & ~frame.fresh.view(-1, 1, 1, 1).to(ok.device)
        valid = ok.to(dtype)
        warped = sample_bilinear(prev.detach().to(dtype), points)
        return warped * valid, valid

    def next_state(self, f_hat: torch.Tensor, out: SemanticLevelOutput) -> tuple[torch.Tensor, ...]:
        return (out.probs,) if self.time != SEMANTIC_TIME_OFF else ()


class SemanticDecoder(PyramidDecoder):
    """The M4Semantic decoder pyramid; per frame (as the released code) unless ``semantic_time`` is set: then
    temporal, with state ``semantic`` (the level's probabilities of the frame the depth state holds) and the depth
    map of ``reads`` of the same frame as an input (design 6.3)."""

    level_class = SemanticLevel
    maps = {"semantic": "probs", "semantic_logits": "logits", "semantic_other": "other"}
    head = "semantic"
    #: a reset empties the temporal input; the level still predicts (the semantic decoder predicts every frame)
    refines_resets = True

    def __init__(self, cfg: ModelConfig):
        super().__init__(cfg)
        self.time = cfg.semantic_time
        if self.time != SEMANTIC_TIME_OFF:
            self.state_names = ("semantic",)
            self.reads = (GUIDE_MAPS[self.time],)
            # the state is the semantics of the frame whose depth the depth decoder's state holds (the reference
            # frame of a streaming policy): it moves on only when the depth decoder runs
            self.state_follows = "depth" if "depth" in cfg.decoders else None
        self.num_classes = cfg.num_classes

    def frame(self, rot, trans, intrinsics, fresh=None, guide=None) -> SemanticFrame:
        depth = None if guide is None else guide.get(self.reads[0])
        return SemanticFrame(quaternion_to_matrix(rot), trans, intrinsics, fresh, depth)

    def level_state_shapes(self, level: SemanticLevel, batch: int, h: int, w: int) -> tuple[tuple[int, ...], ...]:
        return ((batch, self.num_classes, h, w),) if self.temporal else ()
