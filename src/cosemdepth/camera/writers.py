"""A :class:`~cosemdepth.camera.calibration.Calibration` written in the layouts :func:`load_calibration` reads.

Each writer returns the file's text in the tool's own layout and pixel convention (ROS, OpenCV and Kalibr count
pixel centres from 0: ``cx - 0.5``; COLMAP as the package). Numbers are written with Python's shortest round-trip
``repr``, so reading a file back gives the same float64 values. A lens a layout cannot express is a ValueError.
"""

from __future__ import annotations

from .calibration import Calibration

#: File names :func:`write_all` uses, by layout.
FILE_NAMES = {
    "ros": "camera_info.yaml",
    "opencv": "opencv_calibration.yaml",
    "kalibr": "kalibr_camchain.yaml",
    "colmap": "colmap_cameras.txt",
}


def _list(values) -> str:
    return "[" + ", ".join(repr(float(v)) for v in values) + "]"


def _radtan_count(cal: Calibration) -> int:
    c = cal.coefficients
    return 8 if any(v != 0 for v in c[5:]) else 5


def ros_yaml(cal: Calibration, camera_name: str = "camera") -> str:
    """ROS camera_info YAML (camera_calibration_parsers' layout)."""
    fx, fy, cx, cy = cal.fx, cal.fy, cal.cx - 0.5, cal.cy - 0.5
    if cal.model == "radtan":
        n = _radtan_count(cal)
        name, d = ("plumb_bob" if n == 5 else "rational_polynomial"), cal.coefficients[:n]
    elif cal.model == "equidistant":
        name, d = "equidistant", cal.coefficients
    else:
        name, d = "plumb_bob", (0.0,) * 5
    lines = [
        f"image_width: {cal.size[1]}",
        f"image_height: {cal.size[0]}",
        f"camera_name: {camera_name}",
        "camera_matrix:",
        "  rows: 3",
        "  cols: 3",
        f"  data: {_list([fx, cal.skew, cx, 0, fy, cy, 0, 0, 1])}",
        f"distortion_model: {name}",
        "distortion_coefficients:",
        "  rows: 1",
        f"  cols: {len(d)}",
        f"  data: {_list(d)}",
        "rectification_matrix:",
        "  rows: 3",
        "  cols: 3",
        f"  data: {_list([1, 0, 0, 0, 1, 0, 0, 0, 1])}",
        "projection_matrix:",
        "  rows: 3",
        "  cols: 4",
        f"  data: {_list([fx, cal.skew, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0])}",
    ]
    return "\n".join(lines) + "\n"


def _opencv_matrix(name: str, rows: int, cols: int, data) -> list[str]:
    return [f"{name}: !!opencv-matrix", f"   rows: {rows}", f"   cols: {cols}", "   dt: d", f"   data: {_list(data)}"]


def opencv_yaml(cal: Calibration) -> str:
    """OpenCV FileStorage YAML (``%YAML:1.0``, ``!!opencv-matrix``; ``fisheye_model: 1`` for equidistant)."""
    k = [cal.fx, cal.skew, cal.cx - 0.5, 0, cal.fy, cal.cy - 0.5, 0, 0, 1]
    if cal.model == "radtan":
        d = cal.coefficients[: _radtan_count(cal)]
    elif cal.model == "equidistant":
        d = cal.coefficients
    else:
        d = (0.0,) * 5
    lines = ["%YAML:1.0", "---", f"image_width: {cal.size[1]}", f"image_height: {cal.size[0]}"]
    lines += _opencv_matrix("camera_matrix", 3, 3, k)
    lines += _opencv_matrix("distortion_coefficients", 1, len(d), d)
    lines.append(f"fisheye_model: {1 if cal.model == 'equidistant' else 0}")
    return "\n".join(lines) + "\n"


def kalibr_yaml(cal: Calibration, rostopic: str = "/cam0/image_raw") -> str:
    """A Kalibr camchain with one camera ``cam0`` (pinhole-radtan with 4 coefficients, pinhole-equidistant, or
    pinhole-none)."""
    if cal.model == "radtan":
        if any(v != 0 for v in cal.coefficients[4:]):
            raise ValueError("Kalibr's radtan model has 4 coefficients (k1, k2, p1, p2); this lens needs more")
        model, d = "radtan", cal.coefficients[:4]
    elif cal.model == "equidistant":
        model, d = "equidistant", cal.coefficients
    else:
        model, d = "none", ()
    if cal.skew != 0:
        raise ValueError("Kalibr's pinhole model has no skew")
    lines = [
        "cam0:",
        "  camera_model: pinhole",
        f"  intrinsics: {_list([cal.fx, cal.fy, cal.cx - 0.5, cal.cy - 0.5])}",
        f"  distortion_model: {model}",
        f"  distortion_coeffs: {_list(d)}",
        f"  resolution: [{cal.size[1]}, {cal.size[0]}]",
        f"  rostopic: {rostopic}",
    ]
    if cal.t_cam_imu is not None:
        lines.append("  T_cam_imu:")
        lines += [f"  - {_list(row)}" for row in cal.t_cam_imu]
    return "\n".join(lines) + "\n"


def colmap_cameras(cal: Calibration, camera_id: int = 1) -> str:
    """COLMAP ``cameras.txt`` with one camera (PINHOLE, OPENCV, FULL_OPENCV or OPENCV_FISHEYE)."""
    if cal.skew != 0:
        raise ValueError("COLMAP's camera models have no skew")
    k = [cal.fx, cal.fy, cal.cx, cal.cy]
    if cal.model == "radtan":
        model, p = ("OPENCV", k + list(cal.coefficients[:4]))
        if any(v != 0 for v in cal.coefficients[4:]):
            model, p = "FULL_OPENCV", k + list(cal.coefficients)
    elif cal.model == "equidistant":
        model, p = "OPENCV_FISHEYE", k + list(cal.coefficients)
    else:
        model, p = "PINHOLE", k
    return (
        "# Camera list with one line of data per camera:\n"
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        "# Number of cameras: 1\n"
        f"{camera_id} {model} {cal.size[1]} {cal.size[0]} " + " ".join(repr(float(v)) for v in p) + "\n"
    )


def calibration_files(cal: Calibration) -> dict[str, str]:
    """``{file name: text}`` of every layout that can express ``cal`` (:data:`FILE_NAMES`)."""
    out = {}
    for layout, write in (
        ("ros", ros_yaml),
        ("opencv", opencv_yaml),
        ("kalibr", kalibr_yaml),
        ("colmap", colmap_cameras),
    ):
        try:
            out[FILE_NAMES[layout]] = write(cal)
        except ValueError:
            continue
    return out


__all__ = ["FILE_NAMES", "calibration_files", "colmap_cameras", "kalibr_yaml", "opencv_yaml", "ros_yaml"]
