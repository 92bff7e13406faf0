"""Reading ROS bags: opening a bag, finding its topics, decoding images, poses and camera_info, and pairing each
image with the pose at its stamp.

Bags are read with ``rosbags`` (pure Python: ROS 2 bag folders in sqlite3 or MCAP storage, ROS 1 ``.bag`` files,
no ROS installation). It is an optional dependency (``pip install cosemdepth[ros]``), imported only here and only
when a bag is opened, so that the rest of the package works without it.

Stamps are integers in nanoseconds (``header.stamp.sec * 10**9 + header.stamp.nanosec``), so that an output message
carries exactly its input's stamp.

Pairing images with poses (:func:`pose_at_images`) is a merge of two streams sorted by stamp that keeps only the two
poses around the current image: memory does not grow with the length of the bag.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from ..data.decode import DEFAULT_JPEG_IDCT, decode_rgb
from ..data.poses import interpolate_pose
from ..errors import DatasetError
from ..optional import require

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped", "nav_msgs/msg/Odometry")
CAMERA_INFO_TYPES = ("sensor_msgs/msg/CameraInfo",)
#: Raw image encodings read (16-bit ones keep every bit: uint16, scaled to 0..1 by ``value / 65535`` as 16-bit
#: PNGs are).
IMAGE_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8", "mono8", "rgb16", "bgr16", "mono16")
#: An image and a pose closer than this (ns) are the same instant (as ``poses_at``'s 1 us).
EXACT_NS = 1000


def require_rosbags():
    """The ``rosbags`` package, or a ConfigError saying how to install it."""
    require("rosbags.highlevel", "reading and writing ROS bags")  # lazy: an optional dependency, only for bags
    import rosbags

    return rosbags


def stamp_ns(header: Any) -> int:
    """A ``std_msgs/Header``'s stamp in integer nanoseconds."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def format_stamp(ns: int) -> str:
    """``1234.000000042`` (seconds with 9 decimals) for messages."""
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"


class Bag:
    """An open bag (a context manager): ``Bag(path)`` opens it, :meth:`connections` finds a topic's connections,
    :meth:`messages` iterates the deserialized messages of one topic in storage order."""

    def __init__(self, path: str | Path) -> None:
        require_rosbags()
        from rosbags.highlevel import AnyReader  # deferred: an optional dependency (cosemdepth[ros])

        self.path = Path(path)
        if not self.path.exists():
            raise DatasetError(f"{self.path}: bag not found")
        try:  # rosbags raises its own error types for every malformed file, already in the constructor for some
            self._reader = AnyReader([self.path])
            self._reader.open()
        except Exception as e:
            raise DatasetError(f"{self.path}: cannot read the bag ({_reason(e)})") from None

    def __enter__(self) -> "Bag":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._reader is not None:
            try:
                self._reader.close()
            except Exception:
                pass
            self._reader = None

    @property
    def reader(self):
        """The open ``rosbags.highlevel.AnyReader`` (its connections, typestore and raw messages)."""
        return self._reader

    def topics(self) -> dict[str, str]:
        """Topic -> message type."""
        return {c.topic: c.msgtype for c in self._reader.connections}

    def connections(self, topic: str, types: tuple[str, ...], option: str) -> list:
        """The connections of ``topic``; a DatasetError naming the bag and ``topic`` when it is absent or its type is
        not one of ``types`` (``option`` names the argument in the message)."""
        conns = [c for c in self._reader.connections if c.topic == topic]
        if not conns:
            have = ", ".join(f"{t} ({m})" for t, m in sorted(self.topics().items())) or "none"
            raise DatasetError(f"{self.path}: no topic {topic!r} ({option}); topics in the bag: {have}")
        bad = [c.msgtype for c in conns if c.msgtype not in types]
        if bad:
            raise DatasetError(
                f"{self.path}: topic {topic} ({option}) holds {bad[0]}; expected one of {', '.join(types)}"
            )
        return conns

    def messages(self, conns: list) -> Iterator[tuple[str, Any]]:
        """``(msgtype, message)`` of ``conns`` in storage order; a corrupt message is a DatasetError."""
        try:
            for conn, _, raw in self._reader.messages(connections=conns):
                try:
                    msg = self._reader.deserialize(raw, conn.msgtype)
                except Exception as e:
                    raise DatasetError(
                        f"{self.path}: topic {conn.topic}: cannot decode a message ({_reason(e)})"
                    ) from None
                yield conn.msgtype, msg
        except DatasetError:
            raise
        except Exception as e:
            raise DatasetError(f"{self.path}: cannot read the bag ({_reason(e)})") from None


