"""Lens models and the undistorting remap against OpenCV (an independent implementation of the same models), a
float64 reference, hand-computed points, BL2 (no distortion), and the valid-pixel mask."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from cosemdepth.camera import Calibration, Undistorter
from cosemdepth.camera.distortion import distort, monotonic_limit, undistort_points
from cosemdepth.data.frames import rgb_to_tensor
from cosemdepth.errors import DatasetError

RADTAN = (-0.3, 0.1, 0.001, -0.0005, 0.002)
FISHEYE = (0.02, -0.005, 0.001, 0.0005)


def _cv_k(cal: Calibration) -> np.ndarray:
    """OpenCV's camera matrix of ``cal`` (pixel centres at integers: cx - 0.5)."""
    return np.array([[cal.fx, cal.skew, cal.cx - 0.5], [0, cal.fy, cal.cy - 0.5], [0, 0, 1.0]])


def _points(n=200, scale=1.2, seed=0) -> torch.Tensor:
    return torch.from_numpy(np.random.default_rng(seed).uniform(-scale, scale, (n, 2)))


def test_radtan_matches_opencv_project_and_undistort():
    xy = _points()
    xd = distort("radtan", xy, RADTAN).numpy()
    k = np.eye(3)
    obj = np.concatenate([xy.numpy(), np.ones((len(xy), 1))], 1)
    ref, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), k, np.array(RADTAN))
    np.testing.assert_allclose(xd, ref[:, 0], atol=1e-12)
    back = undistort_points("radtan", torch.from_numpy(xd), RADTAN)
    np.testing.assert_allclose(back.numpy(), xy.numpy(), atol=1e-10)


def test_equidistant_matches_opencv_fisheye():
    xy = _points(scale=2.0)
    xd = distort("equidistant", xy, FISHEYE).numpy()
    obj = np.concatenate([xy.numpy(), np.ones((len(xy), 1))], 1)[:, None]
    ref, _ = cv2.fisheye.projectPoints(obj, np.zeros(3), np.zeros(3), np.eye(3), np.array(FISHEYE))
    np.testing.assert_allclose(xd, ref[:, 0], atol=1e-12)
    back = undistort_points("equidistant", torch.from_numpy(xd), FISHEYE)
    np.testing.assert_allclose(back.numpy(), xy.numpy(), atol=1e-9)


def test_distortion_by_hand():
    # radtan k1 = -0.2 at (0.59, -0.01): r^2 = 0.3482, radial = 1 - 0.2 * 0.3482 = 0.93036
    xd = distort("radtan", torch.tensor([0.59, -0.01], dtype=torch.float64), (-0.2, 0, 0, 0))
    np.testing.assert_allclose(xd.numpy(), [0.59 * 0.93036, -0.01 * 0.93036], rtol=1e-12)
    # a pure equidistant lens (k = 0) maps radius r to theta = atan(r): (1, 0) -> (pi/4, 0)
    xd = distort("equidistant", torch.tensor([1.0, 0.0], dtype=torch.float64), (0, 0, 0, 0))
    np.testing.assert_allclose(xd.numpy(), [math.pi / 4, 0.0], rtol=1e-12)
    # beyond 90 degrees off-axis an equidistant ray has no pinhole coordinates
    assert torch.isnan(undistort_points("equidistant", torch.tensor([[1.7, 0.0]], dtype=torch.float64), (0,) * 4)).all()


def test_monotonic_limit_by_hand():
    # r (1 - 0.3 r^2) peaks at r = 1 / sqrt(0.9) with rho = (2/3) / sqrt(0.9)
    r, rho = monotonic_limit("radtan", (-0.3, 0, 0, 0))
    assert abs(r - 1 / math.sqrt(0.9)) < 2e-3 and abs(rho - (2 / 3) / math.sqrt(0.9)) < 1e-6


def _bilinear_f64(img: np.ndarray, mx: np.ndarray, my: np.ndarray, scale: float) -> np.ndarray:
    """Float64 bilinear sampling at index coordinates (pixel centres at integers), edges replicated."""
    h, w = img.shape[:2]
    a, b = np.clip(mx.astype(np.float64), 0, w - 1), np.clip(my.astype(np.float64), 0, h - 1)
    x0, y0 = np.floor(a).astype(int), np.floor(b).astype(int)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    wx, wy = (a - x0)[..., None], (b - y0)[..., None]
    f = img.astype(np.float64) / scale
    top = f[y0, x0] * (1 - wx) + f[y0, x1] * wx
    bottom = f[y1, x0] * (1 - wx) + f[y1, x1] * wx
    return top * (1 - wy) + bottom * wy


