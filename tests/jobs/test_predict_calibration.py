"""``predict`` with a distorting lens: a bag whose camera_info is ``plumb_bob`` gives the same depth as the same frames
given as a flight with the equivalent ``--calibration`` YAML; the output camera_info is the undistorted pinhole; the
pixels without a source pixel are never valid."""

import json  # noqa: I001 (the commands' test helpers are put on the path first)
import sys
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))  # the commands' test helpers
from _outputs import _one_thread, model_dir  # noqa: F401 (pytest fixtures)
from test_predict_bag import K, bag_args, make_bag, make_flight, predict, read_bag

from cosemdepth.camera import Calibration, Undistorter, load_calibration

D = (-0.25, 0.05, 0.001, -0.001, 0.0)  # a strong barrel lens on the 32x32 test images (f = 16 px)


def ros_yaml(d, k=K) -> str:
    fx, fy, cx, cy = k
    return (
        "image_width: 32\nimage_height: 32\ncamera_name: test\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
        f"  data: [{fx}, 0, {cx}, 0, {fy}, {cy}, 0, 0, 1]\ndistortion_model: plumb_bob\n"
        f"distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: {list(d)}\n"
        "rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
        f"projection_matrix:\n  rows: 3\n  cols: 4\n  data: [{fx}, 0, {cx}, 0, 0, {fy}, {cy}, 0, 0, 0, 1, 0]\n"
    )


def outputs(out):
    man = json.loads((out / "predictions.json").read_text())
    depth = [np.load(out / f["files"]["depth"]) for f in man["frames"]]
    valid = [np.asarray(Image.open(out / f["files"]["depth_valid"])) > 0 for f in man["frames"]]
    return man, depth, valid


def test_plumb_bob_bag_equals_the_flight_with_the_calibration_file(model_dir, tmp_path):
    bag = make_bag(tmp_path / "in", distortion=D)
    assert predict("--model", model_dir, *bag_args(bag, "--camera-info-topic", "/cam/info", "--size", 16),
                   "--out", tmp_path / "bag_out") == 0  # fmt: skip
    images, poses = make_flight(tmp_path / "flight")
    (tmp_path / "cam.yaml").write_text(ros_yaml(D))
    rc = predict(
        "--model", model_dir, "--flight", "--images", images, "--poses", poses, "--convention", "flu",
        "--calibration", tmp_path / "cam.yaml", "--size", 16, "--out", tmp_path / "flight_out",
    )  # fmt: skip
    assert rc == 0
    man_b, depth_b, valid_b = outputs(tmp_path / "bag_out")
    man_f, depth_f, valid_f = outputs(tmp_path / "flight_out")
    assert len(depth_b) == len(depth_f) == 6
    for a, b in zip(depth_b, depth_f):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
    for a, b in zip(valid_b, valid_f):
        assert np.array_equal(a, b)
    # the undistorted camera: the calibration's focal length scaled to 16 px, centred (package convention)
    for man in (man_b, man_f):
        assert man["run"]["intrinsics"] == [8.0, 8.0, 8.0, 8.0]
        und = man["dataset"]["undistortion"]
        assert und["calibration"]["model"] == "radtan" and und["calibration"]["coefficients"][:5] == list(D)
        assert und["valid_fraction"] == 1.0 and 0 < und["source_coverage"] < 1
    # the output bag's camera_info: that pinhole in ROS's convention, no distortion
    info = read_bag(tmp_path / "bag_out" / "bag")["/cosemdepth/camera_info"][0][1]
    assert list(info.k) == [8.0, 0.0, 7.5, 0.0, 8.0, 7.5, 0.0, 0.0, 1.0] and not np.any(info.d)


def test_pixels_without_a_source_are_never_valid(model_dir, tmp_path):
    """A pincushion lens: the undistorted image's corners look outside the source image; every depth mask is 0
    there, whatever the policy says about the rest."""
    images, poses = make_flight(tmp_path / "flight")
    (tmp_path / "cam.yaml").write_text(ros_yaml((0.3, 0, 0, 0, 0)))
    rc = predict(
        "--model", model_dir, "--flight", "--images", images, "--poses", poses, "--convention", "flu",
        "--calibration", tmp_path / "cam.yaml", "--size", 32, "--out", tmp_path / "out", "--policy", "every-frame",
    )  # fmt: skip
    assert rc == 0
    man, depth, valid = outputs(tmp_path / "out")
    source = Undistorter(load_calibration(tmp_path / "cam.yaml"), size=(32, 32)).valid.numpy()
    assert 0.5 < source.mean() < 1 and not source[0, 0]
    assert man["dataset"]["undistortion"]["valid_fraction"] == float(source.mean())
    assert all(not (v & ~source).any() for v in valid)  # (the AND itself: tests/inference/test_policy.py)


def test_calibration_and_intrinsics_together_are_refused(model_dir, tmp_path, capsys):
    images, poses = make_flight(tmp_path / "flight")
    (tmp_path / "cam.yaml").write_text(ros_yaml(D))
    rc = predict(
        "--model", model_dir, "--flight", "--images", images, "--poses", poses, "--calibration", tmp_path / "cam.yaml",
        "--hfov", 90, "--out", tmp_path / "out",
    )  # fmt: skip
    assert rc == 2
    assert "exactly one of --intrinsics FX FY CX CY, --hfov DEG and --calibration FILE" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_calibration_of_another_size_is_scaled_and_said(model_dir, tmp_path, capsys):
    images, poses = make_flight(tmp_path / "flight")
    cal = Calibration((64, 64), 32.0, 32.0, 32.0, 32.0, model="radtan", coefficients=D)
    from cosemdepth.camera.writers import ros_yaml as write_ros

    (tmp_path / "cam64.yaml").write_text(write_ros(cal))
    rc = predict(
        "--model", model_dir, "--flight", "--images", images, "--poses", poses, "--calibration",
        tmp_path / "cam64.yaml", "--size", 16, "--out", tmp_path / "out",
    )  # fmt: skip
    assert rc == 0
    err = capsys.readouterr().err
    assert "the calibration is for 64x64 images, the flight's images are 32x32: scaled by 0.5" in err
