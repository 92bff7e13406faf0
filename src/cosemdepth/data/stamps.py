"""Time units of stamps: image file names and pose-file timestamps in seconds, milliseconds, microseconds or
nanoseconds, read as seconds.

A side (the image names, or the pose file's timestamps) is read in the unit the user gives, else in the unit that
makes every one of its stamps a date between 2000 and 2100 (stamps since 1970, as ROS, EuRoC and most loggers write
them: the four units' ranges of such dates do not overlap), else in seconds (stamps counted from some start).
When stamps fail to match, :func:`unit_hint` says how each side was read and which ``--stamp-unit`` would match them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import ConfigError

#: unit -> seconds per unit
UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
#: powers of ten of the units (integer stamps are converted exactly: ``int / 10**k`` is correctly rounded)
_DIGITS = {"s": 0, "ms": 3, "us": 6, "ns": 9}
#: stamps since 1970 that are dates from 2000-01-01 to 2100-01-01 UTC, in seconds
EPOCH_RANGE_S = (946684800.0, 4102444800.0)
#: median step between consecutive stamps that is plausible for a camera or a pose source, in seconds
#: (at most 500 Hz, at least one every minute); used only to suggest a unit, never to choose one
PLAUSIBLE_STEP_S = (2e-3, 60.0)


def parse_stamp_unit(text: str) -> tuple[str, str]:
    """``--stamp-unit``: ``"auto"``, one unit for both sides (``"ns"``), or ``"IMAGES,POSES"`` (``"ns,s"``) ->
    ``(image_unit, pose_unit)``, each ``"auto"`` or a key of :data:`UNITS`."""
    parts = [p.strip().lower() for p in str(text).split(",")]
    if len(parts) == 1:
        parts = parts * 2
    choices = ("auto", *UNITS)
    if len(parts) != 2 or any(p not in choices for p in parts):
        raise ConfigError(f"--stamp-unit must be one of {', '.join(choices)} or IMAGES,POSES (e.g. ns,s), got {text!r}")
    return parts[0], parts[1]


def parse_stamp(text: str) -> int | float | None:
    """A file stem as a stamp: an ``int`` when it is all digits (kept exact: 19-digit nanosecond stamps do not fit
    a float64), a finite ``float`` when it is another number, else None."""
    if text.isdigit():
        return int(text)
    try:
        v = float(text)
    except ValueError:
        return None
    return v if math.isfinite(v) else None


def epoch_unit(values: Sequence[float]) -> str | None:
    """The unit in which every value is a date from 2000 to 2100 (a stamp since 1970), or None."""
    if not len(values):
        return None
    lo, hi = min(values), max(values)
    for unit, scale in UNITS.items():
        if EPOCH_RANGE_S[0] <= lo * scale and hi * scale <= EPOCH_RANGE_S[1]:
            return unit
    return None


@dataclass(frozen=True)
class StampSide:
    """One side's stamps read as seconds: ``what`` ("image names", "pose stamps"), ``unit``, ``how`` it was chosen
    (``"given"``, ``"epoch"``: the only unit in which they are dates 2000-2100, ``"assumed"``: seconds by default),
    ``raw`` the values as written and ``seconds`` [N] float64."""

    what: str
    unit: str
    how: str
    raw: tuple
    seconds: np.ndarray

    def describe(self) -> str:
        """e.g. ``"image names 0..3e+09 read as s (assumed: not dates in any unit)"``."""
        how = {
            "given": "given",
            "epoch": "stamps since 1970 in that unit",
            "assumed": "the default: not dates 2000-2100 in any unit",
        }[self.how]
        return f"{self.what} {_g(min(self.raw))}..{_g(max(self.raw))} read as {self.unit} ({how})"


def read_side(values: Sequence[int | float], unit: str, what: str) -> StampSide:
    """``values`` (as written) in ``unit`` (``"auto"``: see the module docstring) -> a :class:`StampSide`."""
    if unit == "auto":
        found = epoch_unit(values)
        unit, how = (found, "epoch") if found is not None else ("s", "assumed")
    elif unit in UNITS:
        how = "given"
    else:
        raise ConfigError(f"stamp unit must be 'auto' or one of {list(UNITS)}, got {unit!r}")
    return StampSide(what, unit, how, tuple(values), to_seconds(values, unit))


def to_seconds(values: Sequence[int | float], unit: str) -> np.ndarray:
    """``values`` in ``unit`` -> seconds, float64 (integers divided exactly, then rounded once)."""
    k = _DIGITS[unit]
    return np.array([v / 10**k if isinstance(v, int) else float(v) * UNITS[unit] for v in values], dtype=np.float64)


def posed_count(image_s: np.ndarray, pose_s: np.ndarray, max_gap: float, exact: float = 1e-6) -> int:
    """How many of the times ``image_s`` get a pose from poses at ``pose_s`` (sorted): one within ``exact`` s, or
    two around it at most ``max_gap`` s apart (the rule of :func:`cosemdepth.data.poses.poses_at`)."""
    k = np.searchsorted(pose_s, image_s)
    before = np.where(k > 0, pose_s[np.maximum(k - 1, 0)], -np.inf)
    after = np.where(k < len(pose_s), pose_s[np.minimum(k, len(pose_s) - 1)], np.inf)
    near = np.minimum(np.abs(image_s - before), np.abs(after - image_s)) <= exact
    with np.errstate(invalid="ignore"):
        between = (k > 0) & (k < len(pose_s)) & (after - before <= max_gap + 1e-9)
    return int((near | between).sum())


def median_step(seconds: np.ndarray) -> float | None:
    return float(np.median(np.diff(seconds))) if len(seconds) > 1 else None


def unit_hint(images: StampSide, poses: StampSide, max_gap: float) -> str:
    """How the two sides were read and, when other units would give more images a pose, the ``--stamp-unit`` that
    gives the most (ties: the units closest to those read); ``""`` when no other units do better."""
    now = posed_count(images.seconds, poses.seconds, max_gap)
    current = (images.unit, poses.unit)
    candidates = []
    for ui in UNITS:
        for up in UNITS:
            if (ui, up) == current:
                continue
            img = to_seconds(images.raw, ui)
            pose = to_seconds(poses.raw, up)
            if not _plausible(img) or not _plausible(pose):
                continue
            changed = (ui != images.unit) + (up != poses.unit)
            candidates.append((-posed_count(img, pose, max_gap), changed, ui, up))
    best, best_units = now, None
    if candidates and -min(candidates)[0] > now:
        neg, _, ui, up = min(candidates)
        best, best_units = -neg, (ui, up)
    read = f"{images.describe()}; {poses.describe()}"
    step = median_step(poses.seconds)
    if step is not None:
        read += f", one every {_g(step)} s (median)"
    if best_units is None:
        return f"{read}; no other units match more images (other clocks? then match by order or index)"
    ui, up = best_units
    flag = ui if ui == up else f"{ui},{up}"
    return (
        f"{read}; read as image names in {ui} and pose stamps in {up}, {best} of {len(images.raw)} images "
        f"would have a pose: pass --stamp-unit {flag}"
    )


def _plausible(seconds: np.ndarray) -> bool:
    step = median_step(seconds)
    return step is None or PLAUSIBLE_STEP_S[0] <= step <= PLAUSIBLE_STEP_S[1]


def _g(v: float) -> str:
    return f"{v:.10g}" if isinstance(v, float) else str(v)


__all__ = [
    "EPOCH_RANGE_S",
    "StampSide",
    "UNITS",
    "epoch_unit",
    "parse_stamp",
    "parse_stamp_unit",
    "posed_count",
    "read_side",
    "to_seconds",
    "unit_hint",
]