@pytest.mark.parametrize("model,coeffs", [("radtan", RADTAN), ("equidistant", FISHEYE)])
def test_remap_matches_opencv_maps_and_a_float64_reference(model, coeffs):
    """The target camera of a same-size Undistorter is (fx, fy, W/2, H/2); OpenCV's maps to that camera, sampled in
    float64, are the reference (float32 maps: 1e-4 of a level at most)."""
    cal = Calibration((60, 80), 41.0, 42.5, 40.75, 29.5, model=model, coefficients=coeffs)
    und = Undistorter(cal)
    assert und.size == (60, 80) and und.k == (41.0, 42.5, 40.0, 30.0)
    new_k = np.array([[41.0, 0, 39.5], [0, 42.5, 29.5], [0, 0, 1.0]])
    if model == "radtan":
        m1, m2 = cv2.initUndistortRectifyMap(_cv_k(cal), np.array(coeffs), None, new_k, (80, 60), cv2.CV_32FC1)
    else:
        m1, m2 = cv2.fisheye.initUndistortRectifyMap(
            _cv_k(cal), np.array(coeffs), np.eye(3), new_k, (80, 60), cv2.CV_32FC1
        )
    img = np.random.default_rng(1).integers(0, 256, (60, 80, 3), dtype=np.uint8)
    out, valid = und(img)
    ref = _bilinear_f64(img, m1, m2, 255.0)
    np.testing.assert_allclose(out.permute(1, 2, 0).numpy(), ref, atol=2e-4)
    assert valid.all()  # barrel and fisheye at the same focal length: every target pixel has a source


def test_remap_by_hand_on_a_linear_ramp():
    """On an image that is linear in the column, bilinear sampling is exact: the value is the source column."""
    cal = Calibration((80, 100), 80.0, 80.0, 50.0, 40.0, model="radtan", coefficients=(-0.2, 0, 0, 0))
    ramp = np.repeat((np.arange(100, dtype=np.uint16) * 500)[None, :, None], 80, 0).repeat(3, 2)
    out, _ = Undistorter(cal)(ramp)
    # target pixel (39, 79): centre (79.5, 39.5) -> (x, y) = (29.5 / 80, -0.5 / 80) = (0.36875, -0.00625)
    # -> r^2 = 0.136015625, x_d = x (1 - 0.2 r^2) = 0.3587188 -> u = 80 x_d + 50 = 78.697508; index u - 0.5
    assert abs(float(out[0, 39, 79]) - 78.197508 * 500 / 65535) < 1e-6


@pytest.mark.parametrize("size", [(24, 32), (17, 45), (48, 64)])
def test_without_distortion_the_remap_is_bl2(size):
    cal = Calibration((48, 64), 40.0, 40.0, 32.0, 24.0)
    img = np.random.default_rng(2).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    out, valid = Undistorter(cal, size=size)(img)
    # (PyTorch's bilinear resize computes its source coordinates in float32, the remap in float64)
    torch.testing.assert_close(out, rgb_to_tensor(img, size), atol=5e-6, rtol=0)
    assert valid.all()


def test_focal_px_sets_the_size_as_for_pinhole_inputs():
    cal = Calibration((480, 640), 320.0, 320.0, 320.0, 240.0, model="radtan", coefficients=RADTAN)
    und = Undistorter(cal, focal_px=64.0)
    assert und.size == (96, 128) and und.k == (64.0, 64.0, 64.0, 48.0)
    assert und.intrinsics.tolist() == [64.0, 64.0, 64.0, 48.0]


def test_the_mask_marks_target_pixels_without_a_source():
    # pincushion: the target corners look outside the source image
    cal = Calibration((60, 80), 40.0, 40.0, 40.0, 30.0, model="radtan", coefficients=(0.3, 0, 0, 0))
    und = Undistorter(cal)
    v = und.valid
    assert not v[0, 0] and not v[-1, -1] and v[30, 40]
    # by hand: target pixel (29, 0) centre (0.5, 29.5) -> x = -0.9875, y = -0.0125, radial 1 + 0.3 r^2 = 1.2926
    # -> u = 40 x radial + 40 = -11.06 < 0: outside; pixel (0, 40): (0.0125, -0.7375) -> v = -4.31: outside;
    # pixel (10, 40): (0.0125, -0.4875) -> radial 1.0713, v = 30 - 19.5 * 1.0713 = 9.11: inside
    assert not v[29, 0] and not v[0, 40] and v[10, 40]
    ramp = np.zeros((60, 80, 3), np.uint8)
    ramp[:, 0] = 200  # the left source column
    edge, _ = und(ramp)
    black, _ = Undistorter(cal, fill="black")(ramp)
    assert float(edge[0, 29, 0]) == pytest.approx(200 / 255)  # edge fill: the nearest border pixel
    assert float(black[0, 29, 0]) == 0.0 and torch.equal(black * v, black)
    # the remapped ground truth has no depth (0) where there is no source
    depth = Undistorter(cal).remap_depth(torch.full((1, 60, 80), 7.0))
    assert torch.equal(depth[0] > 0, v) and float(depth.max()) == 7.0


def test_full_canvas_keeps_every_source_pixel():
    cal = Calibration((60, 80), 40.0, 40.0, 40.0, 30.0, model="radtan", coefficients=(-0.3, 0.1, 0, 0))
    same, full = Undistorter(cal), Undistorter(cal, canvas="full")
    assert same.valid.all() and same.source_coverage < 0.9
    assert full.size[0] > 60 and full.size[1] > 80 and full.source_coverage == 1.0 and 0.5 < full.valid_fraction < 1


def test_wrong_image_size_and_bad_options():
    und = Undistorter(Calibration((60, 80), 40.0, 40.0, 40.0, 30.0, model="radtan", coefficients=RADTAN))
    with pytest.raises(DatasetError, match=r"the image is 40x30 \(WxH\) but the calibration"):
        und(np.zeros((30, 40, 3), np.uint8))
    with pytest.raises(Exception, match="fill must be one of"):
        Undistorter(und.calibration, fill="mirror")
