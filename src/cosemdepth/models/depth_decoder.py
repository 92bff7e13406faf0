"""M4Depth depth decoder (spec 4): per level a parallax-sweeping cost volume, a spatial cost volume, time recurrence
through the previous depth, level memory, a refiner and the parallax -> depth decoding."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable, Optional

import torch
import torch.nn as nn

from ..config import ModelConfig
from ..geometry.camera import level_intrinsics
from ..geometry.parallax import (
    PARALLAX_EPS,
    EpipolarGeometry,
    candidate_sample_points,
    epipolar_geometry,
    parallax_to_depth,
    prev_depth_to_parallax,
)
from ..geometry.rotation import quaternion_to_matrix
from ..ops.cost_volume import parallax_sweep_cost_volume, spatial_cost_volume
from ..ops.normalize import grouped_l2_normalize
from ..ops.resample import resize_bl1
from .layers import Refiner
from .outputs import DepthLevelOutput

#: Parallax hypotheses rho_in + k, k = -SEARCH..SEARCH (spec 4.6.2).
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


@dataclass(frozen=True)
class RefineOps:
    """The operations of a depth level's normal branch that an inference engine may replace by equivalents.

    Attributes:
        pscv: ``(feat, prev, points, groups, half) -> (pscv, warped_parallax)`` (see ``parallax_sweep_cost_volume``).
        sncv: ``(feat, groups, radius) -> volume`` (see ``spatial_cost_volume``).
        concat: ``blocks -> refiner input`` (channel concatenation).
        refiner: ``x -> y`` or None for the level's own :class:`Refiner`.
    """

    pscv: Callable = parallax_sweep_cost_volume
    sncv: Callable = spatial_cost_volume
    concat: Callable = functools.partial(torch.cat, dim=1)
    refiner: Optional[Callable] = None


_REFERENCE_OPS = RefineOps()


class DepthLevel(nn.Module):
    """One level l (absolute, 1 = finest) of the depth decoder."""

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

    def prepare(self, feat: torch.Tensor, guard: bool) -> torch.Tensor:
        """Grouped L2 normalisation of the encoder features (spec 4.3)."""
        return grouped_l2_normalize(feat, self.groups, guard=guard) if self.normalize else feat

    def coarse_inputs(
        self, coarse: DepthLevelOutput | None, like: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(rho_in, depth_in, other_in)`` from the coarser level (BL1 upsampling) or the constant init (spec 4.4)."""
        b, _, h, w = like.shape
        if coarse is None:
            ones = like.new_ones(b, 1, h, w)
            return ones, ones * INIT_DEPTH, like.new_zeros(b, 4, h, w)
        size = (h, w)
        return 2.0 * resize_bl1(coarse.parallax, size), resize_bl1(coarse.depth, size), resize_bl1(coarse.other, size)

    def refine(
        self,
        f_hat: torch.Tensor,
        rho_in: torch.Tensor,
        other_in: torch.Tensor,
        geom: EpipolarGeometry,
        prev_feat: torch.Tensor,
        prev_depth: torch.Tensor,
        trans: torch.Tensor,
        guard: bool,
        pscv_half: bool,
        ops: Optional["RefineOps"] = None,
    ) -> DepthLevelOutput:
        """The normal branch (spec 4.6). ``ops`` swaps the cost volumes, the concatenation and the refiner for
        equivalent implementations (the fast inference engine); None: the reference ones."""
        ops = ops or _REFERENCE_OPS
        # Previous frame's depth as parallax w.r.t. the current frame, on the previous grid (stop-gradient).
        prev_para = prev_depth_to_parallax(prev_depth, trans, geom.intrinsics, guard=guard).detach()
        offsets = torch.arange(-SEARCH_RANGE, SEARCH_RANGE + 1, device=rho_in.device, dtype=rho_in.dtype)
        candidates = (rho_in + offsets.view(1, -1, 1, 1)).clamp(1e-6, 1e6)  # [B,9,h,w]
        points = candidate_sample_points(candidates, geom)
        pscv, warped_para = ops.pscv(f_hat, torch.cat([prev_feat, prev_para], dim=1), points, self.groups, pscv_half)
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

    @staticmethod
    def _guard(x: torch.Tensor, guard: bool) -> torch.Tensor:
        return x.clamp_min(PARALLAX_EPS) if guard else x


