"""The semantic decoder in the official TF checkpoints: its refiners' scope (``semantic_refiner``), the classes and
the SNCV switch its refiners' shapes determine."""

from __future__ import annotations

from typing import Any, Mapping

from ...checkpoints.tf_decoders import Shapes, TfDecoder
from ...errors import CheckpointError
from ...models.config import ModelConfig
from .decoder import semantic_refiner_in_channels


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


#: the semantic decoder's TF names: refiners under ``semantic_refiner``, the classes and SNCV from their shapes
TF_NAMES = TfDecoder("semantic_refiner", semantic_config)
