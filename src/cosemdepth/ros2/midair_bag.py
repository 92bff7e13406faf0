"""A Mid-Air-format flight (Mid-Air, SynthAir) as a ROS 2 bag: a camera for ``cosemdepth replay``, the node's tests
and its benchmark; and a bag's copy with only some of its images (:func:`keep_images`).

The bag (MCAP) holds, for one trajectory of a dataset root:

* ``image_topic``: every colour image on disk (``sensor_msgs/Image`` ``rgb8``, decoded as the dataset reader
  decodes it, or ``CompressedImage`` with the JPEG file's bytes), stamped ``base_ns + frame / 25 s`` (the camera runs
  at 25 Hz; only the frames a SynthAir tree rendered are there, every 4th by default), frame_id ``camera``;
* ``info_topic``: its ``sensor_msgs/CameraInfo`` beside each image (the 90-degree pinhole of the format:
  ``fx = W/2``, centred);
* ``pose_topic``: the 100 Hz ground truth from ``sensor_records.hdf5`` (NED world, FRD body: ``--convention ned``)
  as ``pose_type`` messages: ``geometry_msgs/PoseStamped``, ``nav_msgs/Odometry`` or PX4's ``VehicleOdometry``
  (its microsecond stamps on the images' clock, as a bridge synchronised with the companion computer sends them),
  from 20 ms before the first image to 20 ms after the last.

Each message is logged at its stamp, images 1 ms after the pose of their stamp (a camera's images reach a computer
after its odometry).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..data.decode import DEFAULT_JPEG_IDCT, read_rgb
from ..data.midair import format as fmt
from ..errors import ConfigError, DatasetError
from ..robotics.messages import camera_info, header, image
from .idl import typestore

#: The stamp of the flight's start (ns since 1970) when none is given: 2023-11-14 22:13:20 UTC.
DEFAULT_BASE_NS = 1_700_000_000 * 10**9
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Odometry", "px4_msgs/msg/VehicleOdometry")


def _pose_message(ts, msgtype: str, stamp: int, p: np.ndarray, q: np.ndarray) -> Any:
    t = ts.types
    if msgtype == "px4_msgs/msg/VehicleOdometry":
        nan3 = np.full(3, np.nan, dtype=np.float32)
        us = stamp // 1000
        return t[msgtype](
            timestamp=us,
            timestamp_sample=us,
            pose_frame=1,
            position=p.astype(np.float32),
            q=q.astype(np.float32),
            velocity_frame=0,
            velocity=nan3,
            angular_velocity=nan3,
            position_variance=nan3,
            orientation_variance=nan3,
            velocity_variance=nan3,
            reset_counter=0,
            quality=0,
        )
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
        orientation=t["geometry_msgs/msg/Quaternion"](x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0])),
    )
    hdr = header(ts, stamp, "world_ned")
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return t[msgtype](header=hdr, pose=pose)
    zero = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    return t["nav_msgs/msg/Odometry"](
        header=hdr,
        child_frame_id="body_frd",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)
        ),
    )


def write_midair_bag(
    root: str | Path,
    climate: str,
    trajectory: int,
    out: str | Path,
    *,
    environment: str = "SynthAir",
    frames: int | None = None,
    compressed: bool = False,
    pose_type: str = "geometry_msgs/msg/PoseStamped",
    image_topic: str = "/camera/image_raw",
    info_topic: str = "/camera/camera_info",
    pose_topic: str = "/odom",
    base_ns: int = DEFAULT_BASE_NS,
) -> dict[str, Any]:
    """Write trajectory ``trajectory`` of ``root/environment/climate`` as a bag at ``out`` (see the module
    docstring), its first ``frames`` images (default all); returns ``{"images": n, "poses": m, "stamps": [...]}``
    (the images' stamps, ns)."""
    import h5py
    from rosbags.rosbag2 import StoragePlugin, Writer

    if pose_type not in POSE_TYPES:
        raise ConfigError(f"pose_type must be one of {', '.join(POSE_TYPES)}, got {pose_type!r}")
    folder = Path(root) / environment / climate
    name = fmt.trajectory_dir(trajectory)
    h5_path = folder / fmt.SENSOR_RECORDS
    if not h5_path.is_file():
        raise DatasetError(f"{h5_path}: not found")
    with h5py.File(h5_path, "r") as h5:
        if name not in h5:
            raise DatasetError(f"{h5_path}: no trajectory {name}")
        gt = h5[name]["groundtruth"]
        attitude = np.asarray(gt["attitude"][()], dtype=np.float64)
        position = np.asarray(gt["position"][()], dtype=np.float64)
        paths = [p.decode() if isinstance(p, bytes) else str(p) for p in h5[name]["camera_data"]["color_left"][()]]
    paths = [p for p in paths if (folder / p).is_file()][:frames]
    if not paths:
        raise DatasetError(f"{folder / fmt.COLOR_DIR / name}: no colour images")
    ts = typestore()
    per_frame = fmt.GROUNDTRUTH_RATE // fmt.CAMERA_RATE
    numbers = [int(Path(p).stem) for p in paths]
    gt_ns = 1_000_000_000 // fmt.GROUNDTRUTH_RATE
    first, last = numbers[0] * per_frame - 2, numbers[-1] * per_frame + 2
    messages = []
    for k in range(max(first, 0), min(last, len(attitude) - 1) + 1):
        stamp = base_ns + k * gt_ns
        messages.append((pose_topic, _pose_message(ts, pose_type, stamp, position[k], attitude[k]), stamp))
    stamps = []
    for n, rel in zip(numbers, paths):
        stamp = base_ns + n * per_frame * gt_ns
        stamps.append(stamp)
        hdr = header(ts, stamp, "camera")
        if compressed:
            data = np.frombuffer((folder / rel).read_bytes(), dtype=np.uint8)
            msg = ts.types["sensor_msgs/msg/CompressedImage"](header=hdr, format="jpeg", data=data)
            h, w = read_rgb(folder / rel, DEFAULT_JPEG_IDCT).shape[:2]
        else:
            rgb = read_rgb(folder / rel, DEFAULT_JPEG_IDCT)
            msg = image(ts, hdr, rgb, "rgb8")
            h, w = rgb.shape[:2]
        log = stamp + 1_000_000
        messages.append((info_topic, camera_info(ts, hdr, (h, w), (w / 2, h / 2, w / 2, h / 2)), log))
        messages.append((image_topic, msg, log))
    messages.sort(key=lambda m: m[2])  # stable: at one log time, the order above
    conns: dict[str, Any] = {}
    with Writer(Path(out), version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for topic, msg, t in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=ts)
            writer.write(conns[topic], t, ts.serialize_cdr(msg, msg.__msgtype__))
    return {"images": len(paths), "poses": len(messages) - 2 * len(paths), "stamps": stamps}


def keep_images(bag: str | Path, out: str | Path, stamps, topics: tuple[str, ...]) -> Path:
    """A copy of the ROS 2 bag ``bag`` at ``out`` (MCAP) in which the messages of ``topics`` (images, their
    camera_info) are kept only at the header stamps ``stamps`` (ns); every other message is kept. What ``predict --bag``
    reads to compare a live run that dropped frames: the same motion chain as the node's."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import StoragePlugin, Writer

    keep = {int(s) for s in stamps}
    with AnyReader([Path(bag)]) as r, Writer(Path(out), version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns: dict[str, Any] = {}
        for c, t, raw in r.messages():
            if c.topic in topics:
                h = r.deserialize(raw, c.msgtype).header
                if h.stamp.sec * 1_000_000_000 + h.stamp.nanosec not in keep:
                    continue
            if c.topic not in conns:
                conns[c.topic] = w.add_connection(c.topic, c.msgtype, typestore=r.typestore)
            w.write(conns[c.topic], t, raw)
    return Path(out)


__all__ = ["DEFAULT_BASE_NS", "POSE_TYPES", "keep_images", "write_midair_bag"]
