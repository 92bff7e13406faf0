"""A calibrated camera: image size, intrinsics, lens model; its checks (NaN, singular, folding) and size scaling.

Pixel convention (the package's, design 2.1): pixel ``(i, j)`` covers ``[j, j + 1] x [i, i + 1]``, so its centre
is ``(j + 0.5, i + 0.5)`` and a centred principal point is ``(W / 2, H / 2)``. OpenCV, ROS and Kalibr count pixel
centres from 0 (their ``cx`` is this package's ``cx - 0.5``); COLMAP uses the package's convention. The parsers
(:mod:`cosemdepth.camera.parsers`) convert; a :class:`Calibration` always holds the package's convention.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch

from ..errors import DatasetError
from .distortion import MODELS, monotonic_limit, radial_profile

#: The layouts :func:`cosemdepth.camera.load_calibration` reads, by name (as recorded in ``Calibration.layout``).
LAYOUTS = {
    "ros": "ROS camera_info YAML",
    "opencv": "OpenCV FileStorage YAML",
    "kalibr": "Kalibr camchain YAML",
    "colmap": "COLMAP cameras.txt",
    "camera_info": "sensor_msgs/CameraInfo message",
    "synthair": "SynthAir lens",
}
#: Two image sizes have "the same aspect ratio" when scaling one side by the other's factor misses it by at most
#: this many pixels (1280x720 -> 854x480 does).
ASPECT_TOLERANCE_PX = 1.0


@dataclass(frozen=True)
class Calibration:
    """A camera as calibrated: ``size = (H, W)`` of its images, ``fx, fy, cx, cy`` and ``skew`` in pixels (package
    convention: pixel centres at +0.5), the lens ``model`` (``"pinhole"``, ``"radtan"``, ``"equidistant"``:
    :mod:`cosemdepth.camera.distortion`) and its ``coefficients`` (padded to the model's count). ``source`` names
    where it came from (a file, a bag topic) for messages; ``layout`` is a key of :data:`LAYOUTS`. ``t_cam_imu``:
    Kalibr's ``T_cam_imu`` (4x4, ``X_cam = T X_imu``) when the file has it. ``note``: what was done to it on the
    way (scaled to another image size), or ``""``."""

    size: tuple[int, int]
    fx: float
    fy: float
    cx: float
    cy: float
    model: str = "pinhole"
    coefficients: tuple[float, ...] = ()
    skew: float = 0.0
    source: str = ""
    layout: str = ""
    camera_name: str = ""
    t_cam_imu: tuple[tuple[float, ...], ...] | None = field(default=None, compare=False)
    note: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise DatasetError(f"{self.where}: lens model {self.model!r} is not one of {', '.join(MODELS)}")
        c = tuple(float(v) for v in self.coefficients)
        if self.model == "radtan" and not any(v != 0 for v in c):  # a radtan lens without distortion is a pinhole
            object.__setattr__(self, "model", "pinhole")
            c = ()
        n = MODELS[self.model]
        if len(c) > n and any(v != 0 for v in c[n:]):
            raise DatasetError(f"{self.where}: the {self.model} model takes {n} coefficients, got {len(c)}")
        object.__setattr__(self, "coefficients", (c + (0.0,) * n)[:n])

    @property
    def where(self) -> str:
        return self.source or "calibration"

    @property
    def k(self) -> tuple[float, float, float, float]:
        """``(fx, fy, cx, cy)`` (package convention)."""
        return (self.fx, self.fy, self.cx, self.cy)

    @property
    def has_distortion(self) -> bool:
        return self.model != "pinhole" and (self.model == "equidistant" or any(v != 0 for v in self.coefficients))

    @property
    def mount_rotation(self) -> np.ndarray | None:
        """``[3, 3]`` the rotation of Kalibr's ``T_cam_imu`` (``X_camera = M X_imu``): the ``convention`` matrix
        of a flight whose poses are the IMU's (:func:`cosemdepth.data.poses.convention_matrix`); None without it."""
        if self.t_cam_imu is None:
            return None
        return np.asarray(self.t_cam_imu, dtype=np.float64)[:3, :3].copy()

    def project(self, xy_d: torch.Tensor) -> torch.Tensor:
        """Distorted normalised coordinates ``[..., 2]`` -> pixel coordinates ``[..., 2]`` ``(u, v)`` (package
        convention)."""
        x, y = xy_d[..., 0], xy_d[..., 1]
        return torch.stack([self.fx * x + self.skew * y + self.cx, self.fy * y + self.cy], -1)

    def normalise(self, uv: torch.Tensor) -> torch.Tensor:
        """Pixel coordinates ``[..., 2]`` -> distorted normalised coordinates ``[..., 2]`` (inverse of
        :meth:`project`)."""
        y = (uv[..., 1] - self.cy) / self.fy
        x = (uv[..., 0] - self.cx - self.skew * y) / self.fx
        return torch.stack([x, y], -1)

    def corner_radius(self) -> float:
        """The largest distorted normalised radius of the image (at one of its four corners)."""
        h, w = self.size
        uv = torch.tensor([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]], dtype=torch.float64)
        return float(self.normalise(uv).norm(dim=-1).max())

    def limit(self) -> tuple[float, float]:
        """``(parameter, rho)`` where the lens stops being monotonic (:func:`~.distortion.monotonic_limit`)."""
        return monotonic_limit(self.model, self.coefficients)

    def check(self) -> "Calibration":
        """Raise a :class:`~cosemdepth.errors.DatasetError` naming :attr:`source` unless the calibration is usable:
        a positive image size, finite intrinsics and coefficients, ``fx, fy > 0`` (a singular camera matrix
        otherwise), and a lens that does not fold over the image (its radial profile increases out to the image
        corners). Returns ``self``."""
        h, w = self.size
        if not (isinstance(h, int) and isinstance(w, int) and h > 0 and w > 0):
            raise DatasetError(f"{self.where}: image size must be two positive integers, got {w}x{h} (WxH)")
        values = [self.fx, self.fy, self.cx, self.cy, self.skew, *self.coefficients]
        if not all(math.isfinite(v) for v in values):
            raise DatasetError(
                f"{self.where}: the intrinsics hold NaN or infinite values (fx, fy, cx, cy = {_fmt(self.k)}, "
                f"coefficients {_fmt(self.coefficients)})"
            )
        if self.fx <= 0 or self.fy <= 0:
            raise DatasetError(
                f"{self.where}: the camera matrix is singular or flipped (fx = {self.fx:g}, fy = {self.fy:g}; both "
                "must be > 0)"
            )
        if self.has_distortion:
            param, rho = self.limit()
            corner = self.corner_radius()
            if rho < corner * (1 - 1e-9):
                angle = math.degrees(param if self.model == "equidistant" else math.atan(param))
                raise DatasetError(
                    f"{self.where}: the {self.model} coefficients {_fmt(self.coefficients)} fold the image: the "
                    f"distorted radius stops growing at {angle:.1f} degrees off-axis (radius {rho:.3f}), short of "
                    f"the image corners (radius {corner:.3f}); the calibration does not describe the lens at the "
                    "border (refit it with the target reaching the corners, or with fewer coefficients)"
                )
        return self

    def for_image_size(self, size: tuple[int, int], what: str = "the images") -> "Calibration":
        """This calibration for images of ``size = (H, W)``: itself when the size is its own; scaled (``fx, cx`` by
        ``W' / W``, ``fy, cy`` by ``H' / H``; the lens coefficients act on normalised coordinates and stay) when the
        aspect ratio is the same, with :attr:`note` saying so; else a DatasetError."""
        h2, w2 = (int(v) for v in size)
        h, w = self.size
        if (h2, w2) == (h, w):
            return self
        sx, sy = w2 / w, h2 / h
        if abs(w * sy - w2) > ASPECT_TOLERANCE_PX or abs(h * sx - h2) > ASPECT_TOLERANCE_PX:
            raise DatasetError(
                f"{self.where}: the calibration is for {w}x{h} images but {what} are {w2}x{h2} (WxH), of another "
                "aspect ratio (cropped?); calibrate the camera at this size"
            )
        note = f"{self.where}: the calibration is for {w}x{h} images, {what} are {w2}x{h2}: scaled by {sx:.6g}"
        if abs(sx - sy) > 1e-12:
            note += f" x {sy:.6g} (W x H)"
        return replace(
            self,
            size=(h2, w2),
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=self.cx * sx,
            cy=self.cy * sy,
            skew=self.skew * sx,
            note=note,
        )

    def to_dict(self) -> dict[str, Any]:
        """What ``predictions.json`` records of it (intrinsics in the package convention)."""
        d: dict[str, Any] = {
            "source": self.source,
            "layout": LAYOUTS.get(self.layout, self.layout),
            "size": [self.size[0], self.size[1]],
            "intrinsics": [self.fx, self.fy, self.cx, self.cy],
            "skew": self.skew,
            "model": self.model,
            "coefficients": list(self.coefficients),
        }
        if self.camera_name:
            d["camera_name"] = self.camera_name
        if self.note:
            d["note"] = self.note
        return d


def _fmt(values) -> str:
    return "[" + ", ".join(f"{float(v):.6g}" for v in values) + "]"


def radial_gain_at_corner(cal: Calibration) -> float:
    """``rho(r) / r`` at the undistorted radius of a pinhole with ``cal``'s intrinsics at its image corner: below 1
    for barrel (and fisheye) lenses, above 1 for pincushion ones (a figure for messages and reports)."""
    r = torch.tensor(cal.corner_radius(), dtype=torch.float64)
    param = torch.atan(r) if cal.model == "equidistant" else r
    return float(radial_profile(cal.model, param, cal.coefficients) / r)


__all__ = ["ASPECT_TOLERANCE_PX", "Calibration", "LAYOUTS", "radial_gain_at_corner"]
