"""Calibration files in the real layouts of ROS, OpenCV, Kalibr and COLMAP -> Calibration, against hand-read values
(each layout's pixel-centre convention converted to the package's: centres at +0.5), files written by OpenCV itself
(cv2.FileStorage), and the one-line errors (exit 2 from the CLI) for everything else."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from cosemdepth.camera import Calibration, load_calibration
from cosemdepth.camera.parsers import calibration_from_camera_info
from cosemdepth.camera.writers import calibration_files
from cosemdepth.errors import DatasetError

FIXTURES = Path(__file__).parent / "fixtures"


def test_ros_camera_info_yaml():
    cal = load_calibration(FIXTURES / "ros_camera_info.yaml")
    assert cal.size == (480, 640) and cal.layout == "ros" and cal.camera_name == "narrow_stereo"
    # ROS counts pixel centres from 0: cx 318.5 is the package's 319.0; the projection matrix is not used
    assert cal.k == (423.12345, 421.5, 319.0, 242.75) and cal.skew == 0
    assert cal.model == "radtan" and cal.coefficients == (-0.281, 0.0732, 0.00041, -0.00022, 0, 0, 0, 0)


@pytest.mark.parametrize(
    "model,d,expect",
    [
        ("rational_polynomial", [-0.1, 0.02, 0.001, 0.002, 0.0, 0.05, 0.01, 0.001], "radtan"),
        ("equidistant", [0.01, -0.002, 0.0005, 0.0], "equidistant"),
        ("plumb_bob", [0.0, 0.0, 0.0, 0.0, 0.0], "pinhole"),
    ],
)
def test_ros_distortion_models(tmp_path, model, d, expect):
    text = (FIXTURES / "ros_camera_info.yaml").read_text()
    text = text.replace("distortion_model: plumb_bob", f"distortion_model: {model}")
    text = text.replace("  cols: 5\n  data: [-0.281, 0.0732, 0.00041, -0.00022, 0.0]", f"  cols: {len(d)}\n  data: {d}")
    (tmp_path / "c.yaml").write_text(text)
    cal = load_calibration(tmp_path / "c.yaml")
    assert cal.model == expect
    if expect != "pinhole":
        assert cal.coefficients[: len(d)] == tuple(d)


def test_opencv_filestorage_by_hand_with_its_header_and_tags():
    cal = load_calibration(FIXTURES / "opencv_out_camera_data.yml")
    assert cal.size == (720, 1280) and cal.layout == "opencv"
    assert cal.k == (657.46697944293521, 657.46697944293521, 640.0, 360.0)  # 639.5 + 0.5
    assert cal.model == "radtan" and cal.coefficients[:5] == (-0.25, 0.08, 0.0, 0.0, -0.01)


def _write_filestorage(path: Path, k, d, size, fisheye=None):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", size[1])
    fs.write("image_height", size[0])
    fs.write("camera_matrix", np.asarray(k, dtype=np.float64))
    fs.write("distortion_coefficients", np.asarray(d, dtype=np.float64).reshape(-1, 1))
    if fisheye is not None:
        fs.write("fisheye_model", int(fisheye))
    fs.release()


def test_opencv_filestorage_written_by_opencv(tmp_path):
    k = [[612.25, 0.0, 331.75], [0.0, 611.5, 243.125], [0.0, 0.0, 1.0]]
    d = [-0.21, 0.045, 0.0007, -0.0003, -0.0041]
    _write_filestorage(tmp_path / "cv.yml", k, d, (480, 640))
    # OpenCV 4 writes a "%YAML:1.0" header (the hand-written fixture above), OpenCV 5 "%YAML 1.2"; both have the tags
    text = (tmp_path / "cv.yml").read_text()
    assert text.startswith("%YAML") and "!!opencv-matrix" in text
    cal = load_calibration(tmp_path / "cv.yml")
    assert cal.k == (612.25, 611.5, 332.25, 243.625) and cal.coefficients[:5] == tuple(d)
    _write_filestorage(tmp_path / "fe.yml", k, d[:4], (480, 640), fisheye=1)
    fe = load_calibration(tmp_path / "fe.yml")
    assert fe.model == "equidistant" and fe.coefficients == tuple(d[:4])


def test_kalibr_camchain_reads_cam0_and_its_imu_transform():
    cal = load_calibration(FIXTURES / "kalibr_camchain.yaml")
    assert cal.layout == "kalibr" and cal.size == (480, 752)
    assert cal.k == (458.654, 457.296, 367.715, 248.875)  # pu, pv + 0.5
    assert cal.model == "radtan" and cal.coefficients[:4] == (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)
    assert "cam0 of the cameras cam0, cam1" in cal.note
    m = cal.mount_rotation
    assert m.shape == (3, 3) and m[0, 1] == -0.999880929698 and abs(np.linalg.det(m) - 1) < 1e-6
    eq = load_calibration(FIXTURES / "kalibr_equidistant.yaml")
    assert eq.model == "equidistant" and eq.k[2] == 254.93170605935475 + 0.5 and eq.mount_rotation is None


def test_colmap_cameras_txt_reads_the_first_camera_without_a_shift():
    cal = load_calibration(FIXTURES / "colmap_cameras.txt")
    assert cal.layout == "colmap" and cal.size == (1080, 1920)
    assert cal.k == (1130.5, 1131.25, 960.0, 540.0)  # COLMAP's centres are at +0.5 already
    assert cal.coefficients == (-0.12, 0.035, 0.0004, -0.0002, 0, 0, 0, 0)
    assert "camera 1, the first of 2" in cal.note


@pytest.mark.parametrize(
    "line,model,k,coeffs",
    [
        ("3 SIMPLE_PINHOLE 640 480 500 320 240", "pinhole", (500, 500, 320, 240), ()),
        ("3 PINHOLE 640 480 500 501 320 240", "pinhole", (500, 501, 320, 240), ()),
        ("3 SIMPLE_RADIAL 640 480 500 320 240 -0.05", "radtan", (500, 500, 320, 240), (-0.05,)),
        ("3 RADIAL 640 480 500 320 240 -0.05 0.01", "radtan", (500, 500, 320, 240), (-0.05, 0.01)),
        ("3 OPENCV_FISHEYE 640 480 300 300 320 240 0.01 0.002 0 0", "equidistant", (300, 300, 320, 240), (0.01, 0.002)),
        (
            "3 FULL_OPENCV 640 480 500 500 320 240 -0.1 0.01 0 0 0.001 0.02 0 0",
            "radtan",
            (500, 500, 320, 240),
            (-0.1, 0.01, 0, 0, 0.001, 0.02),
        ),
    ],
)
def test_colmap_models(tmp_path, line, model, k, coeffs):
    (tmp_path / "cameras.txt").write_text("# comment\n" + line + "\n")
    cal = load_calibration(tmp_path / "cameras.txt")
    assert cal.model == model and cal.k == k
    assert cal.coefficients[: len(coeffs)] == coeffs


@pytest.mark.parametrize(
    "name,text,message",
    [
        ("kalibr_omni.yaml", "cam0:\n  camera_model: omni\n  distortion_model: radtan\n", "lens model omni-radtan"),
        ("kalibr_fov.yaml", "cam0:\n  camera_model: pinhole\n  distortion_model: fov\n", "lens model pinhole-fov"),
        ("cameras.txt", "1 FOV 640 480 500 500 320 240 0.9\n", "lens model FOV (COLMAP) is not supported"),
        (
            "ros.yaml",
            "image_width: 4\nimage_height: 4\ncamera_matrix: {rows: 3, cols: 3, data: [1,0,1,0,1,1,0,0,1]}\n"
            "distortion_model: weird\n",
            "lens model 'weird' is not supported",
        ),
        ("notes.yaml", "hello: world\n", "not a calibration file this package reads"),
        ("list.yaml", "- 1\n- 2\n", "not a calibration file this package reads"),
        ("bad.yaml", "camera_matrix: [1, 2\n", "not valid YAML"),
        ("nan.txt", "1 PINHOLE 640 480 nan 500 320 240\n", "NaN or infinite"),
        ("zero.txt", "1 PINHOLE 640 480 0 500 320 240\n", "singular or flipped (fx = 0"),
        ("count.txt", "1 OPENCV 640 480 500 500 320 240 0.1\n", "OPENCV has 8 parameters"),
    ],
)
def test_bad_files_are_one_line_errors_naming_the_file(tmp_path, name, text, message):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(DatasetError) as e:
        load_calibration(path)
    msg = str(e.value)
    assert str(path) in msg and message in msg and "\n" not in msg, msg


def test_a_folding_lens_is_refused():
    """The OpenCV sample's k3 = -0.58 turns the radius back at about 40 degrees off-axis, inside the image."""
    with pytest.raises(DatasetError, match=r"opencv_folding.yml: the radtan coefficients .* fold the image"):
        load_calibration(FIXTURES / "opencv_folding.yml")
    # equidistant: theta (1 - 0.5 theta^2) peaks at theta = 0.816 (radius 0.544), short of the corner (1.41)
    with pytest.raises(DatasetError, match="fold the image"):
        Calibration((64, 64), 32, 32, 32, 32, model="equidistant", coefficients=(-0.5, 0, 0, 0)).check()


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(DatasetError, match="calibration file not found"):
        load_calibration(tmp_path / "none.yaml")
    with pytest.raises(DatasetError, match="is a folder"):
        load_calibration(tmp_path)


