"""A ROS bag as the input: an image topic, a pose topic and camera_info (:mod:`cosemdepth.robotics.bag_flight`,
``predict --bag``). Each frame carries its image's header (``meta``: ``stamp_ns``, ``frame_id``) and its absolute
camera-to-world pose (``pose``), for the output bag and the rerun recording."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
import torch

from ...data.decode import DEFAULT_JPEG_IDCT, check_jpeg_idct
from ...errors import ConfigError
from ...output_safety.outdir import Input
from ...robotics.bag_flight import DEFAULT_BAG_CONVENTION, DEFAULT_MAX_POSE_GAP, BagFlight, open_bag_flight
from ..registry import register_source
from .dataset import DatasetSource


@dataclass(frozen=True)
class BagOptions:
    """A ROS bag (``--bag PATH --image-topic T --pose-topic T (--camera-info-topic T | --intrinsics | --hfov)``).

    Attributes:
        bag: the bag (ROS 2 folder, sqlite3 or MCAP, or ROS 1 ``.bag``); image_topic, pose_topic: its topics.
        camera_info_topic: the camera's topic, or calibration: a calibration file, or intrinsics ``(fx, fy, cx, cy)``
            / hfov (exactly one of them); a distorting lens is undistorted on the fly.
        convention: axes of the posed frame (None: REP 103's ``flu``); frame_skip: keep every k-th posed image;
        max_pose_gap: interpolate only between poses at most this many seconds apart (None: the default);
        skip_unposed: leave out images without a pose; ignore_distortion: take the camera's K as if the images were
        undistorted; jpeg_idct: JPEG decoding.
    """

    bag: Path
    image_topic: Optional[str] = None
    pose_topic: Optional[str] = None
    camera_info_topic: Optional[str] = None
    intrinsics: Optional[tuple[float, float, float, float]] = None
    hfov: Optional[float] = None
    convention: Optional[str] = None
    frame_skip: int = 1
    max_pose_gap: Optional[float] = None
    skip_unposed: bool = False
    ignore_distortion: bool = False
    jpeg_idct: str = DEFAULT_JPEG_IDCT
    calibration: Optional[Path] = None

    #: the source table's name of this input
    source = "bag"

    def __post_init__(self) -> None:
        if self.max_pose_gap is not None and not self.max_pose_gap >= 0:
            raise ConfigError(f"--max-pose-gap must be >= 0 seconds, got {self.max_pose_gap}")
        for opt in ("image_topic", "pose_topic"):
            if not getattr(self, opt):
                raise ConfigError(f"--bag needs --{opt.replace('_', '-')} T")
        cameras = (self.camera_info_topic, self.calibration, self.intrinsics, self.hfov)
        if sum(x is not None for x in cameras) > 1:
            raise ConfigError("give one of --camera-info-topic, --calibration, --intrinsics and --hfov")
        if (
            self.camera_info_topic is None
            and self.calibration is None
            and (self.intrinsics is None) == (self.hfov is None)
        ):
            raise ConfigError(
                "--bag needs --camera-info-topic T, or exactly one of --calibration FILE, --intrinsics FX FY CX CY "
                "and --hfov DEG"
            )
        if self.hfov is not None and not 0 < self.hfov < 180:
            raise ConfigError(f"--hfov must be in (0, 180) degrees, got {self.hfov}")
        check_jpeg_idct(self.jpeg_idct)

    def inputs(self) -> list[Input]:
        """The paths it reads (the output policy of :mod:`cosemdepth.output_safety.outdir`)."""
        return [Input(label, p) for label, p in (("--bag", self.bag), ("--calibration", self.calibration)) if p]

    def settings(self) -> dict[str, Any]:
        """``predictions.json``'s ``run`` entries about the input."""
        return {
            "intrinsics_given": None if self.intrinsics is None else [float(v) for v in self.intrinsics],
            "hfov_deg": self.hfov,
            "calibration": None if self.calibration is None else str(self.calibration),
            "camera_info_topic": self.camera_info_topic,
            "convention": self.convention or DEFAULT_BAG_CONVENTION,
            "frame_skip": self.frame_skip,
            "pose_topic": self.pose_topic,
            "max_pose_gap": self.max_pose_gap,
            "skip_unposed": self.skip_unposed,
        }


class BagSource(DatasetSource):
    """The frames of a bag flight (:class:`~cosemdepth.robotics.bag_flight.BagFlight`), with each image's header
    and absolute pose."""

    name = "bag"

    def __init__(self, flight: BagFlight, *, info: dict[str, Any] | None = None) -> None:
        super().__init__(flight.dataset, info=info)
        self.flight = flight

    @classmethod
    def from_options(cls, options: BagOptions, size=None) -> "BagSource":
        flight = open_bag_flight(
            options.bag,
            options.image_topic,
            options.pose_topic,
            camera_info_topic=options.camera_info_topic,
            intrinsics=options.intrinsics,
            fov=options.hfov,
            convention=options.convention or DEFAULT_BAG_CONVENTION,
            frame_skip=options.frame_skip,
            skip_unposed=options.skip_unposed,
            max_pose_gap=DEFAULT_MAX_POSE_GAP if options.max_pose_gap is None else options.max_pose_gap,
            ignore_distortion=options.ignore_distortion,
            size=size,
            jpeg_idct=options.jpeg_idct,
            calibration=options.calibration,
        )
        return cls(flight, info={"root": str(options.bag), "split": None})

    def pose(self, trajectory: int, row: int) -> torch.Tensor:
        r, p = self.flight.camera_to_world(row)
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = r, p
        return torch.from_numpy(out)

    def meta(self, trajectory: int, row: int) -> dict[str, Any]:
        index = self.flight.index
        return {"stamp_ns": int(index.stamps[row]), "frame_id": index.frame_ids[row]}

    def report(self) -> str:
        """``"; bag: N of M images"`` (and how many were skipped without a pose)."""
        index = self.flight.index
        text = f"; bag: {len(index.stamps)} of {index.total} images"
        if index.skipped:
            text += f", {index.skipped} skipped without a pose"
        return text

    def close(self) -> None:
        self.flight.close()


register_source("bag", BagSource)

__all__ = ["BagOptions", "BagSource"]
