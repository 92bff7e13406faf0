"""SynthAir through a distorting lens: every distorted pixel's own ray (checked with OpenCV's undistortPoints, an
independent inverse of the lens), the pinhole's depth on the optical axis, the calibration files beside the flight,
and ``--distortion`` errors."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from synthair_helpers import euler_matrix, matrix_to_quaternion
from test_synthair_render import _lake_centre

from cosemdepth.camera import Calibration, load_calibration
from cosemdepth.cli.main import main
from cosemdepth.synthair.climate import get_climate
from cosemdepth.synthair.render import render_frame

SIZE = 48
LENSES = {
    "radtan": (-0.3, 0.1, 0.001, -0.0005, 0.0),
    "equidistant": (0.02, -0.005, 0.001, 0.0),
}


def _lens(model):
    s = SIZE
    return Calibration((s, s), s / 2, s / 2, s / 2, s / 2, model=model, coefficients=LENSES[model])


def _opencv_rays(model) -> np.ndarray:
    """``[S, S, 2]`` undistorted normalised coordinates of the pixel centres, by OpenCV (integer pixel centres)."""
    c = (np.arange(SIZE) + 0.5).astype(np.float64)
    uv = np.stack(np.meshgrid(c, c), -1).reshape(-1, 1, 2) - 0.5
    k = np.array([[SIZE / 2, 0, SIZE / 2 - 0.5], [0, SIZE / 2, SIZE / 2 - 0.5], [0, 0, 1.0]])
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    d = np.array(LENSES[model])
    if model == "radtan":
        xy = cv2.undistortPoints(uv, k, d, criteria=crit)
    else:
        xy = cv2.fisheye.undistortPoints(uv, k, d, criteria=crit)
    return xy.reshape(SIZE, SIZE, 2)


@pytest.mark.parametrize("model", list(LENSES))
def test_each_distorted_pixel_sees_along_its_own_ray_over_flat_water(world, model):
    """z-depth of the plane ``down = h`` seen along camera ray ``(x, y, 1)``: ``h / (R (1, x, y))_down`` with
    ``(x, y)`` OpenCV's undistortion of the pixel centre."""
    x0, y0 = _lake_centre(world)
    h = 12.0
    rot = euler_matrix(np.radians(-123.0), np.radians(-35.0), np.radians(12.0))
    pos = np.array([x0, y0, -(world.water_level + h)])
    frame = render_frame(world, get_climate("cloudy"), matrix_to_quaternion(rot), pos, SIZE, SIZE, lens=_lens(model))
    xy = _opencv_rays(model)
    ned = np.stack([np.ones((SIZE, SIZE)), xy[..., 0], xy[..., 1]], -1) @ rot.T  # camera (x, y, z) = body (y, z, x)
    down = ned[..., 2]
    expected = h / np.where(down > 1e-6, down, np.nan)
    horizontal = expected * np.linalg.norm(ned[..., :2], axis=-1)
    near = np.isfinite(expected) & (horizontal < 50.0)
    assert near.sum() > SIZE * SIZE // 4
    np.testing.assert_allclose(frame.depth[near], expected[near], rtol=3e-4)
    assert (frame.labels[near] == 8).all()


def test_the_lens_shows_the_pinholes_view_on_the_axis_and_a_wider_one_at_the_border(world):
    x0, y0 = _lake_centre(world)
    rot = euler_matrix(np.radians(40.0), np.radians(-20.0), 0.0)
    pos = np.array([x0, y0, -(world.water_level + 15.0)])
    q = matrix_to_quaternion(rot)
    pin = render_frame(world, get_climate("sunny"), q, pos, SIZE, SIZE)
    lens = render_frame(world, get_climate("sunny"), q, pos, SIZE, SIZE, lens=_lens("radtan"))
    # the four pixels around the optical axis look along nearly the same rays as the pinhole's
    c = SIZE // 2
    np.testing.assert_allclose(
        lens.depth[c - 1 : c + 1, c - 1 : c + 1], pin.depth[c - 1 : c + 1, c - 1 : c + 1], rtol=2e-3
    )
    # the barrel lens sees further down at its bottom row: nearer water
    assert lens.depth[-1, c] < pin.depth[-1, c]


def test_synth_distortion_writes_the_calibration_files_beside_the_flight(world, tmp_path):
    out = tmp_path / "ds"
    argv = ["synth", "--out", str(out), "--trajectories", "1", "--frames", "8", "--size", "16", "--climates", "sunny"]
    assert main([*argv, "--distortion", "equidistant:0.02,-0.005,0.001,0", "--no-progress"]) == 0
    meta = json.loads((out / "synthair.json").read_text())
    lens = meta["camera"]["distortion"]
    assert lens["model"] == "equidistant" and lens["coefficients"] == [0.02, -0.005, 0.001, 0.0]
    files = sorted(p.name for p in (out / "calibration").iterdir())
    assert files == ["camera_info.yaml", "colmap_cameras.txt", "kalibr_camchain.yaml", "opencv_calibration.yaml"]
    for name in files:
        cal = load_calibration(out / "calibration" / name)
        assert cal.size == (16, 16) and cal.k == (8.0, 8.0, 8.0, 8.0) and cal.model == "equidistant"
    # OpenCV reads its file: the camera matrix in its convention (pixel centres at integers)
    fs = cv2.FileStorage(str(out / "calibration" / "opencv_calibration.yaml"), cv2.FILE_STORAGE_READ)
    np.testing.assert_array_equal(fs.getNode("camera_matrix").mat(), [[8, 0, 7.5], [0, 8, 7.5], [0, 0, 1]])
    fs.release()
    # the set is refused without its calibration, read with it
    from cosemdepth.data import open_dataset
    from cosemdepth.errors import DatasetError

    with pytest.raises(DatasetError, match="rendered through a equidistant lens; pass its calibration"):
        open_dataset("synthair", out, split="test")
    ds = open_dataset("synthair", out, split="test", size=16, calibration=out / "calibration" / "camera_info.yaml")
    assert ds[0]["source_valid"].shape == (1, 1, 16, 16) and ds.calibration["valid_fraction"] == 1.0


@pytest.mark.parametrize(
    "spec, message",
    [
        ("barrel:0.1", "--distortion 'barrel:0.1': unknown lens model 'barrel'"),
        ("radtan:0.1", "radtan takes 4 to 8 finite coefficients, got 1"),
        ("equidistant:0.1,0,0", "equidistant takes 4 finite coefficients, got 3"),
        ("radtan:a,b,c,d", "the coefficients must be numbers"),
        ("radtan:-0.6,0,0,0", "--distortion: the radtan coefficients [-0.6, 0, 0, 0, 0, 0, 0, 0] fold the image"),
        ("equidistant:-0.05,0,0,0", "degrees off-axis; SynthAir renders rays up to 89 degrees"),
    ],
)
def test_bad_distortion_is_refused_before_anything_is_written(tmp_path, capsys, spec, message):
    out = tmp_path / "ds"
    rc = main(["synth", "--out", str(out), "--size", "16", "--frames", "8", "--distortion", spec, "--no-progress"])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert message in err and err.count("\n") == 0, err
    assert not out.exists()
