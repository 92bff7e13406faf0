"""The depth decoder (M4Depth, design 5), in one folder: its module (:mod:`.decoder`: :class:`DepthDecoder`, the
weights ``depth_decoder.*``), its task (:mod:`.task`: the log-depth loss, the depth metrics, the ``predict`` files and
pictures, ground truth ``"depth"``), its names in the official TF checkpoints (:mod:`.tf_names`), and the one
registration below, which also declares the architecture made of it alone, ``m4depth``."""

from ...tasks import register_decoder
from .decoder import DepthDecoder, DepthLevel, DepthLevelOutput
from .task import DepthTask, DepthTaskMetrics, DepthWriter, valid_mask
from .tf_names import TF_NAMES

#: the depth decoder's task, registered under the decoder name "depth" with its module, architecture and TF names
DEPTH = register_decoder(DepthTask(), {"m4depth": ("depth",)}, tf=TF_NAMES)

__all__ = [
    "DEPTH",
    "DepthDecoder",
    "DepthLevel",
    "DepthLevelOutput",
    "DepthTask",
    "DepthTaskMetrics",
    "DepthWriter",
    "TF_NAMES",
    "valid_mask",
]
