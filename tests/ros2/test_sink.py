"""The topics sink's pieces: the point cloud projects back onto its pixels, the outputs follow the model's decoders,
remaps are ROS's NAME:=TOPIC."""

import numpy as np
import pytest

from cosemdepth.errors import ConfigError
from cosemdepth.robotics.messages import header, point_cloud
from cosemdepth.ros2.idl import decode, encode, typestore
from cosemdepth.ros2.sink import output_names, parse_remaps, points_of


def test_points_project_back_onto_their_valid_pixels():
    rng = np.random.default_rng(1)
    h, w = 4, 6
    depth = rng.uniform(1, 50, (h, w)).astype(np.float32)
    valid = rng.random((h, w)) > 0.3
    k = (5.0, 4.0, 3.2, 1.9)  # package convention: the pixel (i, j) has its centre at (j + 0.5, i + 0.5)
    pts = points_of(depth, valid, k)
    assert pts.shape == (valid.sum(), 3) and pts.dtype == np.float32
    ii, jj = np.nonzero(valid)  # row-major order, as the points
    assert np.allclose(pts[:, 2], depth[valid])
    assert np.allclose(k[0] * pts[:, 0] / pts[:, 2] + k[2], jj + 0.5, atol=1e-4)
    assert np.allclose(k[1] * pts[:, 1] / pts[:, 2] + k[3], ii + 0.5, atol=1e-4)
    ts = typestore()
    msg = decode(encode(point_cloud(ts, header(ts, 5, "cam"), pts)), "sensor_msgs/msg/PointCloud2")
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (1, len(pts), 12, 12 * len(pts))
    assert [(f.name, f.offset, f.datatype) for f in msg.fields] == [("x", 0, 7), ("y", 4, 7), ("z", 8, 7)]
    assert np.array_equal(np.frombuffer(bytes(msg.data), "<f4").reshape(-1, 3), pts)


def test_outputs_follow_the_decoders():
    both = ["depth", "depth_valid", "depth_status", "labels", "labels_color", "camera_info"]
    assert output_names(True, True, True, False) == both
    assert output_names(True, True, True, True) == [*both, "points"]
    assert output_names(False, True, False, True) == ["labels", "camera_info"]  # M4Semantic: no depth, no points
    assert output_names(True, False, True, False) == ["depth", "depth_valid", "depth_status", "camera_info"]


def test_remaps():
    assert parse_remaps(["depth:=/camera/depth/image_raw", "points:=cloud"]) == {
        "depth": "/camera/depth/image_raw",
        "points": "/cloud",
    }
    for bad in ("depth=/x", "nope:=/x", "depth:=/9x"):
        with pytest.raises(ConfigError, match="--remap"):
            parse_remaps([bad])
