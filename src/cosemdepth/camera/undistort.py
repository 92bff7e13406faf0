"""Undistortion: the images of a calibrated camera remapped to a centred pinhole, built once, applied per frame.

The target camera is a pinhole with the calibration's focal lengths scaled to the output size (``fx' = fx W' / W``,
``fy' = fy H' / H``) and a centred principal point ``(W' / 2, H' / 2)`` (package convention). Its size is, by
default, the calibration's image size (``canvas="same"``), scaled to ``focal_px`` when given (the model's focal
length: :func:`cosemdepth.operating_point.size_for_focal`, as for pinhole inputs), or ``size`` itself. Each target
pixel centre is taken through the lens model (:func:`cosemdepth.camera.distortion.distort`) to its source position
and sampled bilinearly from the native image: undistortion and resizing are one resampling step. The source
positions are computed once, in float64; each frame is one ``torch.nn.functional.grid_sample`` (bilinear, border
padding) at them (measured against OpenCV's ``remap`` and a gather from the uint8 image: benchmarks/undistortion.py).
Without distortion and with a centred principal point this is BL2 (the readers' half-pixel bilinear resize) up to
float32 rounding of the coordinates.

A target pixel is *valid* when its ray is inside the monotonic part of the lens and lands inside the source image
(``0 <= u <= W``, ``0 <= v <= H``). A barrel or fisheye lens at the default canvas covers every target pixel and
the periphery of the source is lost (:attr:`Undistorter.source_coverage`); ``canvas="full"`` widens the target to
the whole undistorted source (up to :data:`MAX_FULL_ANGLE` off-axis) and leaves invalid pixels where no source
exists. What the model is fed at invalid pixels (``fill``): ``"edge"`` (the nearest source border pixel, as an
edge-replicating pad) or ``"black"`` (zeros). The depth there is not an estimate: the readers hand
:attr:`Undistorter.valid` to the streaming policy, which marks those pixels invalid in every depth mask.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
import torch

from ..errors import ConfigError, DatasetError
from ..operating_point import size_for_focal
from .calibration import Calibration
from .distortion import distort, to_radius_parameter, undistort_points

#: Target canvases: ``same`` (the calibration's image at the output focal length) or ``full`` (every source pixel).
CANVASES = ("same", "full")
#: What the model sees at target pixels without a source pixel.
FILLS = ("edge", "black")
#: The default fill (measured: benchmarks/undistortion.py, docs/benchmarks.md).
DEFAULT_FILL = "edge"
#: ``canvas="full"`` stops at this angle off-axis (degrees): a pinhole image cannot reach 90 degrees.
MAX_FULL_ANGLE = 75.0
#: Source pixels sampled per axis (at most) when measuring :attr:`Undistorter.source_coverage`.
COVERAGE_SAMPLES = 512

_FULL_SCALE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}


class Undistorter:
    """The remap of one camera (see the module docstring). Build it once per camera; call it per frame.

    Args:
        calibration: the camera (checked here; scale it to the images' size first:
            :meth:`Calibration.for_image_size`).
        focal_px: the target's horizontal focal length in pixels (the model's); sets the size by
            :func:`~cosemdepth.operating_point.size_for_focal`. None: the calibration's own.
        size: ``(H', W')`` instead of ``focal_px`` (the focal lengths scale with it).
        canvas: ``"same"`` or ``"full"`` (:data:`CANVASES`).
        fill: ``"edge"`` or ``"black"`` (:data:`FILLS`).

    Attributes:
        size: ``(H', W')``; intrinsics: ``[4]`` float32 ``(fx', fy', cx', cy')`` of the target (package convention);
        valid: ``[H', W']`` bool, target pixels with a source; valid_fraction: their share;
        source_coverage: the share of the source image's pixels the target shows.
    """

    def __init__(
        self,
        calibration: Calibration,
        *,
        focal_px: float | None = None,
        size: tuple[int, int] | None = None,
        canvas: str = "same",
        fill: str = DEFAULT_FILL,
    ) -> None:
        if canvas not in CANVASES:
            raise ConfigError(f"canvas must be one of {', '.join(CANVASES)}, got {canvas!r}")
        if fill not in FILLS:
            raise ConfigError(f"fill must be one of {', '.join(FILLS)}, got {fill!r}")
        if focal_px is not None and size is not None:
            raise ConfigError("give the target's focal_px or its size, not both")
        cal = calibration.check()
        self.calibration, self.canvas, self.fill = cal, canvas, fill
        h, w = cal.size
        base_h, base_w = (h, w) if canvas == "same" else self._full_canvas()
        if size is not None:
            out = (int(size[0]), int(size[1]))
            if out[0] < 1 or out[1] < 1:
                raise ConfigError(f"size must be positive, got {size!r}")
        elif focal_px is not None:
            out = size_for_focal((base_h, base_w), cal.fx, float(focal_px))
        else:
            out = (base_h, base_w)
        self.size = out
        sx, sy = out[1] / base_w, out[0] / base_h
        self.k = (cal.fx * sx, cal.fy * sy, out[1] / 2, out[0] / 2)
        self.intrinsics = torch.tensor(self.k, dtype=torch.float32)
        self._build()

    # ------------------------------------------------------------------------------------------- construction
    def _full_canvas(self) -> tuple[int, int]:
        """``(H, W)`` at the calibration's focal lengths holding every source pixel's ray up to
        :data:`MAX_FULL_ANGLE` off-axis (a symmetric canvas around the centred principal point)."""
        cal = self.calibration
        h, w = cal.size
        n = 256
        t = torch.linspace(0.0, 1.0, n, dtype=torch.float64)
        edges = torch.cat(
            [
                torch.stack([t * w, torch.zeros(n, dtype=torch.float64)], -1),
                torch.stack([t * w, torch.full((n,), float(h), dtype=torch.float64)], -1),
                torch.stack([torch.zeros(n, dtype=torch.float64), t * h], -1),
                torch.stack([torch.full((n,), float(w), dtype=torch.float64), t * h], -1),
            ]
        )
        xy = undistort_points(cal.model, cal.normalise(edges), cal.coefficients, cal.limit()[0])
        cap = math.tan(math.radians(MAX_FULL_ANGLE))
        r = xy.norm(dim=-1, keepdim=True)
        xy = torch.where(torch.isfinite(r) & (r <= cap), xy, xy / r * cap)
        xy = torch.nan_to_num(xy, nan=cap)
        ex, ey = float(xy[:, 0].abs().max()), float(xy[:, 1].abs().max())
        return max(h, math.ceil(2 * ey * cal.fy)), max(w, math.ceil(2 * ex * cal.fx))

    def _build(self) -> None:
        cal = self.calibration
        h, w = cal.size
        ho, wo = self.size
        fx, fy, cx, cy = self.k
        rows = (torch.arange(ho, dtype=torch.float64) + 0.5 - cy) / fy
        cols = (torch.arange(wo, dtype=torch.float64) + 0.5 - cx) / fx
        xy = torch.stack(torch.meshgrid(cols, rows, indexing="xy"), -1)  # [H', W', 2] (x, y)
        r = xy.norm(dim=-1)
        limit, _ = cal.limit()
        inside = to_radius_parameter(cal.model, r) < limit if cal.has_distortion else torch.ones_like(r, dtype=bool)
        # beyond the lens's monotonic part: far out along the same direction (clamped to the border below)
        far = xy / r.clamp_min(1e-12).unsqueeze(-1) * 1e6
        xy_d = torch.where(inside.unsqueeze(-1), distort(cal.model, xy, cal.coefficients), far)
        uv = cal.project(xy_d)
        u, v = uv[..., 0], uv[..., 1]
        in_image = (u >= 0) & (u <= w) & (v >= 0) & (v <= h)
        self.valid = (inside & in_image).contiguous()
        self.valid_fraction = float(self.valid.double().mean())
        # grid_sample's normalised coordinates (align_corners=False: pixel centres at +0.5, as the package's); its
        # "border" padding clamps to the edge pixels, an edge-replicating pad
        grid = torch.stack([2 * u / w - 1, 2 * v / h - 1], -1).clamp(-1e4, 1e4)
        self._grid = grid.to(torch.float32)[None].contiguous()  # [1, H', W', 2]
        xn = u.floor().clamp(0, w - 1).long()
        yn = v.floor().clamp(0, h - 1).long()
        self._nearest = (yn * w + xn).reshape(-1)
        self.source_coverage = self._coverage()

    def _coverage(self) -> float:
        """The share of the source image's pixels whose ray the target shows (sampled on a grid)."""
        cal = self.calibration
        h, w = cal.size
        sh, sw = min(h, COVERAGE_SAMPLES), min(w, COVERAGE_SAMPLES)
        vs = (torch.arange(sh, dtype=torch.float64) + 0.5) * (h / sh)
        us = (torch.arange(sw, dtype=torch.float64) + 0.5) * (w / sw)
        uv = torch.stack(torch.meshgrid(us, vs, indexing="xy"), -1)
        xy = undistort_points(cal.model, cal.normalise(uv), cal.coefficients, cal.limit()[0])
        fx, fy, cx, cy = self.k
        ut, vt = xy[..., 0] * fx + cx, xy[..., 1] * fy + cy
        ho, wo = self.size
        seen = torch.isfinite(ut) & torch.isfinite(vt) & (ut >= 0) & (ut <= wo) & (vt >= 0) & (vt <= ho)
        return float(seen.double().mean())

    # ------------------------------------------------------------------------------------------------ per frame
    def _check(self, shape: tuple[int, ...], what: str) -> None:
        if tuple(shape) != tuple(self.calibration.size):
            h, w = self.calibration.size
            raise DatasetError(
                f"{what} is {shape[1]}x{shape[0]} (WxH) but the calibration ({self.calibration.where}) is for "
                f"{w}x{h} images"
            )

    def _sample(self, image: torch.Tensor) -> torch.Tensor:
        """Bilinear sampling of ``image [C, H, W]`` float32 at the target's source positions -> ``[C, H', W']``."""
        out = torch.nn.functional.grid_sample(
            image[None], self._grid, mode="bilinear", padding_mode="border", align_corners=False
        )[0]
        if self.fill == "black":
            out = out * self.valid
        return out

    def __call__(self, rgb: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        """One frame: ``rgb [H, W, 3]`` uint8 (or uint16) at the calibration's size -> ``(rgb [3, H', W']`` float32
        in [0, 1] (``/255`` or ``/65535``), ``valid [H', W']`` bool``)``, ready for the model (as
        :func:`cosemdepth.data.frames.rgb_to_tensor` gives pinhole images)."""
        rgb = np.ascontiguousarray(rgb)
        scale = _FULL_SCALE.get(rgb.dtype)
        if scale is None or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise TypeError(f"expected an [H, W, 3] uint8 or uint16 image, got {rgb.dtype} {list(rgb.shape)}")
        self._check(rgb.shape[:2], "the image")
        src = torch.from_numpy(rgb.astype(np.int32) if rgb.dtype == np.uint16 else np.require(rgb, requirements="W"))
        src = src.permute(2, 0, 1)
        return self._sample(src.to(torch.float32)).div_(scale), self.valid

    def remap(self, image: torch.Tensor) -> torch.Tensor:
        """Bilinear remap of a float image ``[C, H, W]`` -> ``[C, H', W']`` (as ``__call__``)."""
        self._check(tuple(image.shape[-2:]), "the image")
        return self._sample(image.to(torch.float32))

    def remap_nearest(self, image: torch.Tensor) -> torch.Tensor:
        """Nearest-pixel remap of ``[..., H, W]`` (labels, depth) -> ``[..., H', W']``: each target pixel takes the
        source pixel its ray lands in (edge pixels where it lands outside)."""
        self._check(tuple(image.shape[-2:]), "the map")
        lead = image.shape[:-2]
        flat = image.reshape(*lead, -1)
        return flat.index_select(-1, self._nearest).reshape(*lead, *self.size)

    def remap_depth(self, depth: torch.Tensor) -> torch.Tensor:
        """Ground-truth z-depth ``[1, H, W]`` (or ``[H, W]``) -> ``[1, H', W']``: nearest pixel (the target and the
        source camera share their centre and axes, so a z-depth stays the z-depth of that surface point; a bilinear
        blend would invent depths across edges), and 0 (unknown) where the target pixel has no source."""
        d = depth.reshape(1, *depth.shape[-2:])
        return self.remap_nearest(d) * self.valid.to(d.dtype)

    def info(self) -> dict[str, Any]:
        """What predictions.json records: the source calibration and the target camera."""
        return {
            "calibration": self.calibration.to_dict(),
            "canvas": self.canvas,
            "fill": self.fill,
            "size": list(self.size),
            "intrinsics": [float(v) for v in self.k],
            "valid_fraction": self.valid_fraction,
            "source_coverage": self.source_coverage,
        }


class UndistortedFrames:
    """A frame loader (:data:`cosemdepth.data.sequence.FrameLoader`) reading a calibrated camera's frames through
    an :class:`Undistorter`: ``inner`` loads a frame at the native size (``rgb [3, H, W]``, optional ``depth
    [1, H, W]`` and ``semantic [H, W]``); the result is at the target size with ``source_valid [1, H', W']``
    (the :attr:`Undistorter.valid` mask). Picklable when ``inner`` is."""

    def __init__(self, inner, undistorter: Undistorter) -> None:
        self.inner = inner
        self.undistorter = undistorter

    @property
    def size(self) -> tuple[int, int]:
        return self.undistorter.size

    def __call__(self, rec) -> Mapping[str, torch.Tensor]:
        frame = self.inner(rec)
        u = self.undistorter
        out = {"rgb": u.remap(frame["rgb"]), "source_valid": u.valid[None].clone()}
        if "depth" in frame:
            out["depth"] = u.remap_depth(frame["depth"])
        if "semantic" in frame:
            out["semantic"] = u.remap_nearest(frame["semantic"])
        return out


__all__ = ["CANVASES", "DEFAULT_FILL", "FILLS", "MAX_FULL_ANGLE", "UndistortedFrames", "Undistorter"]
