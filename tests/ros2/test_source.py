"""The live source on loopback, fed by a publisher in the test: the pose topic's type is discovered (PoseStamped,
Odometry, PX4's VehicleOdometry, /tf), the newest frame goes first and the older ones are counted as dropped, the
motion is that since the previous processed frame, and a frame without a pose, a gap, a clock jump back or a new
camera publisher start the state afresh with the reason in the frame's meta."""

import math
import threading
import time

import numpy as np
import pytest
import torch

from cosemdepth.robotics.messages import header, image
from cosemdepth.ros2.dds import Graph
from cosemdepth.ros2.idl import encode, idl_type, typestore
from cosemdepth.ros2.midair_bag import _pose_message
from cosemdepth.ros2.source import LiveOptions, LiveSource

TS = typestore()
T0 = 1_700_000_000 * 10**9
MS = 1_000_000
IMG = "sensor_msgs/msg/Image"


class Camera:
    """A camera and a pose publisher (their own participant)."""

    def __init__(self, pose_type: str, pose_topic: str = "/pose") -> None:
        self.graph = Graph()
        self.pose_type = pose_type
        self.images = self.graph.writer("/cam/image", idl_type(IMG), "reliable")
        self.poses = self.graph.writer(pose_topic, idl_type(pose_type), "reliable")
        rng = np.random.default_rng(0)
        self.rgb = rng.integers(0, 255, (8, 12, 3)).astype(np.uint8)

    def image(self, t_ns: int, writer=None) -> None:
        (writer or self.images).write(encode(image(TS, header(TS, t_ns, "cam"), self.rgb, "rgb8")))

    def pose(self, t_ns: int, x: float) -> None:
        """The body at (x, 0, 0), axes of the world."""
        p, q = np.array([x, 0.0, 0.0]), np.array([1.0, 0.0, 0.0, 0.0])
        if self.pose_type == "tf2_msgs/msg/TFMessage":
            t = TS.types
            tr = t["geometry_msgs/msg/TransformStamped"](
                header=header(TS, t_ns, "odom"),
                child_frame_id="base_link",
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=0.0),
                    rotation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                ),
            )
            msg = t["tf2_msgs/msg/TFMessage"](transforms=[tr])
        else:
            msg = _pose_message(TS, self.pose_type, t_ns, p, q)
        self.poses.write(encode(msg))

    def close(self) -> None:
        self.graph.close()


def until(cond, seconds=20.0):
    end = time.monotonic() + seconds
    while not cond():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.01)


def open_source(camera: Camera, pose_topic="/pose", **kw):
    graph = Graph()
    source = LiveSource(graph, LiveOptions("/cam/image", pose_topic, hfov=90.0, **kw), None, log=lambda m: None)
    assert source.start()
    until(lambda: camera.images.subscribers() > 0 and camera.poses.subscribers() > 0)
    guard = threading.Timer(60, source.stop)  # a test that waits for a frame that never comes ends, and fails
    guard.start()
    return source, source.batches(), guard


