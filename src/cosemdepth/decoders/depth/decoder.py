"""M4Depth depth decoder (design 5): per level a parallax-sweeping cost volume, a spatial cost volume, time recurrence
through the previous depth, level memory, a refiner and the parallax -> depth decoding."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ...geometry.camera import level_intrinsics
from ...geometry.parallax import (
    PARALLAX_EPS,
    candidate_sample_points,
    epipolar_geometry,
    parallax_to_depth,
    prev_depth_to_parallax,
)
from ...geometry.rotation import quaternion_to_matrix
from ...models.config import ModelConfig
from ...models.layers import Refiner
from ...models.pyramid import LevelOps, PyramidDecoder, PyramidLevel
from ...ops.resample import resize_bl1

#: Parallax hypotheses rho_in + k, k = -SEARCH..SEARCH (design 5.5.2).
SEARCH_RANGE = 4
SNCV_RADIUS = 3
#: Depth of the initial / reset state (metres) and the clip of the decoded log-parallax.
INIT_DEPTH = 1000.0
LOG_PARALLAX_CLIP = 7.0


def groups_at_level(level: int, subdivision: bool = True) -> int:
    """K_l = 2^floor(l / 2) channel groups at absolute level l (1 without feature subdivision)."""
    return 2 ** (level // 2) if subdivision else 1


def refiner_in_channels(level: int, cfg: ModelConfig) -> int:
    k = groups_at_level(level, cfg.feature_subdivision)
    n_cand = 2 * SEARCH_RANGE + 1
    n_sncv = (2 * SNCV_RADIUS + 1) ** 2
    return n_cand * k + 1 + 4 * cfg.level_memory + n_sncv * k * cfg.sncv + 1 * cfg.time_recurrence


@dataclass
class DepthLevelOutput:
    """One depth-decoder level for one frame: ``parallax``, ``depth`` ``[B,1,h,w]``, ``other`` ``[B,4,h,w]``."""

    parallax: torch.Tensor
    depth: torch.Tensor
    other: torch.Tensor


@dataclass(frozen=True)
class DepthFrame:
    """Per-frame context of the depth levels: rotation matrix, translation, intrinsics and numerics switches."""

    rot: torch.Tensor
    trans: torch.Tensor
    intrinsics: torch.Tensor
    guard: bool
    pscv_half: bool


class DepthLevel(PyramidLevel):
    """One level l (absolute, 1 = finest) of the depth decoder."""

    #: the fast path keeps the features NCHW, as both cost volumes read them, and takes the epipolar distances with
    #: ``hypot``
    fast_ops = {"layout": torch.Tensor.contiguous, "hypot": True}

    def __init__(self, level: int, channels: int, cfg: ModelConfig):
        super().__init__()
        self.level = level
        self.channels = channels
        self.groups = groups_at_level(level, cfg.feature_subdivision)
        if channels % self.groups:
            raise ValueError(f"level {level}: {channels} channels not divisible into {self.groups} groups")
        self.normalize = cfg.feature_normalization
        self.use_sncv = cfg.sncv
        self.use_time = cfg.time_recurrence
        self.use_memory = cfg.level_memory
        self.scale = 2.0 ** (level - 3)  # parallax unit of the log inputs/outputs: level-3 pixels
        self.refiner = Refiner(refiner_in_channels(level, cfg), 5)

    def coarse_inputs(self, coarse: DepthLevelOutput | None, like: torch.Tensor, ops: LevelOps) -> DepthLevelOutput:
        """``(rho_in, depth_in, other_in)`` from the coarser level (BL1) or the constant init (design 5.3)."""
        b, _, h, w = like.shape
        if coarse is None:
            ones = like.new_ones(b, 1, h, w)
            return DepthLevelOutput(ones, ones * INIT_DEPTH, like.new_zeros(b, 4, h, w))
        size = (h, w)
        return DepthLevelOutput(
            2.0 * resize_bl1(coarse.parallax, size), resize_bl1(coarse.depth, size), resize_bl1(coarse.other, size)
        )

    def refine(
        self,
        f_hat: torch.Tensor,
        inputs: DepthLevelOutput,
        frame: DepthFrame,
        prev: tuple[torch.Tensor, torch.Tensor],
        ops: LevelOps,
    ) -> DepthLevelOutput:
        """The normal branch (design 5.5); ``prev`` is the previous frame's (features, depth) at this level."""
        guard = frame.guard
        rho_in, other_in = inputs.parallax, inputs.other
        prev_feat, prev_depth = prev
        h, w = f_hat.shape[-2:]
        geom = epipolar_geometry(
            h, w, frame.rot, frame.trans, level_intrinsics(frame.intrinsics, self.level), guard=guard, hypot=ops.hypot
        )
        # Previous frame's depth as parallax w.r.t. the current frame, on the previous grid (stop-gradient).
        prev_para = prev_depth_to_parallax(prev_depth, frame.trans, geom.intrinsics, guard=guard).detach()
        offsets = torch.arange(-SEARCH_RANGE, SEARCH_RANGE + 1, device=rho_in.device, dtype=rho_in.dtype)
        candidates = (rho_in + offsets.view(1, -1, 1, 1)).clamp(1e-6, 1e6)  # [B,9,h,w]
        points = candidate_sample_points(candidates, geom)
        prev_block = torch.cat([prev_feat, prev_para], dim=1)
        pscv, warped_para = ops.pscv(f_hat, prev_block, points, self.groups, frame.pscv_half)
        blocks = [pscv, torch.log(self._guard(rho_in, guard) * self.scale)]
        if self.use_memory:
            blocks.append(other_in)
        if self.use_sncv:
            blocks.append(ops.sncv(f_hat, self.groups, SNCV_RADIUS))
        if self.use_time:
            tau = warped_para[:, SEARCH_RANGE : SEARCH_RANGE + 1]  # the unshifted hypothesis
            blocks.append(torch.log(self._guard(tau, guard) * self.scale))
        y = (ops.refiner or self.refiner)(ops.concat(blocks))
        parallax = torch.exp(y[:, :1].clamp(-LOG_PARALLAX_CLIP, LOG_PARALLAX_CLIP)) / self.scale
        depth = parallax_to_depth(parallax, geom, guard=guard)
        return DepthLevelOutput(parallax, depth, y[:, 1:5])

    def next_state(self, f_hat: torch.Tensor, out: DepthLevelOutput) -> tuple[torch.Tensor, torch.Tensor]:
        return f_hat, out.depth

    def reset_state(self, f_hat: torch.Tensor, inputs: DepthLevelOutput) -> tuple[torch.Tensor, torch.Tensor]:
        return f_hat, torch.full_like(inputs.depth, INIT_DEPTH)

    @staticmethod
    def _guard(x: torch.Tensor, guard: bool) -> torch.Tensor:
        return x.clamp_min(PARALLAX_EPS) if guard else x


class DepthDecoder(PyramidDecoder):
    """The M4Depth decoder pyramid: temporal, with state ``feat`` (the normalised features) and ``depth`` per level.

    Attributes (besides ``guard`` and ``static`` of :class:`PyramidDecoder`):
        pscv_half: compute the PSCV products in float16 like the original (default False: float32).
    """

    level_class = DepthLevel
    state_names = ("feat", "depth")
    maps = {"depth": "depth", "parallax": "parallax", "depth_other": "other"}
    head = "depth"

    def __init__(self, cfg: ModelConfig):
        super().__init__(cfg)
        self.pscv_half = False

    def frame(
        self, rot: torch.Tensor, trans: torch.Tensor, intrinsics: torch.Tensor, fresh=None, guide=None
    ) -> DepthFrame:
        return DepthFrame(quaternion_to_matrix(rot), trans, intrinsics, self.guard, self.pscv_half)

    def level_state_shapes(self, level: DepthLevel, batch: int, h: int, w: int) -> tuple[tuple[int, ...], ...]:
        return (batch, level.channels, h, w), (batch, 1, h, w)
