"""Pose interpolation, image/pose pairing and message decoding of ROS bags, against hand-computed values."""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "data"))
from _bags import camera_info_msg, compressed_msg, image_msg, typestore, yaw_quat

from cosemdepth.camera import calibration_from_camera_info
from cosemdepth.data.frames import rgb_to_tensor
from cosemdepth.data.poses import interpolate_pose, slerp
from cosemdepth.errors import DatasetError
from cosemdepth.robotics.rosbag import image_to_rgb, pose_at_images

S = 1_000_000_000


def test_slerp_halfway_between_0_and_90_degrees_is_45_degrees():
    q = slerp(yaw_quat(0.0), yaw_quat(math.pi / 2), 0.5)
    c = math.cos(math.pi / 8)
    np.testing.assert_allclose(q, [c, 0, 0, math.sin(math.pi / 8)], atol=1e-12)
    # a quarter of the way: 22.5 degrees; the opposite sign of q1 gives the same (short way) rotation
    q = slerp(yaw_quat(0.0), -yaw_quat(math.pi / 2), 0.25)
    np.testing.assert_allclose(q, [math.cos(math.pi / 16), 0, 0, math.sin(math.pi / 16)], atol=1e-12)


def test_interpolate_pose_by_hand():
    p, q = interpolate_pose(0.25, [0, 0, 0], yaw_quat(0), [4, -8, 2], yaw_quat(math.pi))
    np.testing.assert_allclose(p, [1, -2, 0.5])
    np.testing.assert_allclose(q, [math.cos(math.pi / 8), 0, 0, math.sin(math.pi / 8)], atol=1e-12)


def _poses(stamps):
    return [(t, np.array([float(i), 0.0, 0.0]), yaw_quat(0.1 * i)) for i, t in enumerate(stamps)]


