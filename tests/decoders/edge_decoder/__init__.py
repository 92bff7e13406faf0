"""A third decoder defined outside the package, as a plugin folder (``COSEMDEPTH_PLUGINS=edge_decoder``): a
stateless pyramid that predicts the edge strength of the scene, ``e = g / (1 + g)`` with ``g`` the magnitude of the
log-depth gradient (forward differences, zero on the last row / column), so its ground truth comes from the depth
every dataset with depth has. The folder holds its module (``decoder.py``), its task (``task.py``) and the one
registration below, which also declares the architecture ``depth-edge`` (depth + edge); the official TF checkpoints
do not hold it."""

from cosemdepth.tasks import register_decoder

from .decoder import EdgeDecoder, EdgeLevel, EdgeLevelOutput
from .task import EdgeMetrics, EdgeTask, EdgeWriter, edge_strength

#: the architecture of the encoder with the depth and edge decoders
ARCH = "depth-edge"

#: the edge decoder's task, registered with its module and its architecture
EDGE = register_decoder(EdgeTask(), {ARCH: ("depth", "edge")})

__all__ = [
    "ARCH",
    "EDGE",
    "EdgeDecoder",
    "EdgeLevel",
    "EdgeLevelOutput",
    "EdgeMetrics",
    "EdgeTask",
    "EdgeWriter",
    "edge_strength",
]
