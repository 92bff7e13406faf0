"""Which pose of a flight's pose file goes with which of its images (``match``, ``--match``).

* ``"stamp"``: image file stems are stamps (``1305031102.175304.png``, ``1403636579758555392.png``); each image
  takes the pose with the same stamp, or the interpolation of the two poses around it when they are at most
  ``max_gap`` seconds apart. Both sides are read as seconds (:mod:`cosemdepth.data.stamps`: a given unit, else the
  unit in which they are dates since 1970, else seconds), so image names in nanoseconds match a pose file in
  seconds;
* ``"order"``: one pose per image: the n-th pose row (file order) goes with the n-th image (natural sort of names);
* ``"index"``: image stems are frame numbers (``000000.JPEG``) that index the pose rows from 0: image ``k`` takes
  row ``k``; the images may be any subset of the rows (every 4th frame, say);
* ``"auto"`` (default): ``"stamp"`` when every image stem is a number, the stems are not zero-padded frame numbers
  (``000042``), the pose file has timestamps and *every* image stamp lies within the poses' time range (``max_gap``
  beyond either end); else ``"order"`` when there are as many poses as images; else a DatasetError saying what was
  found and which rule might fit; with a ``stamp_unit`` given (the names are meant as stamps), ``"stamp"`` even when the
  stamps do not fit, so that the error says so instead of the order being taken. ``"index"`` is never guessed: frame numbers do not say at which rate the poses
  were written (frame k is row 4k of a 100 Hz track for a 25 Hz camera). The choice and its reason are kept in
  :attr:`PoseMatch.reason` (``predict`` writes them into ``predictions.json`` and its summary line).

An image without a pose (``"stamp"``: no pose near its stamp; ``"index"``: a frame number past the last row) is a
DatasetError naming it, or, with ``skip_unposed``, left out and counted (:attr:`PoseMatch.skipped`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..errors import ConfigError, DatasetError
from .poses import PoseTrack, poses_at
from .stamps import StampSide, parse_stamp, parse_stamp_unit, read_side, unit_hint

MATCHES = ("auto", "stamp", "order", "index")
#: Interpolate an image's pose only between poses at most this many seconds apart (flights; ``--max-pose-gap``).
DEFAULT_MAX_GAP = 0.1


@dataclass
class PoseMatch:
    """The posed images of a flight, in stream order: ``images``, their ``indices`` in the matched order of all
    images, ``positions`` [N, 3] and ``quaternions`` [N, 4] (w, x, y, z), ``times`` [N] in seconds (None when the
    pose file has none); ``skipped`` images without a pose; ``match`` the rule used and ``reason`` why ``"auto"``
    chose it (None when it was given); the stamp sides (``"stamp"`` only) and ``max_gap`` in seconds."""

    match: str
    reason: str | None
    images: list[Path]
    indices: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray
    times: np.ndarray | None
    total: int
    skipped: list[Path] = field(default_factory=list)
    image_stamps: StampSide | None = None
    pose_stamps: StampSide | None = None
    max_gap: float | None = None

    def summary(self) -> dict[str, Any]:
        """What ``predictions.json`` records under ``dataset.pose_matching``."""
        out: dict[str, Any] = {
            "match": self.match,
            "chosen_by": "auto" if self.reason else "--match",
            "reason": self.reason,
            "images": self.total,
            "posed": len(self.images),
            "skipped": len(self.skipped),
        }
        if self.skipped:
            out["first_skipped"] = str(self.skipped[0])
        if self.match == "stamp":
            out["max_pose_gap_s"] = self.max_gap
            for key, side in (("image_stamp_unit", self.image_stamps), ("pose_stamp_unit", self.pose_stamps)):
                out[key] = {"unit": side.unit, "how": side.how}
        return out

    def describe(self) -> str:
        """One line, e.g. ``"16 of 16 images matched to poses by stamp (auto: ...; image names in ns, ...)"``."""
        text = f"{len(self.images)} of {self.total} images matched to poses by {self.match}"
        notes = [f"auto: {self.reason}"] if self.reason else []
        if self.match == "stamp":
            notes.append(
                f"image names in {self.image_stamps.unit}, pose stamps in {self.pose_stamps.unit}, "
                f"interpolation across gaps <= {self.max_gap:g} s"
            )
        if notes:
            text += f" ({'; '.join(notes)})"
        if self.skipped:
            text += f", {len(self.skipped)} skipped without a pose (first: {self.skipped[0].name})"
        return text


def _frame_number_names(stems: Sequence[str]) -> bool:
    """Zero-padded frame numbers: all digits, one width, at least one with a leading zero (``000042``)."""
    return (
        all(s.isdigit() for s in stems)
        and len({len(s) for s in stems}) == 1
        and len(stems[0]) > 1
        and any(s.startswith("0") for s in stems)
    )


def match_images(
    images: Sequence[Path],
    track: PoseTrack,
    *,
    match: str = "auto",
    stamp_unit="auto",
    max_gap: float = DEFAULT_MAX_GAP,
    skip_unposed: bool = False,
) -> PoseMatch:
    """Match ``images`` (naturally sorted) to the poses of ``track`` (see the module docstring). ``stamp_unit``:
    ``"auto"``, a unit of :data:`cosemdepth.data.stamps.UNITS` for both sides, or ``(image_unit, pose_unit)``."""
    if match not in MATCHES:
        raise ConfigError(f"match must be one of {', '.join(MATCHES)}, got {match!r}")
    if not (isinstance(max_gap, (int, float)) and max_gap >= 0):
        raise ConfigError(f"--max-pose-gap must be >= 0 seconds, got {max_gap!r}")
    image_unit, pose_unit = parse_stamp_unit(stamp_unit) if isinstance(stamp_unit, str) else tuple(stamp_unit)
    images = list(images)
    stems = [p.stem for p in images]
    raw = [parse_stamp(s) for s in stems]
    image_side = read_side(raw, image_unit, "image names") if all(v is not None for v in raw) else None
    pose_side = read_side(track.timestamps.tolist(), pose_unit, "pose stamps") if track.timestamps is not None else None
    reason = None
    if match == "auto":
        match, reason = _choose(images, stems, track, image_side, pose_side, max_gap)
        if match == "order" and stamp_unit != "auto" and image_side is not None and pose_side is not None:
            # a stamp unit was given, so the names are meant as stamps: a mismatch is reported, not matched by order
            match, reason = "stamp", f"--stamp-unit {_unit_text(stamp_unit)} given (image names and poses both stamps)"
    if match == "stamp":
        return _by_stamp(images, raw, track, image_side, pose_side, max_gap, skip_unposed, reason)
    times = pose_side.seconds if pose_side is not None else None
    if match == "order":
        if len(track) != len(images):
            why = f"auto: {reason}; " if reason else ""
            raise DatasetError(
                f"{track.path}: {len(track)} poses for {len(images)} images in {images[0].parent} "
                f"({why}--match order needs one pose per image)"
            )
        return PoseMatch(
            "order", reason, images, np.arange(len(images)), track.positions, track.quaternions, times, len(images)
        )
    return _by_index(images, stems, track, times, skip_unposed, reason)


def _unit_text(stamp_unit) -> str:
    return stamp_unit if isinstance(stamp_unit, str) else ",".join(stamp_unit)


def _choose(
    images: list[Path],
    stems: list[str],
    track: PoseTrack,
    image_side: StampSide | None,
    pose_side: StampSide | None,
    max_gap: float,
) -> tuple[str, str]:
    n, rows = len(images), len(track)
    hint = ""
    if image_side is None:
        if not all(s.isdigit() for s in stems):  # neither stamps nor frame numbers: only the order is left
            return "order", "image names are not numbers"
        why = "image names are not all numbers"
    elif pose_side is None:
        why = "the pose file has no timestamps"
    elif _frame_number_names(stems):
        why = "image names are zero-padded frame numbers"
    else:
        lo, hi = pose_side.seconds[0] - max_gap, pose_side.seconds[-1] + max_gap
        outside = int(((image_side.seconds < lo) | (image_side.seconds > hi)).sum())
        if outside == 0:
            return "stamp", "every image name is a stamp within the poses' time range"
        why = f"{outside} of {n} image names are outside the poses' time range as stamps"
        hint = "; " + unit_hint(image_side, pose_side, max_gap)
    if rows == n:
        return "order", f"{why}; one pose per image"
    numbers = [int(s) for s in stems if s.isdigit()]
    past = sum(k >= rows for k in numbers)
    index = (
        "; if image k goes with pose row k (rows numbered from 0), pass --match index"
        + (f" (--skip-unposed leaves out the {past} past the last row)" if past else "")
        if len(numbers) == n and (past == 0 or _frame_number_names(stems))
        else ""
    )
    raise DatasetError(
        f"{track.path}: cannot tell how the {n} images of {images[0].parent} go with its {rows} poses: {why}, and "
        f"the counts differ (so not one pose per image, --match order){index}; to match by stamp anyway: --match "
        f"stamp (--skip-unposed leaves out images without a pose){hint}"
    )


def _by_stamp(
    images: list[Path],
    raw: list,
    track: PoseTrack,
    image_side: StampSide | None,
    pose_side: StampSide | None,
    max_gap: float,
    skip_unposed: bool,
    reason: str | None,
) -> PoseMatch:
    if image_side is None:
        bad = next(p for p, v in zip(images, raw) if v is None)
        raise DatasetError(f"{bad}: image name is not a stamp (a number; needed by --match stamp)")
    if pose_side is None:
        raise DatasetError(
            f"{track.path}: pose file has no timestamp column (needed by --match stamp); match "
            "images by order or index instead"
        )
    order = np.argsort(image_side.seconds, kind="stable")
    images = [images[i] for i in order]
    times = image_side.seconds[order]
    span = pose_side.seconds[-1] - pose_side.seconds[0]

    def hint(distance: float) -> str:
        if _frame_number_names([p.stem for p in images]):
            return "the image names look like zero-padded frame numbers: --match order (one pose per image) or index"
        text = unit_hint(image_side, pose_side, max_gap)
        far = distance > max(span, 60.0)
        return text if far or "pass --stamp-unit" in text else ""

    pos, quat, posed = poses_at(
        track,
        times,
        [str(p) for p in images],
        max_gap,
        pose_times=pose_side.seconds,
        skip_unposed=skip_unposed,
        hint=hint,
    )
    keep = np.flatnonzero(posed)
    skipped = [images[i] for i in np.flatnonzero(~posed)]
    if not len(keep):
        raise DatasetError(
            f"{track.path}: none of the {len(images)} images in {images[0].parent} has a pose "
            f"within --max-pose-gap {max_gap:g} s; {unit_hint(image_side, pose_side, max_gap)}"
        )
    return PoseMatch(
        "stamp",
        reason,
        [images[i] for i in keep],
        keep,
        pos[keep],
        quat[keep],
        times[keep],
        len(images),
        skipped,
        image_side,
        pose_side,
        max_gap,
    )


def _by_index(
    images: list[Path],
    stems: list[str],
    track: PoseTrack,
    times: np.ndarray | None,
    skip_unposed: bool,
    reason: str | None,
) -> PoseMatch:
    bad = next((p for p, s in zip(images, stems) if not s.isdigit()), None)
    if bad is not None:
        raise DatasetError(f"{bad}: image name is not a frame number (digits; needed by --match index)")
    order = sorted(range(len(images)), key=lambda i: int(stems[i]))
    images = [images[i] for i in order]
    numbers = [int(stems[i]) for i in order]
    rows = len(track)
    posed = np.array([k < rows for k in numbers], dtype=bool)
    if not posed.all() and not skip_unposed:
        first = int(np.flatnonzero(~posed)[0])
        raise DatasetError(
            f"{images[first]}: frame number {numbers[first]} has no pose: {track.path} has {rows} "
            f"pose rows, numbered from 0 (--match index); --skip-unposed leaves such images out"
        )
    keep = np.flatnonzero(posed)
    if not len(keep):
        raise DatasetError(
            f"{track.path}: none of the {len(images)} images in {images[0].parent} has a pose row "
            f"(frame numbers from {numbers[0]}, {rows} pose rows numbered from 0)"
        )
    idx = np.array([numbers[i] for i in keep], dtype=np.int64)
    return PoseMatch(
        "index",
        reason,
        [images[i] for i in keep],
        keep,
        track.positions[idx],
        track.quaternions[idx],
        times[idx] if times is not None else None,
        len(images),
        [images[i] for i in np.flatnonzero(~posed)],
    )


__all__ = ["DEFAULT_MAX_GAP", "MATCHES", "PoseMatch", "match_images"]