@pytest.mark.parametrize(
    "pose_type, pose_topic, kw",
    [
        ("geometry_msgs/msg/PoseStamped", "/pose", {}),
        ("nav_msgs/msg/Odometry", "/mavros/local_position/odom", {}),
        ("px4_msgs/msg/VehicleOdometry", "/fmu/out/vehicle_odometry", {}),
        ("tf2_msgs/msg/TFMessage", "/tf", {"world_frame": "odom", "body_frame": "base_link"}),
        ("tf2_msgs/msg/TFMessage", "/tf", {}),  # the frames chosen from the transforms: base_link in odom
    ],
)
def test_pose_type_is_discovered_and_the_motion_is_since_the_last_frame(pose_type, pose_topic, kw):
    cam = Camera(pose_type, pose_topic)
    source, frames, guard = open_source(cam, pose_topic, convention="flu", **kw)
    try:
        assert source.pose_type == pose_type and source.image_type == IMG
        for k in range(31):  # 1 m/s along the body's x axis (forward)
            cam.pose(T0 + 10 * k * MS, 0.01 * k)
        cam.image(T0 + 100 * MS)
        first = next(frames)
        cam.image(T0 + 250 * MS)
        second = next(frames)
    finally:
        guard.cancel()
        source.close()
        cam.close()
    assert bool(first.reset[0]) and first.meta[0]["reset_reason"] == "first frame"
    assert not bool(second.reset[0]) and "reset_reason" not in second.meta[0]
    # 0.15 m forward between the frames: the camera (forward-looking on a FLU body) moved 0.15 m along its z axis
    assert torch.allclose(second.trans[0], torch.tensor([0.0, 0.0, 0.15]), atol=1e-5)
    assert torch.allclose(second.rot[0], torch.tensor([1.0, 0.0, 0.0, 0.0]))
    assert second.pose[0, 2, 3].item() == pytest.approx(0.0) and second.pose[0, 0, 3].item() == pytest.approx(0.25)
    f = 6.0 / math.tan(math.radians(45))  # --hfov 90 on 12 px
    assert torch.allclose(second.intrinsics[0], torch.tensor([f, f, 6.0, 4.0]))
    assert tuple(second.rgb.shape) == (1, 3, 8, 12) and second.meta[0]["stamp_ns"] == T0 + 250 * MS


def test_newest_first_drops_timeouts_gaps_jumps_and_restarts():
    cam = Camera("geometry_msgs/msg/PoseStamped")
    source, frames, guard = open_source(cam, pose_timeout=0.3, max_frame_gap=1.0)
    try:
        for k in range(101):
            cam.pose(T0 + 10 * k * MS, 0.01 * k)
        for k in range(1, 6):  # five frames before the node asks for one: it takes the newest, drops four
            cam.image(T0 + 100 * k * MS)
        until(lambda: source.stats.received == 5)
        f = next(frames)
        assert f.meta[0]["stamp_ns"] == T0 + 500 * MS and f.meta[0]["dropped_before"] == 4
        assert source.stats.dropped == 4 and bool(f.reset[0])

        cam.image(T0 + 600 * MS)
        f = next(frames)
        assert not bool(f.reset[0]) and torch.allclose(f.trans[0], torch.tensor([0.0, 0.0, 0.1]), atol=1e-5)

        # no pose comes for an image: after --pose-timeout it goes on without depth
        cam.image(T0 + 1400 * MS)
        f = next(frames)
        assert bool(f.reset[0]) and not bool(f.depth_ok[0])
        assert f.meta[0]["depth_invalid_reason"].startswith("no pose within 0.3 s of its arrival")

        # poses again: the next frame starts afresh after the one without a pose
        for k in range(140, 181):
            cam.pose(T0 + 10 * k * MS, 0.01 * k)
        cam.image(T0 + 1500 * MS)
        f = next(frames)
        assert bool(f.reset[0]) and bool(f.depth_ok[0]) and f.meta[0]["reset_reason"] == "after a frame without a pose"
        cam.image(T0 + 1600 * MS)
        assert not bool(next(frames).reset[0])

        # a gap longer than --max-frame-gap
        for k in range(181, 301):
            cam.pose(T0 + 10 * k * MS, 0.01 * k)
        cam.image(T0 + 2900 * MS)
        f = next(frames)
        assert bool(f.reset[0]) and f.meta[0]["reset_reason"].startswith("gap: 1.300 s since the previous frame")

        # the clock jumps back (both streams, as a simulator reset does)
        cam.image(T0 + 300 * MS)
        for k in range(25, 40):
            cam.pose(T0 + 10 * k * MS, 0.01 * k)
        f = next(frames)
        assert bool(f.reset[0]) and bool(f.depth_ok[0]) and f.meta[0]["reset_reason"].startswith("clock jump back")
        assert f.pose[0, 2, 3].item() == pytest.approx(0.0) and f.pose[0, 0, 3].item() == pytest.approx(0.3)

        # the camera restarts: a new publisher
        other = cam.graph.writer("/cam/image", idl_type(IMG), "reliable")
        until(lambda: other.subscribers() > 0)
        cam.image(T0 + 350 * MS, writer=other)
        f = next(frames)
        assert f.meta[0]["reset_reason"].startswith("image publisher changed")
    finally:
        guard.cancel()
        source.close()
        cam.close()
    s = source.stats
    assert (s.received, s.processed, s.dropped, s.unposed, s.rejected) == (12, 8, 4, 1, 0)
    assert s.resets == {
        "first frame": 1,
        "after a frame without a pose": 1,
        "gap": 1,
        "clock jump back": 1,
        "image publisher changed": 1,
    }


