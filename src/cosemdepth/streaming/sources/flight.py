"""Your own flight as the input: a folder of images with a pose file (:func:`cosemdepth.data.flight.open_flight`,
``predict --flight``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from ...data import open_dataset
from ...data.decode import DEFAULT_JPEG_IDCT, check_jpeg_idct
from ...data.flight import DEFAULT_CONVENTION
from ...data.pose_matching import DEFAULT_MAX_GAP
from ...data.stamps import parse_stamp_unit
from ...errors import ConfigError
from ...output_safety.outdir import Input
from ..registry import register_source
from .dataset import DatasetSource


@dataclass(frozen=True)
class FlightOptions:
    """A folder of images with a pose file (``--flight --images DIR --poses FILE (--intrinsics | --hfov)``).

    Attributes:
        images, poses: the image folder and the absolute camera poses (TUM or CSV: docs/data.md).
        intrinsics: ``(fx, fy, cx, cy)`` in pixels of the original images, hfov: the horizontal field of view in
            degrees, or calibration: the camera's calibration file (images undistorted to a pinhole); exactly one.
        convention: axes of the posed frame (None: :data:`~cosemdepth.data.flight.DEFAULT_CONVENTION`).
        frame_skip: keep every k-th image; match, stamp_unit, max_pose_gap, skip_unposed: how images get poses
            (:mod:`cosemdepth.data.pose_matching`; ``max_pose_gap`` None: its default).
        jpeg_idct: JPEG decoding (:mod:`cosemdepth.data.decode`).
    """

    images: Optional[Path]
    poses: Optional[Path]
    intrinsics: Optional[tuple[float, float, float, float]] = None
    hfov: Optional[float] = None
    convention: Optional[str] = None
    frame_skip: int = 1
    match: str = "auto"
    stamp_unit: str = "auto"
    max_pose_gap: Optional[float] = None
    skip_unposed: bool = False
    jpeg_idct: str = DEFAULT_JPEG_IDCT
    calibration: Optional[Path] = None

    #: the source table's name of this input
    source = "flight"

    def __post_init__(self) -> None:
        if self.max_pose_gap is not None and not self.max_pose_gap >= 0:
            raise ConfigError(f"--max-pose-gap must be >= 0 seconds, got {self.max_pose_gap}")
        if self.images is None:
            raise ConfigError("--flight needs --images DIR")
        if self.poses is None:
            raise ConfigError("--flight needs --poses FILE")
        if sum(x is not None for x in (self.intrinsics, self.hfov, self.calibration)) != 1:
            raise ConfigError(
                "--flight needs exactly one of --intrinsics FX FY CX CY, --hfov DEG and --calibration FILE"
            )
        if self.hfov is not None and not 0 < self.hfov < 180:
            raise ConfigError(f"--hfov must be in (0, 180) degrees, got {self.hfov}")
        if not isinstance(self.frame_skip, int) or self.frame_skip < 1:
            raise ConfigError(f"--frame-skip must be a positive integer, got {self.frame_skip!r}")
        parse_stamp_unit(self.stamp_unit)
        # options of matching by stamp, with a rule that reads no image stamps
        for flag, given, rules in (
            ("--max-pose-gap", self.max_pose_gap is not None, ("order", "index")),
            ("--skip-unposed", self.skip_unposed, ("order",)),
        ):
            if given and self.match in rules:
                raise ConfigError(
                    f"{flag} does not apply to --match {self.match} (every image takes a pose row as "
                    "it is; no interpolation between poses)"
                )
        check_jpeg_idct(self.jpeg_idct)

    def inputs(self) -> list[Input]:
        """The paths it reads (the output policy of :mod:`cosemdepth.output_safety.outdir`)."""
        given = (("--images", self.images), ("--poses", self.poses), ("--calibration", self.calibration))
        return [Input(label, p) for label, p in given if p is not None]

    def settings(self) -> dict[str, Any]:
        """``predictions.json``'s ``run`` entries about the input."""
        return {
            "intrinsics_given": None if self.intrinsics is None else [float(v) for v in self.intrinsics],
            "hfov_deg": self.hfov,
            "calibration": None if self.calibration is None else str(self.calibration),
            "convention": self.convention or DEFAULT_CONVENTION,
            "frame_skip": self.frame_skip,
            "poses": str(self.poses),
            "match": self.match,
            "stamp_unit": self.stamp_unit,
            "max_pose_gap": self.max_pose_gap,
            "skip_unposed": self.skip_unposed,
        }


class FlightSource(DatasetSource):
    """The frames of a flight (:class:`FlightOptions`); ``describe`` records how its images were matched to poses."""

    name = "flight"

    @classmethod
    def from_options(cls, options: FlightOptions, size=None) -> "FlightSource":
        dataset = open_dataset(
            "flight",
            options.images,
            poses=options.poses,
            intrinsics=options.intrinsics,
            fov=options.hfov,
            convention=options.convention or DEFAULT_CONVENTION,
            frame_skip=options.frame_skip,
            seq_len=1,
            size=size,
            jpeg_idct=options.jpeg_idct,
            match=options.match,
            stamp_unit=options.stamp_unit,
            max_gap=DEFAULT_MAX_GAP if options.max_pose_gap is None else options.max_pose_gap,
            skip_unposed=options.skip_unposed,
            calibration=options.calibration,
        )
        info: dict[str, Any] = {"root": str(options.images), "split": None}
        if hasattr(dataset, "pose_matching"):
            info["pose_matching"] = dataset.pose_matching
        return cls(dataset, info=info)

    def report(self) -> str:
        """``"; flight: 16 of 16 images matched to poses by stamp (...)"``."""
        matching = getattr(self.dataset, "pose_matching", None)
        return f"; flight: {matching['describe']}" if matching else ""


register_source("flight", FlightSource)

__all__ = ["FlightOptions", "FlightSource"]
