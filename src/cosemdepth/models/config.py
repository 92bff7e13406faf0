"""The model config: the architecture's choices (:class:`ModelConfig`) and the paper's image size.

The lowest layer of the configuration: it imports nothing but :mod:`cosemdepth.errors`, :mod:`cosemdepth.coerce`
and the decoder registry (:mod:`cosemdepth.models.registry`, where the architectures are), so every layer that reads
a model config (the models, ``data``, ``checkpoints``, the CLI) may import it. A model folder's ``config.json`` is
read with :meth:`ModelConfig.from_dict` (the typed coercer); the run config (:mod:`cosemdepth.training.config`)
holds one as its ``model`` section.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass
from typing import Any, Literal, Mapping, Optional

from ..coerce import from_mapping
from ..errors import ConfigError
from .registry import ARCHITECTURE_FIELDS, ARCHITECTURES, architecture_of

#: ``ModelConfig.semantic_time``: the semantic decoder's temporal input ``S^{t-1}`` (design 6.3): none (the released
#: code), the previous frame's labels warped with the ground-truth depth (the paper's ablation; training and
#: evaluation only) or with the model's own depth (Co-SemDepth-T).
SemanticTime = Literal["off", "gt", "own"]
SEMANTIC_TIMES = typing.get_args(SemanticTime)
SEMANTIC_TIME_OFF, SEMANTIC_TIME_GT, SEMANTIC_TIME_OWN = SEMANTIC_TIMES

#: Encoder output channels per absolute level (design 4.1); a model with L levels uses the first L entries.
ENCODER_CHANNELS = (16, 32, 64, 96, 128, 192)

#: Precisions of the parallax-sweeping cost-volume products (``ModelConfig.pscv_dtype``); the original computes them
#: in float16, so converted official checkpoints use it to reproduce the original's numbers.
PscvDtype = Literal["float32", "float16"]
PSCV_DTYPES = typing.get_args(PscvDtype)
ORIGINAL_PSCV_DTYPE = "float16"

#: Mid-Air camera: 90 degree horizontal FOV, so f = W/2 and c = (W/2, H/2) (design 2.1).
MIDAIR_IMAGE_SIZE = 384


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of a Co-SemDepth-family model.

    ``arch`` selects the joint model or one of its single-task siblings, or Co-SemDepth-T (``"cosemdepth-t"``:
    Co-SemDepth with ``semantic_time="own"``). The depth decoder's boolean switches are the ablations of the original
    code; all on is the paper's model. ``semantic_sncv`` and ``semantic_time`` are the paper's two additions to the
    semantic decoder (its architecture study; off in the released code and the paper's model, design 6.3).
    """

    arch: str = "cosemdepth"
    levels: int = 5
    num_classes: int = 7
    dinl: bool = True
    sncv: bool = True
    time_recurrence: bool = True
    feature_normalization: bool = True
    feature_subdivision: bool = True
    level_memory: bool = True
    #: Precision of the parallax-sweeping cost-volume products: "float32", or "float16" as the original computes
    #: them (converted official checkpoints use float16 so that they reproduce the original's numbers).
    pscv_dtype: PscvDtype = "float32"
    #: Semantic decoder: a spatial cost volume of the level's features (7x7, one group) beside them in the refiner
    #: input (the paper's "+SNCV").
    semantic_sncv: bool = False
    #: Semantic decoder: the previous frame's class probabilities at each level, warped into the current frame, in
    #: the refiner input: "off", "gt" (warped with the ground-truth depth: the paper's "+S^{t-1}"; the depth is an
    #: input of every forward pass) or "own" (with the model's own depth: Co-SemDepth-T). None: the architecture's
    #: (``ARCHITECTURE_FIELDS``, else "off").
    semantic_time: Optional[SemanticTime] = None
    #: Semantic decoder with a ``semantic_time``: the weight ``a`` in [0, 1) of the warped previous output in the
    #: output, ``P_t = (1 - a) softmax(logits_t) + a W(P_{t-1})`` on the finest level's pixels whose warp is valid
    #: (a motion-compensated running average of the labels' probabilities; it has no parameters, and the loss reads
    #: the logits). 0 (default): the output is the softmax.
    semantic_fusion: float = 0.0

    def __post_init__(self) -> None:
        if self.arch not in ARCHITECTURES:
            raise ConfigError(f"model arch must be one of {tuple(ARCHITECTURES)}, got {self.arch!r}")
        for name, value in ARCHITECTURE_FIELDS.get(self.arch, {}).items():
            got = getattr(self, name)
            if got is None:
                object.__setattr__(self, name, value)
            elif got != value:
                other = architecture_of(ARCHITECTURES[self.arch])
                raise ConfigError(
                    f"model arch {self.arch!r} has {name} {value!r}, got {got!r}"
                    + (f"; use arch {other!r} for another {name}" if other not in (None, self.arch) else "")
                )
        if self.semantic_time is None:
            object.__setattr__(self, "semantic_time", SEMANTIC_TIME_OFF)
        if self.semantic_time not in SEMANTIC_TIMES:
            raise ConfigError(
                f"model semantic_time must be one of {', '.join(map(repr, SEMANTIC_TIMES))}, got {self.semantic_time!r}"
            )
        decoders = ARCHITECTURES[self.arch]
        if "semantic" not in decoders and (self.semantic_sncv or self.semantic_time != SEMANTIC_TIME_OFF):
            raise ConfigError(f"model semantic_sncv and semantic_time: the {self.arch} model has no semantic decoder")
        if self.semantic_time == SEMANTIC_TIME_OWN and "depth" not in decoders:
            raise ConfigError(
                f"model semantic_time 'own' warps with the model's own depth: the {self.arch} model has "
                "no depth decoder (use 'gt', or arch 'cosemdepth-t')"
            )
        fusion = self.semantic_fusion
        if isinstance(fusion, bool) or not isinstance(fusion, (int, float)) or not 0.0 <= fusion < 1.0:
            raise ConfigError(f"model semantic_fusion must be a number in [0, 1), got {fusion!r}")
        object.__setattr__(self, "semantic_fusion", float(fusion))
        if fusion and self.semantic_time == SEMANTIC_TIME_OFF:
            raise ConfigError(
                "model semantic_fusion averages the output with the warped previous output of a temporal semantic "
                "decoder: it needs semantic_time 'own' (arch 'cosemdepth-t') or 'gt'"
            )
        if not isinstance(self.levels, int) or not 1 <= self.levels <= len(ENCODER_CHANNELS):
            raise ConfigError(f"model levels must be an integer in 1..{len(ENCODER_CHANNELS)}, got {self.levels!r}")
        if not isinstance(self.num_classes, int) or self.num_classes < 2:
            raise ConfigError(f"model num_classes must be an integer >= 2, got {self.num_classes!r}")
        if self.pscv_dtype not in PSCV_DTYPES:
            raise ConfigError(
                f"model pscv_dtype must be {' or '.join(map(repr, PSCV_DTYPES))}, got {self.pscv_dtype!r}"
            )

    @property
    def decoders(self) -> tuple[str, ...]:
        """The decoders of this architecture, in order."""
        return ARCHITECTURES[self.arch]

    @property
    def has_depth(self) -> bool:
        return "depth" in self.decoders

    @property
    def has_semantic(self) -> bool:
        return "semantic" in self.decoders

    @property
    def needs_depth_input(self) -> bool:
        """Whether every forward pass needs the ground-truth depth of its frames (``semantic_time="gt"``)."""
        return self.semantic_time == SEMANTIC_TIME_GT

    @property
    def encoder_channels(self) -> tuple[int, ...]:
        return ENCODER_CHANNELS[: self.levels]

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], prefix: str = "model") -> "ModelConfig":
        """Build from a (partial) dict, e.g. the ``"model"`` entry of a ``config.json``: missing keys take the
        defaults, values are converted to the field types (:func:`cosemdepth.coerce.from_mapping`); unknown keys and
        bad values raise :class:`ConfigError` naming the key (``prefix.key``)."""
        if d is None:
            raise ConfigError(f"{prefix} must be a mapping of keys to values, got null")
        return from_mapping(cls, d, prefix)


__all__ = [
    "ARCHITECTURES",
    "SEMANTIC_TIMES",
    "SEMANTIC_TIME_GT",
    "SEMANTIC_TIME_OFF",
    "SEMANTIC_TIME_OWN",
    "ENCODER_CHANNELS",
    "MIDAIR_IMAGE_SIZE",
    "ModelConfig",
    "ORIGINAL_PSCV_DTYPE",
    "PSCV_DTYPES",
    "PscvDtype",
    "SemanticTime",
]