def lands_on_the_sensor(rgb_shape, k, model, d):
    """Hand-computed: whether the ray of target pixel (0, 0) lands on the source image (pixel centre (0.5, 0.5),
    package convention, the target camera equal to the source's pinhole part)."""
    fx, fy, cx, cy = k
    x, y = (0.5 - cx) / fx, (0.5 - cy) / fy
    r = math.hypot(x, y)
    if model == "plumb_bob":  # radial k1 only
        scale = 1 + d[0] * r * r
    else:  # equidistant: theta_d = theta (1 + k1 theta^2)
        theta = math.atan(r)
        scale = theta * (1 + d[0] * theta**2) / r
    u, v = fx * x * scale + cx, fy * y * scale + cy
    h, w = rgb_shape[:2]
    return 0 <= u <= w and 0 <= v <= h


@pytest.mark.parametrize("model, d", [("plumb_bob", (0.5, 0.0, 0.0, 0.0, 0.0)), ("equidistant", (2.0, 0.0, 0.0, 0.0))])
def test_camera_info_lens_is_undistorted_as_predict_bag_does_and_an_unusable_one_leaves_frames_out(model, d):
    from cosemdepth.camera import Undistorter, calibration_from_camera_info
    from cosemdepth.robotics.messages import camera_info

    cam = Camera("geometry_msgs/msg/PoseStamped")
    info = cam.graph.writer("/cam/info", idl_type("sensor_msgs/msg/CameraInfo"), "reliable")
    graph = Graph()
    notes = []
    source = LiveSource(
        graph, LiveOptions("/cam/image", "/pose", camera_info_topic="/cam/info"), None, log=notes.append
    )
    guard = threading.Timer(60, source.stop)
    k = (10.0, 10.0, 6.0, 4.0)  # package convention: the principal point at the image centre
    try:
        assert source.start()
        until(lambda: info.subscribers() > 0 and cam.images.subscribers() > 0 and cam.poses.subscribers() > 0)
        guard.start()
        frames = source.batches()
        for i in range(31):
            cam.pose(T0 + 10 * i * MS, 0.01 * i)
        binned = camera_info(TS, header(TS, T0, "cam"), (8, 12), k)
        binned.binning_x = 2
        info.write(encode(binned))
        until(lambda: source.info_error is not None)
        got = []
        consumer = threading.Thread(target=lambda: got.append(next(frames)))  # the node asking for its next frame
        consumer.start()
        cam.image(T0 + 100 * MS)
        until(lambda: source.stats.rejected == 1)
        lens = camera_info(TS, header(TS, T0, "cam"), (8, 12), k)
        lens.distortion_model, lens.d = model, np.array(d)
        info.write(encode(lens))
        until(lambda: source.info is not None)
        cam.image(T0 + 200 * MS)
        consumer.join(30)
        f = got[0]
    finally:
        guard.cancel()
        source.close()
        cam.close()
    assert any("binning" in n for n in notes) and any(n.startswith("frame left out: /cam/info at stamp") for n in notes)
    assert f.meta[0]["reset_reason"] == "first frame"  # the frame left out was never processed
    # predict --bag's undistortion of the same camera_info, bit for bit
    u = Undistorter(calibration_from_camera_info(lens, "x"))
    rgb, valid = u(cam.rgb)
    assert torch.equal(f.rgb[0], rgb) and torch.equal(f.source_valid[0, 0], valid)
    assert torch.allclose(f.intrinsics[0], torch.tensor(k)) and f.meta[0]["intrinsics"] == list(k)
    # the lens pushes the corners' rays off the sensor: no source there; the centre has one
    assert not lands_on_the_sensor(cam.rgb.shape, k, model, d)
    assert not valid[0, 0] and not valid[-1, -1] and valid[3:5, 5:7].all()
