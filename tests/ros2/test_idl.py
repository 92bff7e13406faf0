"""The IDL types made from rosbags' definitions lay messages out as ROS 2 does: Cyclone DDS's own serializer (an
independent CDR implementation) writes the same bytes for them as rosbags (the bytes ROS 2 bags hold), and a sample
in XCDR2 is read back as the same message."""

import numpy as np
import pytest

from cosemdepth.errors import DatasetError
from cosemdepth.robotics.messages import camera_info, depth_status, header, image, point_cloud
from cosemdepth.ros2.dds import dds_type
from cosemdepth.ros2.idl import decode, encode, idl_type, typestore
from cosemdepth.ros2.midair_bag import _pose_message

TS = typestore()


def to_idl(msg, msgtype):
    """The IDL instance of a rosbags message (field by field, as the definitions say)."""
    cls = idl_type(msgtype)
    _, fields = TS.fielddefs[msgtype]
    kw = {}
    for name, (kind, arg) in fields:
        v = getattr(msg, name)
        kind = kind.name
        if kind == "NAME":
            kw[name] = to_idl(v, arg)
        elif kind in ("ARRAY", "SEQUENCE") and arg[0][0].name == "NAME":
            kw[name] = [to_idl(x, arg[0][1]) for x in v]
        elif kind in ("ARRAY", "SEQUENCE"):
            kw[name] = [x.item() if hasattr(x, "item") else x for x in np.asarray(v).tolist()]
        else:
            kw[name] = v.item() if hasattr(v, "item") else v
    return cls(**kw)


def messages():
    t = TS.types
    hdr = header(TS, 1_700_000_000_123_456_789, "camera_optical")
    rng = np.random.default_rng(0)
    depth = rng.random((3, 5)).astype("<f4")
    tf = t["geometry_msgs/msg/TransformStamped"](
        header=hdr,
        child_frame_id="base_link",
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=1.0, y=-2.0, z=3.5),
            rotation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.6, w=0.8),
        ),
    )
    p, q = np.array([1.0, 2.0, -3.0]), np.array([0.8, 0.0, 0.6, 0.0])
    return [
        image(TS, hdr, depth, "32FC1"),
        image(TS, hdr, rng.integers(0, 255, (3, 5, 3)).astype(np.uint8), "rgb8"),
        t["sensor_msgs/msg/CompressedImage"](header=hdr, format="jpeg", data=np.arange(7, dtype=np.uint8)),
        camera_info(TS, hdr, (3, 5), (2.5, 2.5, 2.5, 1.5)),
        depth_status(TS, hdr, "held", [("status", "held"), ("baseline_m", "0.1")]),
        point_cloud(TS, hdr, rng.random((4, 3))),
        _pose_message(TS, "geometry_msgs/msg/PoseStamped", 10**9, p, q),
        _pose_message(TS, "nav_msgs/msg/Odometry", 10**9, p, q),
        _pose_message(TS, "px4_msgs/msg/VehicleOdometry", 10**9, p, q),
        t["tf2_msgs/msg/TFMessage"](transforms=[tf, tf]),
    ]


@pytest.mark.parametrize("msg", messages(), ids=lambda m: m.__msgtype__)
def test_cyclone_serializes_the_idl_type_as_rosbags_does(msg):
    mt = msg.__msgtype__
    sample = to_idl(msg, mt)
    assert type(sample).__idl_typename__ == dds_type(mt)
    ours = bytes(encode(msg))
    assert sample.serialize(use_version_2=False) == ours
    back = decode(ours, mt)
    assert bytes(encode(back)) == ours
    # a non-ROS publisher's XCDR2 sample of the same message reads back as the same message
    x2 = sample.serialize(use_version_2=True)
    assert x2[:2] == b"\x00\x07" and bytes(encode(decode(x2, mt))) == ours


def test_px4_definition_and_empty_members():
    names = [n for n, _ in TS.fielddefs["px4_msgs/msg/VehicleOdometry"][1]]
    assert names[:5] == ["timestamp", "timestamp_sample", "pose_frame", "position", "q"]
    assert names[-2:] == ["reset_counter", "quality"] and len(names) == 13
    # rosidl gives a message without fields one placeholder member
    assert list(idl_type("std_msgs/msg/Empty").__annotations__) == ["structure_needs_at_least_one_member"]


def test_undecodable_bytes_are_a_dataset_error():
    with pytest.raises(DatasetError, match="cannot decode a sensor_msgs/msg/Image sample of 8 bytes"):
        decode(b"\x00\x01\x00\x00\xff\xff\xff\x7f", "sensor_msgs/msg/Image")
