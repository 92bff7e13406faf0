"""Real lenses: calibration files, distortion models and undistortion to the pinhole camera the models assume.

* :func:`load_calibration` reads ROS camera_info YAML, OpenCV FileStorage YAML, Kalibr camchains and COLMAP
  ``cameras.txt`` into a :class:`Calibration` (package pixel convention: centres at +0.5);
  :func:`calibration_from_camera_info` reads a ``sensor_msgs/CameraInfo`` message;
* :mod:`cosemdepth.camera.distortion`: the lens models (radtan, equidistant) as pure functions;
* :class:`Undistorter`: the remap of one camera to a centred pinhole at the model's focal length, built once,
  applied per frame (``rgb, valid = undistorter(image)``; ``undistorter.intrinsics``);
  :class:`UndistortedFrames` wraps a reader's frame loader with it;
* :mod:`cosemdepth.camera.writers`: the same layouts written (SynthAir writes them beside a distorted flight).

See ``docs/data.md`` (Calibration).
"""

from __future__ import annotations

from .calibration import LAYOUTS, Calibration
from .parsers import calibration_from_camera_info, load_calibration
from .undistort import CANVASES, FILLS, UndistortedFrames, Undistorter

__all__ = [
    "CANVASES",
    "Calibration",
    "FILLS",
    "LAYOUTS",
    "UndistortedFrames",
    "Undistorter",
    "calibration_from_camera_info",
    "load_calibration",
]