class DepthDecoder(nn.Module):
    """The M4Depth decoder pyramid, run coarse -> fine, one frame at a time with explicit per-level state.

    Attributes:
        guard: protect the degenerate cases of spec 3.4 (default True; results on normal inputs are unchanged).
        pscv_half: compute the PSCV products in float16 like the original (default False: float32).
        static: never branch on the reset mask (always run the refiners and select per sample); for graph capture and
            export. The default skips the refiners when every sample resets.
    """

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.levels = nn.ModuleList(
            DepthLevel(l, c, cfg) for l, c in enumerate(cfg.encoder_channels, start=1)
        )
        self.guard = True
        self.pscv_half = False
        self.static = False

    def forward(
        self,
        feats: list[torch.Tensor],
        rot: torch.Tensor,
        trans: torch.Tensor,
        intrinsics: torch.Tensor,
        prev_feats: tuple[torch.Tensor, ...] | None,
        prev_depths: tuple[torch.Tensor, ...] | None,
        reset: torch.Tensor | None,
    ) -> tuple[list[DepthLevelOutput], tuple[torch.Tensor, ...], tuple[torch.Tensor, ...]]:
        """Decode one frame.

        Args:
            feats: encoder features, finest first, ``[B, C_l, h_l, w_l]``.
            rot, trans: ``[B, 4]``, ``[B, 3]`` relative motion previous -> current.
            intrinsics: ``[B, 4]`` at the network input size.
            prev_feats, prev_depths: the state of the previous frame (None: no previous frame, every sample resets).
            reset: ``[B]`` bool, samples that start a new trajectory (None: no sample resets).
        Returns:
            per-level outputs (finest first), the new state's features and depths.
        """
        if prev_feats is None:
            all_reset, any_reset = True, True
        elif reset is None:
            all_reset, any_reset = False, False
        elif self.static:
            all_reset, any_reset = False, True
        else:
            all_reset, any_reset = bool(reset.all()), bool(reset.any())
        R = quaternion_to_matrix(rot)
        outs: list[DepthLevelOutput | None] = [None] * len(self.levels)
        new_feats: list[torch.Tensor | None] = [None] * len(self.levels)
        new_depths: list[torch.Tensor | None] = [None] * len(self.levels)
        coarse = None
        for j in range(len(self.levels) - 1, -1, -1):
            lvl: DepthLevel = self.levels[j]
            f_hat = lvl.prepare(feats[j], self.guard)
            rho_in, depth_in, other_in = lvl.coarse_inputs(coarse, f_hat)
            init = DepthLevelOutput(rho_in, depth_in, other_in)
            if all_reset:
                out = init
                state_depth = torch.full_like(depth_in, INIT_DEPTH)
            else:
                h, w = f_hat.shape[-2:]
                geom = epipolar_geometry(h, w, R, trans, level_intrinsics(intrinsics, lvl.level), guard=self.guard)
                out = lvl.refine(
                    f_hat, rho_in, other_in, geom, prev_feats[j], prev_depths[j], trans, self.guard, self.pscv_half
                )
                state_depth = out.depth
                if any_reset:
                    m = reset.view(-1, 1, 1, 1)
                    out = DepthLevelOutput(
                        torch.where(m, init.parallax, out.parallax),
                        torch.where(m, init.depth, out.depth),
                        torch.where(m, init.other, out.other),
                    )
                    state_depth = torch.where(m, torch.full_like(state_depth, INIT_DEPTH), state_depth)
            outs[j], new_feats[j], new_depths[j] = out, f_hat, state_depth
            coarse = out
        return outs, tuple(new_feats), tuple(new_depths)
