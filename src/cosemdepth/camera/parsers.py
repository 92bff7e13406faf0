"""Calibration files as users have them -> :class:`~cosemdepth.camera.calibration.Calibration`.

:func:`load_calibration` recognises the layout from the content:

* **ROS camera_info YAML** (camera_calibration_parsers, written by ``camera_calibration`` / ``camera_info_manager``):
  ``image_width``, ``image_height``, ``camera_name``, ``camera_matrix {rows, cols, data}``, ``distortion_model``
  (``plumb_bob``, ``rational_polynomial``, ``equidistant``), ``distortion_coefficients {rows, cols, data}``,
  ``rectification_matrix``, ``projection_matrix``. Integer pixel centres (``cx + 0.5`` here).
  The rectification and projection matrices (stereo rectification) are not used: images are undistorted to a
  pinhole of their own camera frame, which is the frame the poses describe.
* **OpenCV FileStorage YAML** (``cv::FileStorage``, the calibration samples): a ``%YAML:1.0`` header and
  ``!!opencv-matrix`` nodes ``{rows, cols, dt, data}`` (plain YAML parsers reject both); ``image_width``,
  ``image_height`` (or ``image_size: [w, h]``), ``camera_matrix``, ``distortion_coefficients`` (4, 5, 8 values: radtan;
  12 or 14 when the thin-prism and tilt terms are 0), ``fisheye_model: 1`` for ``cv::fisheye`` (4 values).
  Integer pixel centres.
* **Kalibr camchain YAML**: ``cam0: {camera_model: pinhole, intrinsics: [fu, fv, pu, pv], distortion_model: radtan |
  equidistant | none, distortion_coeffs: [...], resolution: [w, h], T_cam_imu: 4x4}`` (``cam0`` is read; a file with
  more cameras says so in the note). Integer pixel centres.
* **COLMAP cameras.txt**: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`` lines, ``#`` comments; models
  ``SIMPLE_PINHOLE``, ``PINHOLE``, ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV``, ``FULL_OPENCV``, ``OPENCV_FISHEYE``. The
  first camera is read. Pixel centres at +0.5 (the package's convention: no shift).

``sensor_msgs/CameraInfo`` messages (bags, live topics) go through :func:`calibration_from_camera_info`. Anything
else, or a lens model this package does not handle, is a one-line :class:`~cosemdepth.errors.DatasetError` naming
the file (and the model).
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from ..errors import DatasetError
from .calibration import Calibration

#: The largest calibration file read (a calibration is a few kB; anything bigger is not one).
MAX_FILE_BYTES = 4 * 1024 * 1024
#: ROS distortion_model names -> (model, largest coefficient count).
ROS_MODELS = {"plumb_bob": ("radtan", 5), "rational_polynomial": ("radtan", 8), "equidistant": ("equidistant", 4)}
#: COLMAP camera models -> (model, parameter names); ``f`` sets fx = fy.
COLMAP_MODELS = {
    "SIMPLE_PINHOLE": ("pinhole", ("f", "cx", "cy")),
    "PINHOLE": ("pinhole", ("fx", "fy", "cx", "cy")),
    "SIMPLE_RADIAL": ("radtan", ("f", "cx", "cy", "k1")),
    "RADIAL": ("radtan", ("f", "cx", "cy", "k1", "k2")),
    "OPENCV": ("radtan", ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")),
    "FULL_OPENCV": ("radtan", ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")),
    "OPENCV_FISHEYE": ("equidistant", ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")),
}
#: Kalibr distortion models -> (model, coefficient count).
KALIBR_MODELS = {"radtan": ("radtan", 4), "equidistant": ("equidistant", 4), "none": ("pinhole", 0)}
#: Every lens a file may name, for the "not supported" message.
SUPPORTED = (
    "ROS plumb_bob, rational_polynomial, equidistant; OpenCV radtan (4, 5, 8 coefficients) and fisheye; Kalibr "
    "pinhole-radtan, pinhole-equidistant; COLMAP " + ", ".join(COLMAP_MODELS)
)


class _OpenCVLoader(yaml.SafeLoader):
    """PyYAML's safe loader that also reads OpenCV's ``!!opencv-matrix`` / ``!!opencv-nd-matrix`` nodes (as
    mappings with a ``__opencv__`` key)."""


def _opencv_node(loader: yaml.SafeLoader, node: yaml.Node) -> dict:
    if not isinstance(node, yaml.MappingNode):
        raise yaml.constructor.ConstructorError(None, None, "an !!opencv-matrix must be a mapping", node.start_mark)
    return {"__opencv__": True, **loader.construct_mapping(node, deep=True)}


_OpenCVLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", _opencv_node)
_OpenCVLoader.add_constructor("tag:yaml.org,2002:opencv-nd-matrix", _opencv_node)


def _read_text(path: Path) -> str:
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise DatasetError(f"{path}: {size} bytes is too big for a calibration file")
        return path.read_bytes().decode("utf-8-sig")
    except FileNotFoundError:
        raise DatasetError(f"{path}: calibration file not found") from None
    except IsADirectoryError:
        raise DatasetError(f"{path}: is a folder, not a calibration file") from None
    except UnicodeDecodeError:
        raise DatasetError(f"{path}: not a text file (a calibration file is YAML or COLMAP's cameras.txt)") from None
    except OSError as e:
        raise DatasetError(f"{path}: cannot read the calibration file ({e.strerror or e})") from None


def _yaml(text: str, where: str) -> Any:
    lines = text.splitlines()
    if lines and lines[0].startswith("%YAML:"):  # OpenCV's directive (PyYAML wants "%YAML 1.x")
        lines[0] = "# " + lines[0]
    try:
        return yaml.load("\n".join(lines), Loader=_OpenCVLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        at = f" (line {mark.line + 1})" if mark is not None else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise DatasetError(f"{where}: not valid YAML{at}: {problem}") from None
    except (ValueError, RecursionError) as e:  # a number PyYAML cannot convert, nesting too deep
        raise DatasetError(f"{where}: not a calibration file ({type(e).__name__}: {str(e).splitlines()[0]})") from None


def _number(value: Any, where: str, what: str) -> float:
    if isinstance(value, bool):
        raise DatasetError(f"{where}: {what} must be a number, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError, OverflowError):
        raise DatasetError(f"{where}: {what} must be a number, got {str(value)[:40]!r}") from None


def _integer(value: Any, where: str, what: str) -> int:
    v = _number(value, where, what)
    if not (math.isfinite(v) and v == int(v) and v > 0):
        raise DatasetError(f"{where}: {what} must be a positive integer, got {value!r}")
    return int(v)


def _numbers(values: Any, where: str, what: str) -> list[float]:
    if not isinstance(values, (list, tuple)):
        raise DatasetError(f"{where}: {what} must be a list of numbers, got {values!r}")
    return [_number(v, where, what) for v in values]


def _matrix(node: Any, where: str, what: str) -> np.ndarray:
    """A ``{rows, cols, data}`` node (ROS; OpenCV adds ``dt``) or a plain list -> 2-D float64 array."""
    if isinstance(node, Mapping):
        if "data" not in node:
            raise DatasetError(f"{where}: {what} has no data")
        data = _numbers(node["data"], where, f"{what}.data")
        rows = _integer(node.get("rows", 1), where, f"{what}.rows")
        cols = _integer(node.get("cols", len(data)), where, f"{what}.cols")
        if rows * cols != len(data):
            raise DatasetError(f"{where}: {what} is {rows}x{cols} but holds {len(data)} values")
        return np.asarray(data, dtype=np.float64).reshape(rows, cols)
    if isinstance(node, (list, tuple)):
        if node and all(isinstance(r, (list, tuple)) for r in node):
            rows = [_numbers(r, where, what) for r in node]
            if len({len(r) for r in rows}) != 1:
                raise DatasetError(f"{where}: {what} has rows of different lengths")
            return np.asarray(rows, dtype=np.float64)
        return np.asarray(_numbers(node, where, what), dtype=np.float64).reshape(1, -1)
    raise DatasetError(f"{where}: {what} must be a matrix, got {node!r}")


def _camera_matrix(node: Any, where: str, what: str) -> tuple[float, float, float, float, float]:
    """``(fx, fy, cx, cy, skew)`` of a 3x3 camera matrix node (as stored: the caller shifts the pixel convention)."""
    k = _matrix(node, where, what)
    if k.size != 9:
        raise DatasetError(f"{where}: {what} must be 3x3 (9 values), got {k.size} values")
    k = k.reshape(3, 3)
    if not np.isfinite(k).all():
        raise DatasetError(f"{where}: {what} holds NaN or infinite values: {k.reshape(-1).tolist()}")
    if k[1, 0] != 0 or k[2, 0] != 0 or k[2, 1] != 0 or k[2, 2] == 0:
        raise DatasetError(f"{where}: {what} is not a camera matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
    k = k / k[2, 2]
    return float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]), float(k[0, 1])


def _unsupported(where: str, name: str) -> DatasetError:
    return DatasetError(f"{where}: lens model {name} is not supported (supported: {SUPPORTED})")


def _get(d: Mapping, *names: str) -> Any:
    for n in names:
        if n in d:
            return d[n]
    lower = {str(k).lower(): v for k, v in d.items()}
    for n in names:
        if n.lower() in lower:
            return lower[n.lower()]
    return None


# ----------------------------------------------------------------------------------------------------------------
# the layouts


def parse_ros_yaml(doc: Mapping, where: str) -> Calibration:
    """A ROS camera_info YAML document (see the module docstring)."""
    w = _integer(doc.get("image_width"), where, "image_width")
    h = _integer(doc.get("image_height"), where, "image_height")
    fx, fy, cx, cy, skew = _camera_matrix(doc.get("camera_matrix"), where, "camera_matrix")
    name = str(doc.get("distortion_model") or "")
    d = doc.get("distortion_coefficients")
    coeffs = [] if d is None else _matrix(d, where, "distortion_coefficients").reshape(-1).tolist()
    model = _ros_model(name, coeffs, where)
    return Calibration(
        (h, w),
        fx,
        fy,
        cx + 0.5,
        cy + 0.5,
        model=model,
        coefficients=tuple(coeffs),
        skew=skew,
        source=where,
        layout="ros",
        camera_name=str(doc.get("camera_name") or ""),
    ).check()


def _ros_model(name: str, coeffs: Sequence[float], where: str) -> str:
    """The lens model of a ROS ``distortion_model`` name and its coefficients."""
    if name in ROS_MODELS:
        model, most = ROS_MODELS[name]
        if len(coeffs) > most and any(v != 0 for v in coeffs[most:]):
            raise DatasetError(f"{where}: distortion model {name} takes at most {most} coefficients, got {len(coeffs)}")
        if model == "equidistant" and len(coeffs) not in (0, 4):
            raise DatasetError(f"{where}: distortion model equidistant takes 4 coefficients, got {len(coeffs)}")
        return model
    if name in ("", "none", "pinhole") and not any(v != 0 for v in coeffs):
        return "pinhole"
    raise _unsupported(where, repr(name) if name else "(unnamed, with non-zero coefficients)")


def parse_opencv_yaml(doc: Mapping, where: str) -> Calibration:
    """An OpenCV FileStorage YAML document (see the module docstring)."""
    w = _get(doc, "image_width", "imageWidth", "width")
    h = _get(doc, "image_height", "imageHeight", "height")
    size = _get(doc, "image_size", "imageSize", "resolution")
    if (w is None or h is None) and size is not None:
        wh = _matrix(size, where, "image_size").reshape(-1)
        if wh.size != 2:
            raise DatasetError(f"{where}: image_size must be [width, height], got {wh.tolist()}")
        w, h = wh.tolist()
    if w is None or h is None:
        raise DatasetError(f"{where}: no image_width and image_height (the size of the calibrated images)")
    w, h = _integer(w, where, "image_width"), _integer(h, where, "image_height")
    km = _get(doc, "camera_matrix", "cameraMatrix", "K", "intrinsic_matrix", "intrinsics")
    if km is None:
        raise DatasetError(f"{where}: no camera_matrix")
    fx, fy, cx, cy, skew = _camera_matrix(km, where, "camera_matrix")
    dn = _get(doc, "distortion_coefficients", "dist_coeffs", "distCoeffs", "distortion", "D")
    coeffs = [] if dn is None else _matrix(dn, where, "distortion_coefficients").reshape(-1).tolist()
    fisheye = _get(doc, "fisheye_model", "fisheye", "is_fisheye")
    named = str(_get(doc, "distortion_model") or "").strip().lower()
    if (fisheye not in (None, 0, False, "0", "false")) or named in ("fisheye", "equidistant"):
        if len(coeffs) != 4:
            raise DatasetError(f"{where}: the OpenCV fisheye model takes 4 coefficients, got {len(coeffs)}")
        model = "equidistant"
    elif named not in ("", "radtan", "plumb_bob", "rational_polynomial", "pinhole"):
        raise _unsupported(where, repr(named))
    elif len(coeffs) in (0, 4, 5, 8):
        model = "radtan" if any(v != 0 for v in coeffs) else "pinhole"
    elif len(coeffs) in (12, 14):
        if any(v != 0 for v in coeffs[8:]):
            raise _unsupported(where, f"OpenCV with thin-prism/tilt terms ({len(coeffs)} coefficients)")
        model, coeffs = "radtan", coeffs[:8]
    else:
        raise DatasetError(f"{where}: {len(coeffs)} distortion coefficients; OpenCV has 4, 5, 8, 12 or 14")
    return Calibration(
        (h, w),
        fx,
        fy,
        cx + 0.5,
        cy + 0.5,
        model=model,
        coefficients=tuple(coeffs) if model != "pinhole" else (),
        skew=skew,
        source=where,
        layout="opencv",
    ).check()


def parse_kalibr_yaml(doc: Mapping, where: str, camera: str = "cam0") -> Calibration:
    """A Kalibr camchain document: camera ``camera`` (see the module docstring)."""
    cams = sorted(k for k in doc if isinstance(k, str) and re.fullmatch(r"cam\d+", k))
    if camera not in doc:
        raise DatasetError(f"{where}: no camera {camera!r} in the camchain (cameras: {', '.join(cams) or 'none'})")
    cam = doc[camera]
    if not isinstance(cam, Mapping):
        raise DatasetError(f"{where}: {camera} must be a mapping")
    here = f"{where} ({camera})"
    cm = str(cam.get("camera_model", "pinhole"))
    dm = str(cam.get("distortion_model", "none"))
    if cm != "pinhole":
        raise _unsupported(here, f"{cm}-{dm} (Kalibr)")
    if dm not in KALIBR_MODELS:
        raise _unsupported(here, f"{cm}-{dm} (Kalibr)")
    model, count = KALIBR_MODELS[dm]
    intr = _numbers(cam.get("intrinsics"), here, "intrinsics")
    if len(intr) != 4:
        raise DatasetError(f"{here}: intrinsics must be [fu, fv, pu, pv], got {len(intr)} values")
    coeffs = _numbers(cam.get("distortion_coeffs", []), here, "distortion_coeffs")
    if len(coeffs) != count:
        raise DatasetError(f"{here}: distortion model {dm} takes {count} coefficients, got {len(coeffs)}")
    res = _numbers(cam.get("resolution"), here, "resolution")
    if len(res) != 2:
        raise DatasetError(f"{here}: resolution must be [width, height], got {res}")
    w, h = _integer(res[0], here, "resolution width"), _integer(res[1], here, "resolution height")
    t = cam.get("T_cam_imu")
    t_cam_imu = None
    if t is not None:
        m = _matrix(t, here, "T_cam_imu")
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise DatasetError(f"{here}: T_cam_imu must be a finite 4x4 matrix")
        r = m[:3, :3]
        if np.abs(r @ r.T - np.eye(3)).max() > 1e-4 or np.linalg.det(r) < 0:
            raise DatasetError(f"{here}: T_cam_imu's rotation is not a rotation matrix")
        t_cam_imu = tuple(tuple(float(v) for v in row) for row in m)
    others = [c for c in cams if c != camera]
    note = f"{where}: read {camera} of the cameras {', '.join(cams)}" if others else ""
    return Calibration(
        (h, w),
        intr[0],
        intr[1],
        intr[2] + 0.5,
        intr[3] + 0.5,
        model=model,
        coefficients=tuple(coeffs),
        source=here,
        layout="kalibr",
        camera_name=str(cam.get("rostopic", "") or ""),
        t_cam_imu=t_cam_imu,
        note=note,
    ).check()


def parse_colmap_cameras(text: str, where: str) -> Calibration:
    """COLMAP's ``cameras.txt``: the first camera (see the module docstring)."""
    rows = []
    for n, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if s and not s.startswith("#"):
            rows.append((n, s.split()))
    if not rows:
        raise DatasetError(f"{where}: no camera line (CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]) in the file")
    n, parts = rows[0]
    here = f"{where}:{n}"
    if len(parts) < 4:
        raise DatasetError(f"{here}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[], got {' '.join(parts)!r}")
    name = parts[1]
    if name not in COLMAP_MODELS:
        raise _unsupported(here, f"{name} (COLMAP)")
    model, names = COLMAP_MODELS[name]
    w, h = _integer(parts[2], here, "WIDTH"), _integer(parts[3], here, "HEIGHT")
    params = [_number(v, here, "a parameter") for v in parts[4:]]
    if len(params) != len(names):
        raise DatasetError(f"{here}: COLMAP {name} has {len(names)} parameters ({' '.join(names)}), got {len(params)}")
    p = dict(zip(names, params))
    fx = p.get("fx", p.get("f"))
    fy = p.get("fy", p.get("f"))
    coeffs: tuple[float, ...] = ()
    if model == "radtan":
        coeffs = (p.get("k1", 0.0), p.get("k2", 0.0), p.get("p1", 0.0), p.get("p2", 0.0), p.get("k3", 0.0))
        coeffs += (p.get("k4", 0.0), p.get("k5", 0.0), p.get("k6", 0.0))
    elif model == "equidistant":
        coeffs = (p["k1"], p["k2"], p["k3"], p["k4"])
    note = f"{where}: read camera {parts[0]}, the first of {len(rows)}" if len(rows) > 1 else ""
    return Calibration(
        (h, w),
        fx,
        fy,
        p["cx"],
        p["cy"],
        model=model,
        coefficients=coeffs,
        source=here,
        layout="colmap",
        camera_name=f"camera {parts[0]}",
        note=note,
    ).check()


