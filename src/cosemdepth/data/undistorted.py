"""Readers' side of calibrated lenses: the :class:`~cosemdepth.camera.Undistorter` of a calibration for the images
a reader found and the output size it was asked for (``FocalSize`` rules included)."""

from __future__ import annotations

from pathlib import Path

from ..camera import Calibration, Undistorter, load_calibration
from .frames import FocalSize, Size, as_size


def undistorter_for(calibration: str | Path | Calibration, native: Size, size, what: str = "the images") -> Undistorter:
    """The :class:`~cosemdepth.camera.Undistorter` of ``calibration`` (a file or a Calibration) for images of
    ``native = (H, W)`` (the calibration scaled to it when the aspect ratio matches), to the output ``size``: a
    :class:`~cosemdepth.data.frames.FocalSize` (the size where the undistorted camera has that focal length), an int
    or ``(H, W)``, or None (the native size)."""
    cal = calibration if isinstance(calibration, Calibration) else load_calibration(calibration)
    cal = cal.for_image_size(native, what)
    if isinstance(size, FocalSize):
        return Undistorter(cal, focal_px=size.focal_px)
    return Undistorter(cal, size=as_size(size))


__all__ = ["undistorter_for"]
