"""The depth decoder in the official TF checkpoints: its refiners' scope (``disp_refiner``) and the ablation switches
its refiners' input channels determine."""

from __future__ import annotations

import itertools
from typing import Any

from ...checkpoints.tf_decoders import Shapes, TfDecoder
from ...errors import CheckpointError
from ...models.config import ModelConfig
from .decoder import refiner_in_channels


def _ablation_config(sncv: bool, time_recurrence: bool, level_memory: bool, subdivision: bool) -> ModelConfig:
    return ModelConfig(
        arch="m4depth",
        sncv=sncv,
        time_recurrence=time_recurrence,
        level_memory=level_memory,
        feature_subdivision=subdivision,
    )


def infer_depth_ablations(c_ins: list[int], origin: str) -> tuple[bool, bool, bool, bool]:
    """``(sncv, time_recurrence, level_memory, feature_subdivision)`` matching the refiner input channels."""
    matches = [
        combo
        for combo in itertools.product((True, False), repeat=4)
        if all(refiner_in_channels(j + 1, _ablation_config(*combo)) == c for j, c in enumerate(c_ins))
    ]
    if not matches:
        raise CheckpointError(
            f"{origin}: depth refiner input channels {c_ins} (finest level first) match no combination of the "
            "SNCV / time recurrence / level memory / feature subdivision switches (design 5.1): not an M4Depth decoder"
        )
    # Several matches only when they are indistinguishable (e.g. 1 level: K = 1 with or without subdivision);
    # the first one in product order is the one with the most switches on, i.e. the defaults.
    return matches[0]


def depth_config(shapes: Shapes, levels: int, origin: str) -> dict[str, Any]:
    """The depth ablations from the refiners' input channels ``9K + 1 + 4·[level memory] + 49K·[SNCV] + [time
    recurrence]`` with ``K = 2^floor(l/2)`` (1 without feature subdivision) at absolute level ``l``."""
    c_ins = []
    for j in range(levels):
        first = shapes.get(f"depth_decoder.levels.{j}.refiner.convs.0.weight")
        if first is None or len(first) != 4:
            raise CheckpointError(f"{origin}: the first conv of depth refiner level {j} is missing or not a kernel")
        c_ins.append(int(first[2]))
    sncv, tr, lm, sub = infer_depth_ablations(c_ins, origin)
    return dict(sncv=sncv, time_recurrence=tr, level_memory=lm, feature_subdivision=sub)


#: the depth decoder's TF names: refiners under ``disp_refiner``, the ablation switches from their shapes
TF_NAMES = TfDecoder("disp_refiner", depth_config)
