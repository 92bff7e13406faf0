"""Live poses (cosemdepth.ros2.poses): the pose of an image is predict --bag's (pose_at_images over the whole stream),
decided as soon as a pose at or after its stamp arrived; stamps going back clear a track; /tf chains compose; PX4's
odometry is read with its NaNs and clock."""

import math

import numpy as np
import pytest

from cosemdepth.data.quaternion import qmul, qrotate
from cosemdepth.errors import ConfigError
from cosemdepth.robotics.rosbag import pose_at_images
from cosemdepth.ros2.idl import typestore
from cosemdepth.ros2.midair_bag import _pose_message
from cosemdepth.ros2.poses import PX4_ODOMETRY, PoseInput, PoseTrack, TfTree, default_convention, px4_pose

TS = typestore()
MS = 1_000_000


def yaw(a):
    return np.array([math.cos(a / 2), 0.0, 0.0, math.sin(a / 2)])


def test_track_pairs_images_as_pose_at_images_on_the_whole_stream():
    rng = np.random.default_rng(0)
    stamps = np.cumsum(rng.integers(5, 15, 60)) * MS  # 5-15 ms apart
    stamps[30:] += 80 * MS  # a gap wider than max_gap
    poses = [(int(s), rng.normal(size=3), yaw(rng.normal())) for s in stamps]
    images = [(i, int(t), "c") for i, t in enumerate(range(int(stamps[0]) - 5 * MS, int(stamps[-1]), 7 * MS + 13))]
    expected = list(pose_at_images(images, poses, 50 * MS, skip_unposed=True))
    track = PoseTrack()
    got = []
    k = 0
    for _, t, _ in images:
        while not track.ready(t) and k < len(poses):
            track.add(*poses[k])
            k += 1
        got.append(track.at(t, 50 * MS) if track.ready(t) else None)
    assert sum(g is None for g in got) > 0 and sum(g is not None for g in got) > 10
    for e, g in zip(expected, got):
        if e.position is None:
            assert g is None
        else:
            assert np.array_equal(g[0], e.position) and np.array_equal(g[1], e.quaternion)


def test_track_readiness_repeats_backward_stamps_and_bound():
    track = PoseTrack(max_poses=4)
    p, q = np.zeros(3), yaw(0)
    assert not track.ready(0) and track.at(0, MS) is None
    track.add(100 * MS, p, q)
    assert track.ready(100 * MS + 999) and not track.ready(100 * MS + 1001)  # within 1 us counts as at its stamp
    assert track.add(100 * MS, p + 1, q) is None and len(track) == 1  # a repeated stamp is ignored
    note = track.add(50 * MS, p, q)
    assert "went back" in note and track.stamps == [50 * MS]
    for k in range(1, 10):
        track.add((50 + k) * MS, p, q)
    assert track.stamps == [(50 + k) * MS for k in range(6, 10)]


def tr(parent, child, stamp, p=(0.0, 0.0, 0.0), q=(1.0, 0.0, 0.0, 0.0)):
    t = TS.types
    return t["geometry_msgs/msg/TransformStamped"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=parent
        ),
        child_frame_id=child,
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=p[0], y=p[1], z=p[2]),
            rotation=t["geometry_msgs/msg/Quaternion"](w=q[0], x=q[1], y=q[2], z=q[3]),
        ),
    )


def test_tf_chain_composes_static_and_interpolated_dynamic_transforms():
    tf = TS.types["tf2_msgs/msg/TFMessage"]
    tree = TfTree("/odom", "camera")
    tree.add(tf(transforms=[tr("base_link", "camera", 0, (0.5, 0.0, 0.2), yaw(math.pi / 2))]), static=True)
    assert not tree.ready(10**9) and tree.at(10**9, MS) is None  # odom -> base_link not seen yet
    tree.add(tf(transforms=[tr("odom", "base_link", 10**9, (1.0, 0.0, 0.0), yaw(0.0))]))
    tree.add(tf(transforms=[tr("odom", "base_link", 10**9 + 20 * MS, (3.0, 0.0, 0.0), yaw(0.0))]))
    assert tree.ready(10**9 + 10 * MS)
    p, q = tree.at(10**9 + 10 * MS, 50 * MS)
    # base_link halfway: (2, 0, 0), no rotation; camera 0.5 forward and 0.2 up of it, turned 90 degrees left
    assert np.allclose(p, [2.5, 0.0, 0.2]) and np.allclose(q, yaw(math.pi / 2))
    # a point 1 m ahead of the camera (its x axis) is 1 m to the left of base_link's x axis in odom
    assert np.allclose(p + qrotate(q, np.array([1.0, 0, 0])), [2.5, 1.0, 0.2])
    assert np.allclose(qmul(yaw(0.0), yaw(math.pi / 2)), q)


