"""M4Semantic segmentation decoder (spec 5): per level, the encoder features with the upsampled class probabilities
and "other" channels of the coarser level go through a refiner; softmax gives the probabilities."""

from __future__ import annotations

import torch
import torch.nn as nn

from ..config import ModelConfig
from ..ops.normalize import grouped_l2_normalize
from ..ops.resample import resize_nn1
from .layers import Refiner
from .outputs import SemanticLevelOutput


class SemanticLevel(nn.Module):
    """One level l (absolute, 1 = finest) of the semantic decoder."""

    def __init__(self, level: int, channels: int, cfg: ModelConfig):
        super().__init__()
        self.level = level
        self.num_classes = cfg.num_classes
        self.normalize = cfg.feature_normalization
        self.refiner = Refiner(cfg.num_classes + 4 + channels, cfg.num_classes + 4)

    def forward(self, feat: torch.Tensor, coarse: SemanticLevelOutput | None, guard: bool = True) -> SemanticLevelOutput:
        n = self.num_classes
        f_hat = grouped_l2_normalize(feat, 1, guard=guard) if self.normalize else feat
        b, _, h, w = feat.shape
        if coarse is None:
            probs_in = feat.new_zeros(b, n, h, w)
            probs_in[:, n - 1] = 1.0  # one-hot of the last class ("others")
            other_in = feat.new_zeros(b, 4, h, w)
        else:
            probs_in = resize_nn1(coarse.probs, (h, w))
            other_in = resize_nn1(coarse.other, (h, w))
        y = self.refiner(torch.cat([probs_in, other_in, f_hat], dim=1))
        logits = y[:, :n]
        return SemanticLevelOutput(torch.softmax(logits, dim=1), logits, y[:, n:])


class SemanticDecoder(nn.Module):
    """The M4Semantic decoder pyramid, run coarse -> fine; per frame, no temporal input (as the released code)."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.levels = nn.ModuleList(
            SemanticLevel(l, c, cfg) for l, c in enumerate(cfg.encoder_channels, start=1)
        )
        self.guard = True

    def forward(self, feats: list[torch.Tensor]) -> list[SemanticLevelOutput]:
        outs: list[SemanticLevelOutput | None] = [None] * len(self.levels)
        coarse = None
        for j in range(len(self.levels) - 1, -1, -1):
            coarse = outs[j] = self.levels[j](feats[j], coarse, self.guard)
        return outs