def _reason(e: Exception) -> str:
    text = str(e).strip().splitlines()
    return (text[0] if text else type(e).__name__)[:300]


# ---------------------------------------------------------------------------------------------- message decoding


def image_to_rgb(msgtype: str, msg: Any, where: str, jpeg_idct: str = DEFAULT_JPEG_IDCT) -> np.ndarray:
    """A ``sensor_msgs/Image`` (encodings :data:`IMAGE_ENCODINGS`) or ``CompressedImage`` (JPEG/PNG, decoded as the
    dataset readers decode files: :func:`cosemdepth.data.decode.decode_rgb` with ``jpeg_idct``) -> ``[H, W, 3]``
    uint8, or uint16 for the 16-bit encodings and 16-bit PNGs. ``where`` (bag, topic, stamp) prefixes the error messages."""
    if msgtype.endswith("CompressedImage"):
        return decode_rgb(bytes(msg.data), f"{where}: compressed image ({msg.format or 'no format'})", jpeg_idct)
    enc = str(msg.encoding).lower()
    if enc not in IMAGE_ENCODINGS:
        raise DatasetError(
            f"{where}: image encoding {msg.encoding!r} is not supported; use one of "
            f"{', '.join(IMAGE_ENCODINGS)} (or a CompressedImage topic)"
        )
    h, w, row_bytes = int(msg.height), int(msg.width), int(msg.step)  # Image.step: bytes per row
    channels = 1 if enc.startswith("mono") else (4 if enc.endswith("a8") else 3)
    itemsize = 2 if enc.endswith("16") else 1
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if h < 1 or w < 1 or row_bytes < w * channels * itemsize or data.size < row_bytes * h:
        raise DatasetError(f"{where}: image {h}x{w} {enc} with step {row_bytes} does not fit its {data.size} bytes")
    rows = data[: row_bytes * h].reshape(h, row_bytes)[:, : w * channels * itemsize]
    if itemsize == 2:
        dt = np.dtype(">u2" if msg.is_bigendian else "<u2")
        px = np.frombuffer(np.ascontiguousarray(rows).tobytes(), dtype=dt).reshape(h, w, channels).astype(np.uint16)
    else:
        px = rows.reshape(h, w, channels)
    if channels == 1:
        px = np.repeat(px, 3, axis=2)
    elif enc.startswith("bgr"):
        px = px[:, :, 2::-1]
    else:
        px = px[:, :, :3]
    return np.array(px, order="C")  # a writable copy (the message's buffer may be read-only)


def pose_from_msg(msgtype: str, msg: Any) -> tuple[int, np.ndarray, np.ndarray]:
    """``(stamp_ns, position [3], quaternion [4] (w, x, y, z), unit)`` of a PoseStamped,
    PoseWithCovarianceStamped or Odometry message (the pose of the child/body frame in the header's frame)."""
    pose = msg.pose if msgtype == "geometry_msgs/msg/PoseStamped" else msg.pose.pose  # the others wrap it
    p = np.array([pose.position.x, pose.position.y, pose.position.z], dtype=np.float64)
    o = pose.orientation
    q = np.array([o.w, o.x, o.y, o.z], dtype=np.float64)
    return stamp_ns(msg.header), p, q


# --------------------------------------------------------------------------------------- image <-> pose pairing


