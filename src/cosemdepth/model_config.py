"""The model config, the lowest layer of the configuration: the architecture's choices and the paper's image size.

Everything here depends on nothing but :mod:`cosemdepth.errors`, so that any layer (``models``, ``data``, ``io``)
may read it; the run recipe (:mod:`cosemdepth.config`) sits above it and re-exports these names.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping

from .errors import ConfigError

#: Architecture -> the decoders it puts on the shared encoder (names of :data:`cosemdepth.models.registry.DECODERS`;
#: ``cosemdepth.models.registry.register_architecture`` adds entries).
ARCHITECTURES: dict[str, tuple[str, ...]] = {"cosemdepth": ("depth", "semantic"), "m4depth": ("depth",),
                                              "m4semantic": ("semantic",)}

#: Encoder output channels per absolute level (design 4.1); a model with L levels uses the first L entries.
ENCODER_CHANNELS = (16, 32, 64, 96, 128, 192)

#: Precisions of the parallax-sweeping cost-volume products (``ModelConfig.pscv_dtype``); the original computes them
#: in float16, so converted official checkpoints use it to reproduce the original's numbers.
PSCV_DTYPES = ("float32", "float16")
ORIGINAL_PSCV_DTYPE = "float16"

#: Mid-Air camera: 90 degree horizontal FOV, so f = W/2 and c = (W/2, H/2) (design 2.1).
MIDAIR_IMAGE_SIZE = 384


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of a Co-SemDepth-family model.

    ``arch`` selects the joint model or one of its single-task siblings. The boolean switches are the ablations
    of the original code; all on is the paper's model.
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
    pscv_dtype: str = "float32"

    def __post_init__(self) -> None:
        if self.arch not in ARCHITECTURES:
            raise ConfigError(f"model arch must be one of {tuple(ARCHITECTURES)}, got {self.arch!r}")
        if not isinstance(self.levels, int) or not 1 <= self.levels <= len(ENCODER_CHANNELS):
            raise ConfigError(f"model levels must be an integer in 1..{len(ENCODER_CHANNELS)}, got {self.levels!r}")
        if not isinstance(self.num_classes, int) or self.num_classes < 2:
            raise ConfigError(f"model num_classes must be an integer >= 2, got {self.num_classes!r}")
        if self.pscv_dtype not in PSCV_DTYPES:
            raise ConfigError(f"model pscv_dtype must be {' or '.join(map(repr, PSCV_DTYPES))}, got "
                              f"{self.pscv_dtype!r}")

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
    def encoder_channels(self) -> tuple[int, ...]:
        return ENCODER_CHANNELS[: self.levels]

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "ModelConfig":
        return _from_dict(cls, d, "model config")


def _from_dict(cls, d: Mapping[str, Any], what: str):
    if not isinstance(d, Mapping):
        raise ConfigError(f"{what} must be a mapping, got {type(d).__name__}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(d) - names)
    if unknown:
        raise ConfigError(f"unknown {what} key(s) {unknown}; valid keys: {sorted(names)}")
    return cls(**dict(d))


__all__ = ["ARCHITECTURES", "ENCODER_CHANNELS", "MIDAIR_IMAGE_SIZE", "ModelConfig", "ORIGINAL_PSCV_DTYPE", "PSCV_DTYPES"]
