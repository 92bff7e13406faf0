"""Test helper: write small ROS bags with rosbags (ROS 2 MCAP / sqlite3, ROS 1) and the matching --flight inputs."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np


def typestore(ros1: bool):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)


def _header(ts, ns: int, frame_id: str, ros1: bool):
    t = ts.types
    stamp = t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
    if ros1:
        return t["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame_id)
    return t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)


def image_msg(
    ts,
    ns: int,
    rgb: np.ndarray,
    encoding: str = "rgb8",
    ros1: bool = False,
    frame_id: str = "cam",
    bigendian: bool = False,
):
    """``rgb``: uint8 (scaled by 257 for the 16-bit encodings) or uint16 (16-bit encodings, stored as is)."""
    h, w = rgb.shape[:2]
    if encoding.endswith("16"):
        rgb = rgb.astype(np.uint16) * (257 if rgb.dtype == np.uint8 else 1)
    if encoding in ("rgb8", "rgb16"):
        px = rgb
    elif encoding in ("bgr8", "bgr16"):
        px = rgb[:, :, ::-1]
    elif encoding in ("mono8", "mono16"):
        px = rgb[:, :, 0]
    else:
        raise ValueError(encoding)
    if encoding.endswith("16"):
        px = px.astype(">u2" if bigendian else "<u2")
    data = np.ascontiguousarray(px).view(np.uint8).reshape(-1)
    return ts.types["sensor_msgs/msg/Image"](
        header=_header(ts, ns, frame_id, ros1),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=int(bigendian),
        step=data.size // h,
        data=data,
    )


def png_bytes(rgb: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="PNG")
    return buf.getvalue()


def compressed_msg(ts, ns: int, rgb: np.ndarray, ros1: bool = False, frame_id: str = "cam"):
    data = np.frombuffer(png_bytes(rgb), dtype=np.uint8)
    return ts.types["sensor_msgs/msg/CompressedImage"](header=_header(ts, ns, frame_id, ros1), format="png", data=data)


def pose_msg(ts, msgtype: str, ns: int, p, q, ros1: bool = False, frame_id: str = "map"):
    """``q`` is (w, x, y, z)."""
    t = ts.types
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
        orientation=t["geometry_msgs/msg/Quaternion"](x=q[1], y=q[2], z=q[3], w=q[0]),
    )
    hdr = _header(ts, ns, frame_id, ros1)
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return t[msgtype](header=hdr, pose=pose)
    cov = t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36))
    if msgtype == "geometry_msgs/msg/PoseWithCovarianceStamped":
        return t[msgtype](header=hdr, pose=cov)
    z = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    twist = t["geometry_msgs/msg/TwistWithCovariance"](
        twist=t["geometry_msgs/msg/Twist"](linear=z, angular=z), covariance=np.zeros(36)
    )
    return t["nav_msgs/msg/Odometry"](header=hdr, child_frame_id="base_link", pose=cov, twist=twist)


def camera_info_msg(ts, ns: int, h: int, w: int, k, d=(), ros1: bool = False):
    t = ts.types
    fx, fy, cx, cy = k
    kk = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], dtype=np.float64)
    pp = np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0], dtype=np.float64)
    roi = t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    common = dict(
        header=_header(ts, ns, "cam", ros1),
        height=h,
        width=w,
        distortion_model="plumb_bob" if len(d) else "",
        binning_x=0,
        binning_y=0,
        roi=roi,
    )
    if ros1:
        return t["sensor_msgs/msg/CameraInfo"](
            **common, D=np.asarray(d, dtype=np.float64), K=kk, R=np.eye(3).reshape(-1), P=pp
        )
    return t["sensor_msgs/msg/CameraInfo"](
        **common, d=np.asarray(d, dtype=np.float64), k=kk, r=np.eye(3).reshape(-1), p=pp
    )


def write_bag(path: Path, messages: list[tuple[str, object, int]], kind: str = "mcap") -> Path:
    """Write ``(topic, message, log_time_ns)`` (sorted by log time) to a bag of ``kind`` ``mcap``, ``sqlite3`` or
    ``ros1`` (``path`` gets a ``.bag`` suffix for ROS 1)."""
    ros1 = kind == "ros1"
    ts = typestore(ros1)
    messages = sorted(messages, key=lambda m: m[2])
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3)
    conns = {}
    with writer:
        for topic, msg, t in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=ts)
            raw = ts.serialize_ros1(msg, msg.__msgtype__) if ros1 else ts.serialize_cdr(msg, msg.__msgtype__)
            writer.write(conns[topic], t, raw)
    return path


def yaw_quat(yaw: float) -> np.ndarray:
    """(w, x, y, z) of a rotation by ``yaw`` about z."""
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


def trajectory(t: float) -> tuple[np.ndarray, np.ndarray]:
    """A smooth test flight (ENU world, FLU body): forward along a gentle curve, climbing."""
    return np.array([2.0 * t, 0.3 * math.sin(t), 10.0 + 0.5 * t]), yaw_quat(0.2 * t)


def frames(n: int, size: int = 32, seed: int = 0) -> list[np.ndarray]:
    """``n`` random-ish smooth RGB images."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size]
    out = []
    for i in range(n):
        base = np.stack([(xx * 7 + i * 3) % 256, (yy * 5 + i * 11) % 256, (xx + yy + i * 17) % 256], axis=-1)
        out.append(np.clip(base + rng.integers(0, 20, base.shape), 0, 255).astype(np.uint8))
    return out


__all__ = [
    "camera_info_msg",
    "compressed_msg",
    "frames",
    "image_msg",
    "png_bytes",
    "pose_msg",
    "trajectory",
    "typestore",
    "write_bag",
    "yaw_quat",
]
