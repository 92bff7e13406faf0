"""The operating point of a set of weights: the camera and the motion the model was trained with.

M4Depth turns parallax (pixels) into depth with the camera's translation. Parallax in pixels and the apparent size of
everything scale with the focal length in pixels, and the parallax of a frame scales with the translation between
frames: a model is only valid near the focal length and the per-frame motion it was trained with. A model folder
records both (``config.json`` key ``"operating_point"``); this module is their typed form, below every other layer.

``config.json``::

    "operating_point": {
        "size": [H, W],                 # input size of the training images (pixels)
        "focal_px": [fx, fy],           # focal length in pixels of that size
        "step_translation_m": {         # per-step camera translation ||t|| of the training windows (metres)
            "count": N, "mean": ..., "median": ..., "p05": ..., "p25": ..., "p75": ..., "p95": ...},
        "source": "..."                 # where the figures come from (a training run, Mid-Air's split CSVs...)
    }
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

from .errors import ConfigError

#: The statistics of :class:`MotionStats`, in the order written.
MOTION_KEYS = ("count", "mean", "median", "p05", "p25", "p75", "p95")
#: A requested input size whose focal length (pixels) differs from the model's by more than this factor, either way,
#: gets a warning (:meth:`OperatingPoint.size_warning`).
FOCAL_WARN_FACTOR = 1.25


def size_for_focal(native_size: Sequence[int], native_focal_px: float, focal_px: float) -> tuple[int, int]:
    """The input size ``(H', W')`` at which an image of ``native_size = (H, W)`` with horizontal focal length
    ``native_focal_px`` (pixels) has the focal length ``focal_px``: both sides scaled by ``s = focal_px /
    native_focal_px`` and rounded half up (the aspect ratio is kept), at least 1 pixel each."""
    h, w = (int(v) for v in native_size)
    if not (math.isfinite(native_focal_px) and native_focal_px > 0 and math.isfinite(focal_px) and focal_px > 0):
        raise ConfigError(f"focal lengths must be positive, got {native_focal_px!r} and {focal_px!r}")
    s = focal_px / native_focal_px
    return max(1, math.floor(h * s + 0.5)), max(1, math.floor(w * s + 0.5))


@dataclass(frozen=True)
class MotionStats:
    """Distribution of the per-step camera translation ``||t||`` (metres) over the training windows."""

    count: int
    mean: float
    median: float
    p05: float
    p25: float
    p75: float
    p95: float

    @classmethod
    def from_samples(cls, norms: Sequence[float]) -> "MotionStats":
        """Statistics of translation norms (metres); at least one sample."""
        import numpy as np

        x = np.asarray(list(norms), dtype=np.float64)
        x = x[np.isfinite(x)]
        if x.size == 0:
            raise ConfigError("motion statistics need at least one finite translation")
        q = np.quantile(x, [0.05, 0.25, 0.5, 0.75, 0.95])
        return cls(int(x.size), float(x.mean()), float(q[2]), float(q[0]), float(q[1]), float(q[3]), float(q[4]))

    def to_dict(self) -> dict[str, float | int]:
        return {k: getattr(self, k) for k in MOTION_KEYS}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "MotionStats":
        if not isinstance(d, Mapping):
            raise ConfigError(f"step_translation_m must be a mapping, got {type(d).__name__}")
        missing = [k for k in MOTION_KEYS if k not in d]
        if missing:
            raise ConfigError(f"step_translation_m lacks {missing}")
        vals = {k: d[k] for k in MOTION_KEYS}
        if not isinstance(vals["count"], int) or vals["count"] < 1:
            raise ConfigError(f"step_translation_m.count must be a positive integer, got {vals['count']!r}")
        for k in MOTION_KEYS[1:]:
            v = vals[k]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ConfigError(f"step_translation_m.{k} must be a finite number >= 0, got {v!r}")
            vals[k] = float(v)
        return cls(**vals)


@dataclass(frozen=True)
class OperatingPoint:
    """The input size, focal length (pixels) and per-step motion a model was trained with."""

    size: tuple[int, int]
    focal_px: tuple[float, float]
    step_translation: MotionStats | None = None
    source: str = ""
    extra: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        h, w = self.size
        if not all(isinstance(v, int) and v > 0 for v in (h, w)):
            raise ConfigError(f"operating_point.size must be two positive integers, got {list(self.size)}")
        if not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in self.focal_px):
            raise ConfigError(f"operating_point.focal_px must be two positive numbers, got {list(self.focal_px)}")

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view (degrees) of a centred pinhole of this size and focal length."""
        return math.degrees(2 * math.atan(self.size[1] / (2 * self.focal_px[0])))

    @classmethod
    def for_hfov(cls, size: tuple[int, int], hfov_deg: float, **kw) -> "OperatingPoint":
        """A centred pinhole of ``size`` (H, W) with square pixels and horizontal FOV ``hfov_deg``."""
        f = size[1] / (2 * math.tan(math.radians(hfov_deg) / 2))
        return cls((int(size[0]), int(size[1])), (f, f), **kw)

    @property
    def focal(self) -> float:
        """The horizontal focal length in pixels (the one the size rule matches)."""
        return float(self.focal_px[0])

    def input_size(self, native_size: Sequence[int], native_focal_px: float) -> tuple[int, int]:
        """The size to run the model at on an input of ``native_size`` (H, W) whose horizontal focal length is
        ``native_focal_px``: the model's focal length, the input's aspect ratio (:func:`size_for_focal`)."""
        return size_for_focal(native_size, native_focal_px, self.focal)

    def focal_ratio(self, focal_px: float) -> float:
        """``max(f / f_model, f_model / f)`` of an input's horizontal focal length ``f`` (pixels): 1 = the model's."""
        r = float(focal_px) / self.focal
        return max(r, 1 / r) if r > 0 else math.inf

    def size_warning(
        self, size: Sequence[int], focal_px: float, what: str = "--size", default_size: Sequence[int] | None = None
    ) -> str | None:
        """A one-line warning when running at ``size`` (H, W), where the input's horizontal focal length is
        ``focal_px``, is more than :data:`FOCAL_WARN_FACTOR` away from the model's focal length; else None.
        ``default_size``: the size the same input runs at without ``what``, as the command picks it (said when
        given)."""
        if self.focal_ratio(focal_px) <= FOCAL_WARN_FACTOR:
            return None
        h, w = size
        default = (
            "" if default_size is None else f" (without {what} this input runs at {default_size[0]}x{default_size[1]})"
        )
        return (
            f"warning: {what} {h}x{w} gives a focal length of {focal_px:.1f} px, but the model was trained at "
            f"{self.focal:.1f} px ({self.size[0]}x{self.size[1]}); parallax and apparent sizes scale with it, "
            f"so expect worse depth{default}"
        )

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"size": list(self.size), "focal_px": [float(v) for v in self.focal_px]}
        if self.step_translation is not None:
            d["step_translation_m"] = self.step_translation.to_dict()
        if self.source:
            d["source"] = self.source
        return {**self.extra, **d}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "OperatingPoint":
        if not isinstance(d, Mapping):
            raise ConfigError(f"operating_point must be a mapping, got {type(d).__name__}")
        try:
            size = tuple(int(v) for v in d["size"])
            focal = tuple(float(v) for v in d["focal_px"])
        except (KeyError, TypeError, ValueError) as e:
            raise ConfigError(f"operating_point needs size [H, W] and focal_px [fx, fy] ({e})") from None
        if len(size) != 2 or len(focal) != 2:
            raise ConfigError(
                f"operating_point size and focal_px need two values each, got {d.get('size')!r}, {d.get('focal_px')!r}"
            )
        motion = d.get("step_translation_m")
        extra = {k: v for k, v in d.items() if k not in ("size", "focal_px", "step_translation_m", "source")}
        return cls(
            size, focal, None if motion is None else MotionStats.from_dict(motion), str(d.get("source", "")), extra
        )


__all__ = ["FOCAL_WARN_FACTOR", "MOTION_KEYS", "MotionStats", "OperatingPoint", "size_for_focal"]