def test_pairing_exact_interpolated_and_skipped():
    poses = _poses([10 * S, 10 * S + S // 100, 10 * S + 2 * S // 100, 11 * S])  # 10.00, 10.01, 10.02, 11.00
    images = [(0, 10 * S + 500, "a"), (1, 10 * S + 5_000_000, "b"), (2, 10 * S + 30_000_000, "c"), (3, 11 * S, "d")]
    out = list(pose_at_images(images, poses, 50_000_000, skip_unposed=True))
    assert [o.index for o in out] == [0, 1, 2, 3]
    np.testing.assert_allclose(out[0].position, [0, 0, 0])  # within 1 us: the pose itself
    np.testing.assert_allclose(out[1].position, [0.5, 0, 0])  # halfway between 10.00 and 10.01
    np.testing.assert_allclose(out[1].quaternion, [math.cos(0.025), 0, 0, math.sin(0.025)], atol=1e-12)
    assert out[2].position is None  # between 10.02 and 11.00: a 0.98 s gap
    np.testing.assert_allclose(out[3].position, [3, 0, 0])
    assert out[3].frame_id == "d" and out[3].stamp == 11 * S


def test_pairing_gap_is_an_error_naming_the_stamp():
    poses = _poses([10 * S, 10 * S + S // 100, 11 * S])
    images = [(0, 10 * S + 5_000_000, "a"), (1, 10 * S + 500_000_000, "a")]
    with pytest.raises(DatasetError, match=r"BAG: topic /cam: no pose for the image at stamp 10\.500000000"):
        list(pose_at_images(images, poses, 50_000_000, where="BAG: topic /cam"))
    with pytest.raises(DatasetError, match=r"stamp 9\.000000000 .*none before"):
        list(pose_at_images([(0, 9 * S, "a")], poses, 50_000_000))
    with pytest.raises(DatasetError, match="holds no pose messages"):
        list(pose_at_images([(0, 9 * S, "a")], [], 50_000_000, pose_where="BAG: topic /odom"))


def test_pairing_needs_increasing_stamps():
    with pytest.raises(DatasetError, match=r"pose stamps must increase \(10\.000000000 follows 10\.010000000\)"):
        list(pose_at_images([(0, 11 * S, "a")], _poses([10 * S, 10 * S + S // 100, 10 * S]), 10**9))
    with pytest.raises(DatasetError, match="image stamps must increase"):
        list(pose_at_images([(0, 10 * S, "a"), (1, 10 * S, "a")], _poses([9 * S, 11 * S]), 10**10))


def test_pairing_holds_two_poses_only():
    held = []

    def poses():
        for i in range(10_000):
            held.append(i)
            yield (i * S // 100, np.zeros(3), yaw_quat(0))

    images = ((k, k * S // 4 + 1_000_000, "c") for k in range(400))  # 4 Hz over 100 s of 100 Hz poses
    n = 0
    for posed in pose_at_images(images, poses(), 50_000_000):
        n += 1
        # the pose stream is read lazily: at most one pose past the image
        assert held[-1] * S // 100 <= posed.stamp + S // 100
    assert n == 400


RGB = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3) * 4


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8"])
def test_raw_image_encodings(encoding):
    msg = image_msg(typestore(False), 0, RGB, encoding)
    got = image_to_rgb(msg.__msgtype__, msg, "x")
    assert got.dtype == np.uint8
    np.testing.assert_array_equal(got, RGB)


RGB16 = np.arange(4 * 5 * 3, dtype=np.uint16).reshape(4, 5, 3) * 1021 + 3  # low bytes vary: not 8-bit * 257


@pytest.mark.parametrize("bigendian", [False, True])
@pytest.mark.parametrize("encoding", ["rgb16", "bgr16", "mono16"])
def test_16bit_encodings_keep_every_bit_and_scale_by_65535(encoding, bigendian):
    msg = image_msg(typestore(False), 0, RGB16, encoding, bigendian=bigendian)
    got = image_to_rgb(msg.__msgtype__, msg, "x")
    want = np.repeat(RGB16[:, :, :1], 3, axis=2) if encoding == "mono16" else RGB16
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, want)
    x = rgb_to_tensor(got, None)
    np.testing.assert_allclose(x.numpy(), want.transpose(2, 0, 1) / 65535.0, rtol=0, atol=1e-7)


def test_mono_padded_rows_and_compressed():
    ts = typestore(False)
    msg = image_msg(ts, 0, RGB, "mono8")
    padded = np.zeros((4, 8), np.uint8)
    padded[:, :5] = RGB[:, :, 0]
    msg = type(msg)(
        header=msg.header, height=4, width=5, encoding="mono8", is_bigendian=0, step=8, data=padded.reshape(-1)
    )
    np.testing.assert_array_equal(image_to_rgb(msg.__msgtype__, msg, "x"), np.repeat(RGB[:, :, :1], 3, axis=2))
    c = compressed_msg(ts, 0, RGB)
    np.testing.assert_array_equal(image_to_rgb(c.__msgtype__, c, "x"), RGB)
    bad = type(msg)(
        header=msg.header, height=4, width=5, encoding="32FC1", is_bigendian=0, step=20, data=np.zeros(80, np.uint8)
    )
    with pytest.raises(DatasetError, match=r"WHERE: image encoding '32FC1' is not supported"):
        image_to_rgb(bad.__msgtype__, bad, "WHERE")


@pytest.mark.parametrize("ros1", [False, True])
def test_camera_info_k_to_package_convention_and_distortion(ros1):
    ts = typestore(ros1)
    info = calibration_from_camera_info(camera_info_msg(ts, 0, 48, 64, (50, 60, 31.5, 23.5), ros1=ros1), "x")
    assert info.size == (48, 64) and info.k == (50, 60, 32, 24)  # ROS pixel centres at integers: + 0.5
    assert info.model == "pinhole" and not info.has_distortion
    msg = camera_info_msg(ts, 0, 48, 64, (50, 60, 31.5, 23.5), d=(0.1, 0, 0, 0, 0), ros1=ros1)
    info = calibration_from_camera_info(msg, "WHERE")
    assert info.model == "radtan" and info.coefficients == (0.1, 0, 0, 0, 0, 0, 0, 0) and info.k == (50, 60, 32, 24)
