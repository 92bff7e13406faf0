"""The semantic decoder (M4Semantic, design 6), in one folder: its module (:mod:`.decoder`: :class:`SemanticDecoder`,
the weights ``semantic_decoder.*``), its task (:mod:`.task`: the cross-entropy, mIoU and the labels' temporal
consistency, the ``predict`` files and pictures, ground truth ``"semantic"``), its names in the official TF
checkpoints (:mod:`.tf_names`), and the one registration below, which also declares the architectures that use it:
``m4semantic`` (alone), ``cosemdepth`` (after the depth decoder) and ``cosemdepth-t`` (the same, its previous labels
warped with its own depth: ``semantic_time="own"``, design 6.3)."""

from ...models.config import SEMANTIC_TIME_OWN
from ...tasks import register_decoder
from .decoder import SemanticDecoder, SemanticFrame, SemanticLevel, SemanticLevelOutput
from .task import LabelsWriter, SemanticTask, SemanticTaskMetrics
from .tf_names import TF_NAMES

#: the semantic decoder's task, registered under the decoder name "semantic" with its module, architectures and TF
#: names
SEMANTIC = register_decoder(
    SemanticTask(),
    {
        "cosemdepth": ("depth", "semantic"),
        "m4semantic": ("semantic",),
        "cosemdepth-t": (("depth", "semantic"), {"semantic_time": SEMANTIC_TIME_OWN}),
    },
    tf=TF_NAMES,
)

__all__ = [
    "LabelsWriter",
    "SEMANTIC",
    "SemanticDecoder",
    "SemanticFrame",
    "SemanticLevel",
    "SemanticLevelOutput",
    "SemanticTask",
    "SemanticTaskMetrics",
    "TF_NAMES",
]
