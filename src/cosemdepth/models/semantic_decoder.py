"""M4Semantic segmentation decoder (design 6): per level, the encoder features with the upsampled class probabilities
and "other" channels of the coarser level go through a refiner; softmax gives the probabilities."""

from __future__ import annotations

import torch

from ..config import ModelConfig
from .layers import Refiner
from .outputs import SemanticLevelOutput
from .pyramid import LevelOps, PyramidDecoder, PyramidLevel


class SemanticLevel(PyramidLevel):
    """One level l (absolute, 1 = finest) of the semantic decoder."""

    def __init__(self, level: int, channels: int, cfg: ModelConfig):
        super().__init__()
        self.level = level
        self.channels = channels
        self.num_classes = cfg.num_classes
        self.normalize = cfg.feature_normalization
        self.refiner = Refiner(cfg.num_classes + 4 + channels, cfg.num_classes + 4)

    def coarse_inputs(self, coarse: SemanticLevelOutput | None, f_hat: torch.Tensor, ops: LevelOps) -> SemanticLevelOutput:
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

    def refine(self, f_hat, inputs: SemanticLevelOutput, frame, prev, ops: LevelOps) -> SemanticLevelOutput:
        y = (ops.refiner or self.refiner)(ops.concat([inputs.probs, inputs.other, f_hat]))
        logits = y[:, : self.num_classes]
        return SemanticLevelOutput(torch.softmax(logits, dim=1), logits, y[:, self.num_classes :])


class SemanticDecoder(PyramidDecoder):
    """The M4Semantic decoder pyramid; per frame, no temporal input (as the released code)."""

    level_class = SemanticLevel
    maps = {"semantic": "probs", "semantic_logits": "logits", "semantic_other": "other"}
    head = "semantic"