def test_px4_odometry_nan_clock_offset_and_convention():
    p, q = np.array([1.0, 2.0, -3.0]), yaw(0.3)
    msg = _pose_message(TS, PX4_ODOMETRY, 5 * 10**9, p, q)  # stamp 5 s: microseconds since boot
    stamp, pp, qq = px4_pose(msg)
    assert stamp == 5 * 10**9 and np.allclose(pp, p, atol=1e-6) and np.allclose(qq, q, atol=1e-6)
    bad = _pose_message(TS, PX4_ODOMETRY, 10**9, p, q)
    bad.q[0] = np.nan
    assert px4_pose(bad) is None
    assert default_convention(PX4_ODOMETRY) == "ned" and default_convention("nav_msgs/msg/Odometry") == "flu"
    live = PoseInput(PX4_ODOMETRY)
    image_clock = 1_700_000_000 * 10**9
    written = image_clock + 7 * MS  # the bridge wrote it 7 ms after its PX4 stamp, on the companion's clock
    live.add(msg, written - 5 * 10**9 + 5 * 10**9, image_stamp=image_clock)
    assert live.px4_offset == written - 5 * 10**9 and live.latest == written
    live.add(_pose_message(TS, PX4_ODOMETRY, 5 * 10**9 + 4 * MS, p, q), 0, image_stamp=image_clock)
    assert live.latest == written + 4 * MS  # the first offset is kept
    # images stamped with a clock of their own (a replayed bag, a simulator): written 3 years after their stamps
    replayed = PoseInput(PX4_ODOMETRY)
    years = 3 * 365 * 86400 * 10**9
    replayed.add(msg, written + years, image_stamp=image_clock, image_source_ns=image_clock + 2 * MS + years)
    assert replayed.latest == written - 2 * MS  # on the images' clock: the two writers' delays' difference stays in
    with pytest.raises(ConfigError, match="not a pose type"):
        PoseInput("sensor_msgs/msg/Image")


def test_tf_frames_are_chosen_from_the_transforms_when_not_given():
    tf = TS.types["tf2_msgs/msg/TFMessage"]
    # REP 105: map -> odom -> base_link, a camera fixed on base_link: base_link in map
    tree = TfTree(None, None)
    assert tree.frames() == "no dynamic transform on /tf yet"
    tree.add(tf(transforms=[tr("base_link", "camera", 0, (0.5, 0, 0))]), static=True)
    notes = tree.add(tf(transforms=[tr("odom", "base_link", 10**9, (1.0, 0, 0)), tr("map", "odom", 10**9)]))
    assert tree.frames() == ("map", "base_link") and notes == ["/tf: the pose of base_link in map (--body-frame, "
                                                               "--world-frame to choose)"]  # fmt: skip
    assert tree.add(tf(transforms=[tr("odom", "base_link", 2 * 10**9), tr("map", "odom", 2 * 10**9)])) == []
    assert [e[0] for e in tree.chain()] == ["base_link", "odom"]
    # one moving frame of another name: that one, in the root above it
    other = TfTree(None, None)
    other.add(tf(transforms=[tr("world", "drone", 10**9, (0.0, 2.0, 0))]))
    assert other.frames() == ("world", "drone") and np.allclose(other.at(10**9, MS)[0], [0, 2, 0])
    # several moving frames and no base_link: they must be given; a given body gets its root
    two = TfTree(None, None)
    two.add(tf(transforms=[tr("world", "a", 10**9), tr("world", "b", 10**9)]))
    assert "give --body-frame" in two.frames() and two.chain() is None
    live = PoseInput("tf2_msgs/msg/TFMessage")
    live.add(tf(transforms=[tr("world", "a", 10**9), tr("world", "b", 10**9)]), 0)
    assert "moves several frames (a, b)" in live.unresolved() and not live.ready(10**9)
    given = TfTree(None, "b")
    given.add(tf(transforms=[tr("world", "a", 10**9), tr("world", "b", 10**9, (3.0, 0, 0))]))
    assert given.frames() == ("world", "b") and np.allclose(given.at(10**9, MS)[0], [3, 0, 0])
