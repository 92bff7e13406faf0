"""The Co-SemDepth model family."""

from .depth_decoder import DepthDecoder, DepthLevel
from .encoder import DINL, Encoder
from .layers import Refiner
from .model import MODELS, CoSemDepth, M4Depth, M4Semantic, SceneModel, build_model
from .outputs import SequenceOutput, StepOutput, StreamState
from .semantic_decoder import SemanticDecoder, SemanticLevel

__all__ = [
    "DINL",
    "MODELS",
    "CoSemDepth",
    "DepthDecoder",
    "DepthLevel",
    "Encoder",
    "M4Depth",
    "M4Semantic",
    "Refiner",
    "SceneModel",
    "SemanticDecoder",
    "SemanticLevel",
    "SequenceOutput",
    "StepOutput",
    "StreamState",
    "build_model",
]