@dataclass(frozen=True)
class PosedImage:
    """An image message's place in its topic (``index``), stamp, frame_id and its interpolated pose (``None``
    when unposed and skipped)."""

    index: int
    stamp: int
    frame_id: str
    position: np.ndarray | None
    quaternion: np.ndarray | None


def pose_at_images(
    images: Iterable[tuple[int, int, str]],
    poses: Iterable[tuple[int, np.ndarray, np.ndarray]],
    max_gap_ns: int,
    *,
    skip_unposed: bool = False,
    where: str = "bag",
    pose_where: str = "poses",
) -> Iterator[PosedImage]:
    """Pair every image ``(index, stamp_ns, frame_id)`` with the pose at its stamp.

    Both streams must be sorted by stamp (strictly increasing; otherwise a DatasetError naming the stamp). The
    pose at ``t`` is the pose with the same stamp (within :data:`EXACT_NS`), else the interpolation (linear
    position, slerp rotation) of the two poses around ``t`` when they are at most ``max_gap_ns`` apart. An image
    without such poses is a DatasetError naming its stamp, or, with ``skip_unposed``, yielded with pose ``None``.
    Only two poses are held at any time.
    """
    it = iter(poses)
    prev: tuple[int, np.ndarray, np.ndarray] | None = None
    nxt = next(it, None)
    last_image = None

    def advance():
        nonlocal prev, nxt
        new = next(it, None)
        if new is not None and new[0] <= nxt[0]:
            raise DatasetError(
                f"{pose_where}: pose stamps must increase ({format_stamp(new[0])} follows {format_stamp(nxt[0])})"
            )
        prev, nxt = nxt, new

    for index, t, frame_id in images:
        if last_image is not None and t <= last_image:
            raise DatasetError(
                f"{where}: image stamps must increase ({format_stamp(t)} follows {format_stamp(last_image)})"
            )
        if last_image is None and nxt is None:
            raise DatasetError(f"{pose_where}: holds no pose messages")
        last_image = t
        while nxt is not None and nxt[0] < t - EXACT_NS:
            advance()
        pose = None
        for cand in (prev, nxt):
            if cand is not None and abs(cand[0] - t) <= EXACT_NS:
                pose = cand[1], cand[2]
                break
        if pose is None and prev is not None and nxt is not None and nxt[0] - prev[0] <= max_gap_ns:
            a = (t - prev[0]) / (nxt[0] - prev[0])
            pose = interpolate_pose(a, prev[1], prev[2], nxt[1], nxt[2])
        if pose is None:
            if skip_unposed:
                yield PosedImage(index, t, frame_id, None, None)
                continue
            before = f"{(t - prev[0]) / 1e9:.6f} s before" if prev is not None else "none before"
            after = f"{(nxt[0] - t) / 1e9:.6f} s after" if nxt is not None else "none after"
            raise DatasetError(
                f"{where}: no pose for the image at stamp {format_stamp(t)} (nearest poses: {before}, {after}; "
                f"interpolation only across gaps <= {max_gap_ns / 1e9:g} s: --max-pose-gap, or --skip-unposed)"
            )
        yield PosedImage(index, t, frame_id, pose[0], pose[1])


def check_quaternion(q: np.ndarray, where: str, tol: float = 1e-2) -> np.ndarray:
    """``q`` normalized; a DatasetError when it is not finite or its norm is off 1 by more than ``tol``."""
    n = float(np.linalg.norm(q))
    if not math.isfinite(n) or abs(n - 1) > tol:
        raise DatasetError(f"{where}: pose orientation is not a unit quaternion (norm {n:.6f})")
    return q / n


__all__ = [
    "Bag",
    "CAMERA_INFO_TYPES",
    "IMAGE_ENCODINGS",
    "IMAGE_TYPES",
    "POSE_TYPES",
    "PosedImage",
    "check_quaternion",
    "format_stamp",
    "image_to_rgb",
    "pose_at_images",
    "pose_from_msg",
    "require_rosbags",
    "stamp_ns",
]