_COLMAP_LINE = re.compile(r"^\s*\d+\s+[A-Z_]+\s+\d+\s+\d+(\s+\S+)*\s*$")


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration file in any of the layouts of the module docstring (recognised from its content).

    Returns a checked :class:`~cosemdepth.camera.calibration.Calibration` (package pixel convention). Raises a
    one-line :class:`~cosemdepth.errors.DatasetError` naming the file for anything else: not a calibration, a lens
    model this package does not handle, NaN or singular intrinsics, a lens that folds over the image.
    """
    path = Path(path)
    where = str(path)
    text = _read_text(path)
    lines = [s for s in (line.strip() for line in text.splitlines()) if s and not s.startswith("#")]
    if lines and all(_COLMAP_LINE.match(s) for s in lines):
        return parse_colmap_cameras(text, where)
    doc = _yaml(text, where)
    if not isinstance(doc, Mapping):
        raise DatasetError(
            f"{where}: not a calibration file this package reads (ROS camera_info YAML, OpenCV FileStorage YAML, "
            "Kalibr camchain YAML, COLMAP cameras.txt)"
        )
    if any(isinstance(k, str) and re.fullmatch(r"cam\d+", k) for k in doc):
        return parse_kalibr_yaml(doc, where)
    km = _get(doc, "camera_matrix", "cameraMatrix", "K", "intrinsic_matrix")
    opencv = text.lstrip().startswith("%YAML:") or (isinstance(km, Mapping) and km.get("__opencv__"))
    if not opencv and "image_width" in doc and isinstance(doc.get("camera_matrix"), Mapping):
        return parse_ros_yaml(doc, where)
    if km is not None:
        return parse_opencv_yaml(doc, where)
    raise DatasetError(
        f"{where}: not a calibration file this package reads: no camera_matrix (ROS, OpenCV), cam0 (Kalibr) or "
        "camera lines (COLMAP cameras.txt)"
    )


def calibration_from_camera_info(msg: Any, where: str) -> Calibration:
    """A ``sensor_msgs/CameraInfo`` message (ROS 2 ``k``, ``d``; ROS 1 ``K``, ``D``) -> Calibration. The
    ``distortion_model`` is ``plumb_bob``, ``rational_polynomial`` or ``equidistant`` (or empty / all-zero ``d``:
    none); binning and a region of interest are not supported (a DatasetError)."""
    k = np.asarray(getattr(msg, "k", None) if hasattr(msg, "k") else msg.K, dtype=np.float64).reshape(-1)
    d = np.asarray(getattr(msg, "d", None) if hasattr(msg, "d") else msg.D, dtype=np.float64).reshape(-1)
    if k.size != 9 or not np.isfinite(k).all() or k[0] <= 0 or k[4] <= 0:
        raise DatasetError(f"{where}: camera_info K is not a valid camera matrix (fx, fy must be > 0): {k.tolist()}")
    bx, by = int(getattr(msg, "binning_x", 0) or 0), int(getattr(msg, "binning_y", 0) or 0)
    roi = getattr(msg, "roi", None)
    roi_set = roi is not None and any(int(getattr(roi, a, 0) or 0) for a in ("x_offset", "y_offset", "height", "width"))
    if bx > 1 or by > 1 or roi_set:
        raise DatasetError(f"{where}: camera_info with binning or a region of interest is not supported")
    name = str(getattr(msg, "distortion_model", "") or "")
    coeffs = [float(v) for v in d]
    model = _ros_model(name, coeffs, where)
    fx, fy, cx, cy, skew = _camera_matrix(k.tolist(), where, "camera_info K")
    return Calibration(
        (int(msg.height), int(msg.width)),
        fx,
        fy,
        cx + 0.5,
        cy + 0.5,
        model=model,
        coefficients=tuple(coeffs) if model != "pinhole" else (),
        skew=skew,
        source=where,
        layout="camera_info",
    )


__all__ = [
    "COLMAP_MODELS",
    "KALIBR_MODELS",
    "ROS_MODELS",
    "calibration_from_camera_info",
    "load_calibration",
    "parse_colmap_cameras",
    "parse_kalibr_yaml",
    "parse_opencv_yaml",
    "parse_ros_yaml",
]
