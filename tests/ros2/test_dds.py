"""ROS 2's names and settings on DDS (cosemdepth.ros2.dds): topic and type names, the domain, the loopback
configuration, QoS profiles, and raw samples crossing a participant unchanged."""

import time

import numpy as np
import pytest
from _live import LOOPBACK

from cosemdepth.errors import ConfigError
from cosemdepth.ros2.dds import Graph, dds_topic, dds_type, domain_id, loopback_config, qos, ros_topic, ros_type
from cosemdepth.ros2.idl import encode, idl_type, typestore


def test_ros_names_map_to_rmw_cyclonedds_names_and_back():
    assert dds_topic("/cosemdepth/depth") == "rt/cosemdepth/depth"
    assert dds_type("sensor_msgs/msg/Image") == "sensor_msgs::msg::dds_::Image_"
    assert dds_type("px4_msgs/msg/VehicleOdometry") == "px4_msgs::msg::dds_::VehicleOdometry_"
    for t in ("sensor_msgs/msg/Image", "tf2_msgs/msg/TFMessage", "diagnostic_msgs/msg/DiagnosticArray"):
        assert ros_type(dds_type(t)) == t
    assert ros_type("Image") is None and ros_type("sensor_msgs::msg::Image") is None


def test_topic_names_are_made_absolute_and_checked():
    assert ros_topic("camera/image_raw") == "/camera/image_raw"
    assert ros_topic("/fmu/out/vehicle_odometry") == "/fmu/out/vehicle_odometry"
    for bad in ("/9cam", "/cam era", "", "/a//b"):
        with pytest.raises(ConfigError, match="not a valid ROS topic name"):
            ros_topic(bad, "--image-topic")


def test_domain_from_ros_domain_id():
    assert domain_id({}) == 0 and domain_id({"ROS_DOMAIN_ID": ""}) == 0
    assert domain_id({"ROS_DOMAIN_ID": " 42 "}) == 42
    for bad in ("x", "-1", "233", "1.5"):
        with pytest.raises(ConfigError, match="ROS_DOMAIN_ID"):
            domain_id({"ROS_DOMAIN_ID": bad})


def test_loopback_config_is_the_loopback_only_one():
    text = loopback_config(32)
    assert text == LOOPBACK
    assert '<NetworkInterface name="lo"/>' in text and "<AllowMulticast>false</AllowMulticast>" in text
    assert '<Peer address="127.0.0.1"/>' in text


def test_qos_profiles_are_ros2s():
    from cyclonedds.core import Policy
    from cyclonedds.util import duration

    sensor = qos("sensor", writer=True)
    assert Policy.Reliability.BestEffort in sensor and Policy.Durability.Volatile in sensor
    assert Policy.History.KeepLast(5) in sensor
    assert Policy.DataRepresentation(use_cdrv0_representation=True) in sensor  # writers: XCDR1 only
    reliable = qos("reliable")
    assert Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)) in reliable
    assert Policy.History.KeepLast(10) in reliable
    assert Policy.DataRepresentation(use_cdrv0_representation=True, use_xcdrv2_representation=True) in reliable
    static = qos("static", depth=100)
    assert Policy.Durability.TransientLocal in static and Policy.History.KeepLast(100) in static
    with pytest.raises(ConfigError, match="QoS profile"):
        qos("best")


def _take_all(reader, n, seconds=10.0):
    got, end = [], time.monotonic() + seconds
    while len(got) < n and time.monotonic() < end:
        got.extend(reader.take())
        time.sleep(0.02)
    return got


def test_raw_samples_cross_unchanged_and_the_type_is_discovered(loopback_dds):
    ts = typestore()
    t = ts.types
    msg = t["sensor_msgs/msg/Image"](
        header=t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=3, nanosec=9), frame_id="cam"),
        height=2,
        width=3,
        encoding="mono8",
        is_bigendian=0,
        step=3,
        data=np.arange(6, dtype=np.uint8),
    )
    raw = bytes(encode(msg))
    pad = -len(raw) % 4
    assert raw[:4] == b"\x00\x01\x00\x00" and pad == 2  # rosbags' CDR (XCDR1 little-endian), not 4-aligned
    with Graph() as a, Graph() as b:
        assert a.domain == loopback_dds
        reader = b.reader("/test/raw", idl_type("sensor_msgs/msg/Image"), "reliable")
        writer = a.writer("/test/raw", idl_type("sensor_msgs/msg/Image"), "reliable")
        assert b.discover_type("/test/raw", ("sensor_msgs/msg/Image",), 10.0, "--x") == "sensor_msgs/msg/Image"
        end = time.monotonic() + 10
        while writer.subscribers() == 0 and time.monotonic() < end:
            time.sleep(0.02)
        writer.write(encode(msg))
        writer.write(raw)
        got = _take_all(reader, 2)
        assert len(got) == 2
        for s in got:
            # the message's bytes unchanged, padded with zeros to a multiple of 4 bytes
            assert s.data[: len(raw)] == raw and s.data[len(raw) :] == b"\x00" * pad
            assert s.writer == got[0].writer and s.received_ns >= s.source_ns - 10**9
        with pytest.raises(ConfigError, match="publishes sensor_msgs/msg/Image on it"):
            b.discover_type("/test/raw", ("geometry_msgs/msg/PoseStamped",), 1.0, "--pose-topic")
        assert b.discover_type("/nobody/here", ("sensor_msgs/msg/Image",), 0.2, "--x") is None