def test_scaling_to_another_size_only_at_the_same_aspect_ratio():
    cal = load_calibration(FIXTURES / "opencv_out_camera_data.yml")
    half = cal.for_image_size((360, 640))
    assert half.k == (cal.fx / 2, cal.fy / 2, 320.0, 180.0) and half.coefficients == cal.coefficients
    assert "for 1280x720 images, the images are 640x360: scaled by 0.5" in half.note
    assert cal.for_image_size((720, 1280)) is cal
    with pytest.raises(DatasetError, match=r"for 1280x720 images but the images are 640x480 \(WxH\), of another"):
        cal.for_image_size((480, 640))


def test_written_files_read_back_as_the_same_camera(tmp_path):
    """Every layout the writers produce reads back (our reader and OpenCV's FileStorage) to the same numbers."""
    cal = Calibration((96, 128), 70.25, 70.5, 63.75, 48.5, model="radtan", coefficients=(-0.3, 0.1, 0.001, -0.0005))
    files = calibration_files(cal)
    assert set(files) == {"camera_info.yaml", "opencv_calibration.yaml", "kalibr_camchain.yaml", "colmap_cameras.txt"}
    for name, text in files.items():
        (tmp_path / name).write_text(text)
        back = load_calibration(tmp_path / name)
        assert (back.size, back.k, back.model, back.coefficients) == (cal.size, cal.k, cal.model, cal.coefficients)
    fs = cv2.FileStorage(str(tmp_path / "opencv_calibration.yaml"), cv2.FILE_STORAGE_READ)
    np.testing.assert_array_equal(fs.getNode("camera_matrix").mat(), [[70.25, 0, 63.25], [0, 70.5, 48.0], [0, 0, 1]])
    assert fs.getNode("image_width").real() == 128
    fs.release()


def test_camera_info_message_models():
    class Msg:
        height, width, binning_x, binning_y, roi = 48, 64, 0, 0, None
        k = [50.0, 0, 31.5, 0, 60.0, 23.5, 0, 0, 1]
        d = [0.01, -0.002, 0.0005, 0.0]
        distortion_model = "equidistant"

    cal = calibration_from_camera_info(Msg(), "WHERE")
    assert cal.model == "equidistant" and cal.k == (50, 60, 32, 24) and math.isclose(cal.coefficients[0], 0.01)
    Msg.distortion_model = "fisheye_double_sphere"
    with pytest.raises(DatasetError, match="WHERE: lens model 'fisheye_double_sphere' is not supported"):
        calibration_from_camera_info(Msg(), "WHERE")
