"""The Co-SemDepth model family: a shared encoder and registered decoders (see :mod:`.registry`)."""

from .depth_decoder import DepthDecoder, DepthLevel
from .encoder import DINL, Encoder
from .layers import Refiner
from .model import MODELS, CoSemDepth, CoSemDepthT, M4Depth, M4Semantic, SceneModel, build_model
from .outputs import SequenceOutput, StepOutput, StreamState
from .protocol import StreamingModel
from .pyramid import LevelOps, PyramidDecoder, PyramidLevel
from .registry import DECODERS, register_architecture, register_decoder
from .semantic_decoder import SemanticDecoder, SemanticLevel

__all__ = [
    "DECODERS",
    "DINL",
    "MODELS",
    "CoSemDepth",
    "CoSemDepthT",
    "DepthDecoder",
    "DepthLevel",
    "Encoder",
    "LevelOps",
    "M4Depth",
    "M4Semantic",
    "PyramidDecoder",
    "PyramidLevel",
    "Refiner",
    "SceneModel",
    "SemanticDecoder",
    "SemanticLevel",
    "SequenceOutput",
    "StepOutput",
    "StreamState",
    "StreamingModel",
    "build_model",
    "register_architecture",
    "register_decoder",
]
