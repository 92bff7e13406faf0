"""The Co-SemDepth model family: a shared encoder and registered decoders (see :mod:`.registry`; the built-in
decoders are the folders of :mod:`cosemdepth.decoders`, found through the registry, never imported from here)."""

from .encoder import DINL, Encoder
from .layers import Refiner
from .model import SceneModel, build_model
from .outputs import SequenceOutput, StepOutput, StreamState
from .protocol import StreamingModel
from .pyramid import LevelOps, PyramidDecoder, PyramidLevel
from .registry import ARCHITECTURES, DECODERS, register_architecture

__all__ = [
    "ARCHITECTURES",
    "DECODERS",
    "DINL",
    "Encoder",
    "LevelOps",
    "PyramidDecoder",
    "PyramidLevel",
    "Refiner",
    "SceneModel",
    "SequenceOutput",
    "StepOutput",
    "StreamState",
    "StreamingModel",
    "build_model",
    "register_architecture",
]
