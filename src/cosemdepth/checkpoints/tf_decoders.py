"""The official TensorFlow checkpoints' names of each decoder (:class:`TfDecoder`): the scope of its refiners
(``<root>/levels/{j}/<scope>/(prep|est_*)_conv_layers/{k}``) and the :class:`ModelConfig` fields its weights
determine; the table of them (:data:`TF_DECODERS`, keyed by the decoder's registered name, in the order the fields
are read), which :mod:`cosemdepth.checkpoints.convert` loops over. A decoder without an entry has no TF weights;
:func:`register_tf_decoder` adds one."""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, Callable, Mapping

from ..errors import CheckpointError
from ..models.config import ModelConfig
from ..models.depth_decoder import refiner_in_channels
from ..models.semantic_decoder import semantic_refiner_in_channels

Shapes = Mapping[str, tuple[int, ...]]


@dataclass(frozen=True)
class TfDecoder:
    """A decoder's TF names: ``refiner`` its refiners' scope; ``config(shapes, levels, origin)`` the config fields
    its converted weights determine, from our parameter names and their TF shapes (``[kh, kw, C_in, C_out]``),
    keyed by field (the keys are the fields read from the shapes)."""

    refiner: str
    config: Callable[[Shapes, int, str], dict[str, Any]]


def _ablation_config(sncv: bool, time_recurrence: bool, level_memory: bool, subdivision: bool) -> ModelConfig:
    return ModelConfig(
        sncv=sncv, time_recurrence=time_recurrence, level_memory=level_memory, feature_subdivision=subdivision
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


def infer_semantic_sncv(shapes: Mapping[str, tuple[int, ...]], levels: int, num_classes: int, origin: str) -> bool:
    """``semantic_sncv`` matching the semantic refiners' input channels (design 6.3). The authors' released code
    has neither of the semantic decoder's additions (its SNCV is commented out, its ``S^{t-1}`` helper unused), so its
    checkpoints all read as off; a layout with other channels is refused."""
    c_ins = []
    for j in range(levels):
        first = shapes.get(f"semantic_decoder.levels.{j}.refiner.convs.0.weight")
        if first is None or len(first) != 4:
            raise CheckpointError(f"{origin}: the first conv of semantic refiner level {j} is missing or not a kernel")
        c_ins.append(int(first[2]))
    for sncv in (False, True):
        cfg = ModelConfig(arch="m4semantic", levels=levels, num_classes=num_classes, semantic_sncv=sncv)
        if all(
            semantic_refiner_in_channels(j + 1, c, cfg) == n
            for j, (c, n) in enumerate(zip(cfg.encoder_channels, c_ins))
        ):
            return sncv
    raise CheckpointError(
        f"{origin}: semantic refiner input channels {c_ins} (finest level first) match neither the released semantic "
        "decoder (classes + 4 + features) nor its SNCV variant (design 6.3); a previous-frame input (S^{t-1}) cannot "
        "come from the authors' code, which has none"
    )


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


def semantic_config(shapes: Shapes, levels: int, origin: str) -> dict[str, Any]:
    """The classes from the last conv of the finest refiner (``N + 4`` channels), the SNCV from the refiners' input
    channels (design 6.3)."""
    last = shapes.get("semantic_decoder.levels.0.refiner.convs.6.weight")
    if last is None or len(last) != 4:
        raise CheckpointError(f"{origin}: the last conv of the finest semantic refiner is missing or not a kernel")
    if last[3] - 4 < 2:
        raise CheckpointError(f"{origin}: the last semantic conv has {last[3]} channels; expected classes + 4 >= 6")
    num_classes = int(last[3] - 4)
    return {"num_classes": num_classes, "semantic_sncv": infer_semantic_sncv(shapes, levels, num_classes, origin)}


#: Decoder name -> its TF names, in the order their config fields are read.
TF_DECODERS: dict[str, TfDecoder] = {
    "semantic": TfDecoder("semantic_refiner", semantic_config),
    "depth": TfDecoder("disp_refiner", depth_config),
}


def register_tf_decoder(name: str, names: TfDecoder) -> None:
    """Declare the TF names of the registered decoder ``name``."""
    TF_DECODERS[name] = names


__all__ = [
    "TF_DECODERS",
    "TfDecoder",
    "depth_config",
    "infer_depth_ablations",
    "infer_semantic_sncv",
    "register_tf_decoder",
    "semantic_config",
]
