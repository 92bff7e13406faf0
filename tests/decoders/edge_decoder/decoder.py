"""The edge decoder's module: a stateless pyramid whose level refiner sees the level's features and the coarser
level's edge map; a sigmoid gives the edge strength in ``[0, 1]``."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from cosemdepth.models.layers import Refiner
from cosemdepth.models.pyramid import PyramidDecoder, PyramidLevel


@dataclass
class EdgeLevelOutput:
    edge: torch.Tensor


class EdgeLevel(PyramidLevel):
    """The refiner sees the level's features and the coarser level's edge map."""

    def __init__(self, level, channels, cfg):
        super().__init__()
        self.level = level
        self.refiner = Refiner(channels + 1, 1)

    def coarse_inputs(self, coarse, f_hat, ops):
        b, _, h, w = f_hat.shape
        return EdgeLevelOutput(f_hat.new_zeros((b, 1, h, w)) if coarse is None else ops.nearest(coarse.edge, (h, w)))

    def refine(self, f_hat, inputs, frame, prev, ops):
        return EdgeLevelOutput(torch.sigmoid((ops.refiner or self.refiner)(ops.concat([f_hat, inputs.edge]))))


class EdgeDecoder(PyramidDecoder):
    level_class = EdgeLevel
    maps = {"edge": "edge"}
    head = "edge"
