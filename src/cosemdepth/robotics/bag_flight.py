"""Your own flight from a ROS bag: an image topic + a pose topic (+ camera_info) -> a model-ready stream.

:func:`open_bag_flight` reads the bag twice:

1. an index pass (:func:`index_bag`): the image and pose topics are read side by side in stamp order and every
   image gets the pose at its header stamp (:func:`cosemdepth.robotics.rosbag.pose_at_images`: linear position, slerp
   rotation between the two poses around it); only the stamp, frame_id and pose of each image are kept, never the
   pixels;
2. while the model runs, :class:`BagFrameLoader` reads the image messages again, forward, one at a time.

The result is the same :class:`~cosemdepth.data.sequence.SequenceDataset` as ``predict --flight`` builds from a
folder of images and a pose file, with the same conversion of absolute poses to relative camera motions
(:func:`cosemdepth.data.poses.relative_camera_motions`, ``convention`` naming the axes of the posed frame; ROS's
REP 103 ``"flu"`` body by default), the same image -> tensor conversion and the same intrinsics scaling; so the
model sees the same inputs for the same images and poses.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..camera import Calibration, Undistorter, calibration_from_camera_info
from ..data.decode import DEFAULT_JPEG_IDCT, check_jpeg_idct
from ..data.flight import parse_intrinsics, scale_intrinsics
from ..data.frames import Size, resolve_size, rgb_to_tensor
from ..data.poses import convention_matrix, relative_camera_motions
from ..data.quaternion import qmatrix
from ..data.sequence import SequenceDataset, Trajectory
from ..data.undistorted import undistorter_for
from ..errors import ConfigError, DatasetError
from .rosbag import (
    CAMERA_INFO_TYPES,
    IMAGE_TYPES,
    POSE_TYPES,
    Bag,
    check_quaternion,
    format_stamp,
    image_to_rgb,
    pose_at_images,
    pose_from_msg,
    stamp_ns,
)

#: Interpolate an image's pose only between poses at most this many seconds apart (``--max-pose-gap``).
DEFAULT_MAX_POSE_GAP = 0.05
#: Axes of a bag's posed frame when none is given: the ROS body frame (REP 103).
DEFAULT_BAG_CONVENTION = "flu"


@dataclass
class BagIndex:
    """What the index pass keeps: per posed image (in stamp order) its ``indices`` in the image topic, ``stamps``
    (int64 ns), ``frame_ids``, ``positions`` [N, 3] and ``quaternions`` [N, 4] (w, x, y, z) of the posed frame in
    the world; ``skipped`` unposed images; ``native`` image size (H, W)."""

    indices: np.ndarray
    stamps: np.ndarray
    frame_ids: list[str]
    positions: np.ndarray
    quaternions: np.ndarray
    skipped: int
    native: Size
    total: int


def _image_stream(bag: Bag, topic: str, first: dict) -> Any:
    for i, (msgtype, msg) in enumerate(bag.messages(bag.connections(topic, IMAGE_TYPES, "--image-topic"))):
        if i == 0:
            first["rgb"] = image_to_rgb(
                msgtype, msg, f"{bag.path}: topic {topic} at stamp {format_stamp(stamp_ns(msg.header))}"
            )
        first["count"] = i + 1
        yield i, stamp_ns(msg.header), str(msg.header.frame_id)


def _pose_stream(bag: Bag, topic: str, seen: dict) -> Any:
    for msgtype, msg in bag.messages(bag.connections(topic, POSE_TYPES, "--pose-topic")):
        t, p, q = pose_from_msg(msgtype, msg)
        where = f"{bag.path}: topic {topic} at stamp {format_stamp(t)}"
        if not np.isfinite(p).all():
            raise DatasetError(f"{where}: pose position is not finite")
        seen["count"] = seen.get("count", 0) + 1
        yield t, p, check_quaternion(q, where)


def index_bag(
    path: str | Path,
    image_topic: str,
    pose_topic: str,
    *,
    max_pose_gap: float = DEFAULT_MAX_POSE_GAP,
    skip_unposed: bool = False,
) -> BagIndex:
    """The index pass of :func:`open_bag_flight` (see the module docstring)."""
    path = Path(path)
    if not max_pose_gap >= 0:
        raise ConfigError(f"--max-pose-gap must be >= 0 seconds, got {max_pose_gap}")
    first: dict = {"count": 0}
    seen: dict = {}
    idx, stamps, frame_ids, pos, quat = [], [], [], [], []
    skipped = 0
    with Bag(path) as ibag, Bag(path) as pbag:
        # check both topics before reading anything
        ibag.connections(image_topic, IMAGE_TYPES, "--image-topic")
        pbag.connections(pose_topic, POSE_TYPES, "--pose-topic")
        pairs = pose_at_images(
            _image_stream(ibag, image_topic, first),
            _pose_stream(pbag, pose_topic, seen),
            int(round(max_pose_gap * 1e9)),
            skip_unposed=skip_unposed,
            where=f"{path}: topic {image_topic}",
            pose_where=f"{path}: topic {pose_topic} (--pose-topic)",
        )
        for posed in pairs:
            if posed.position is None:
                skipped += 1
                continue
            idx.append(posed.index)
            stamps.append(posed.stamp)
            frame_ids.append(posed.frame_id)
            pos.append(posed.position)
            quat.append(posed.quaternion)
    if not first["count"]:
        raise DatasetError(f"{path}: topic {image_topic} (--image-topic) holds no messages")
    if not idx:
        raise DatasetError(
            f"{path}: none of the {first['count']} images on {image_topic} has a pose on {pose_topic} "
            f"within --max-pose-gap {max_pose_gap:g} s"
        )
    native = tuple(first["rgb"].shape[:2])
    return BagIndex(
        np.asarray(idx, dtype=np.int64),
        np.asarray(stamps, dtype=np.int64),
        frame_ids,
        np.asarray(pos),
        np.asarray(quat),
        skipped,
        native,
        first["count"],
    )


def read_camera_info(path: str | Path, topic: str) -> Calibration:
    """The camera of the first message on ``topic`` (:func:`cosemdepth.camera.calibration_from_camera_info`:
    ``plumb_bob``, ``rational_polynomial`` or ``equidistant`` distortion)."""
    with Bag(path) as bag:
        for _, msg in bag.messages(bag.connections(topic, CAMERA_INFO_TYPES, "--camera-info-topic")):
            where = f"{path}: topic {topic} at stamp {format_stamp(stamp_ns(msg.header))}"
            return calibration_from_camera_info(msg, where)
    raise DatasetError(f"{path}: topic {topic} (--camera-info-topic) holds no messages")


class BagFrameLoader:
    """Loads image ``rec.id`` (its index in the image topic) at the output size, reading the topic forward (rows are
    requested in order when streaming; a request for an earlier image reopens the bag). Picklable (the open bag is
    not pickled)."""

    def __init__(
        self,
        path: Path,
        topic: str,
        size: Size,
        native: Size,
        jpeg_idct: str = DEFAULT_JPEG_IDCT,
        undistorter: Undistorter | None = None,
    ) -> None:
        self.path, self.topic, self.size, self.native = Path(path), topic, size, native
        self.jpeg_idct = check_jpeg_idct(jpeg_idct)
        self.undistorter = undistorter
        self._bag: Bag | None = None
        self._messages = None
        self._next = 0

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_bag": None, "_messages": None, "_next": 0}

    def _open(self) -> None:
        self.close()
        self._bag = Bag(self.path)
        self._messages = self._bag.messages(self._bag.connections(self.topic, IMAGE_TYPES, "--image-topic"))
        self._next = 0

    def close(self) -> None:
        if self._bag is not None:
            self._messages = None
            self._bag.close()
            self._bag = None

    def __call__(self, rec) -> dict[str, torch.Tensor]:
        target = int(rec.id)
        if self._messages is None or target < self._next:
            self._open()
        while True:
            item = next(self._messages, None)
            if item is None:
                raise DatasetError(f"{self.path}: topic {self.topic}: image {target} vanished (bag changed?)")
            self._next += 1
            if self._next - 1 == target:
                break
        msgtype, msg = item
        where = f"{self.path}: topic {self.topic} at stamp {format_stamp(stamp_ns(msg.header))}"
        rgb = image_to_rgb(msgtype, msg, where, self.jpeg_idct)
        if rgb.shape[:2] != tuple(self.native):
            raise DatasetError(
                f"{where}: image is {rgb.shape[0]}x{rgb.shape[1]} but the first image is "
                f"{self.native[0]}x{self.native[1]}; all images of a flight must have one size"
            )
        if self.undistorter is not None:
            image, valid = self.undistorter(rgb)
            return {"rgb": image, "source_valid": valid[None].clone()}
        return {"rgb": rgb_to_tensor(rgb, self.size)}


@dataclass
class BagFlight:
    """An opened bag flight: the ``dataset`` (one trajectory, stream mode) and what the bag writer and the rerun
    log need per row: ``index`` (see :class:`BagIndex`), ``convention`` matrix ``M`` (``X_camera = M X_local``),
    ``intrinsics`` at the output size, output ``size``; ``calibration``: the undistortion applied
    (:meth:`Undistorter.info <cosemdepth.camera.Undistorter.info>`), None for a pinhole."""

    path: Path
    image_topic: str
    dataset: SequenceDataset
    index: BagIndex
    convention: np.ndarray
    intrinsics: torch.Tensor
    size: Size
    loader: BagFrameLoader = field(repr=False)
    calibration: dict | None = None

    def row(self, dataset_index: int) -> int:
        return self.dataset.windows[dataset_index][1]

    def camera_to_world(self, row: int) -> tuple[np.ndarray, np.ndarray]:
        """``(R [3, 3], p [3])`` with ``X_world = R X_camera + p`` (camera optical axes) at ``row``."""
        r = qmatrix(self.index.quaternions[row]) @ self.convention.T
        return r, self.index.positions[row]

    def close(self) -> None:
        self.loader.close()


def frame_label(path: str | Path, topic: str, ns: int) -> str:
    """``BAG:TOPIC@SSSSSSSSSS.NNNNNNNNN``: a bag frame's source as recorded by predict, its stamp in full (seconds
    padded to 10 digits, nanoseconds to 9). Output files are named from the part after the topic's last ``/``
    (``image_raw_1700000000.000001000.npy``), so that names sort as the stamps do."""
    return f"{path}:{topic}@{ns // 1_000_000_000:010d}.{ns % 1_000_000_000:09d}"


def open_bag_flight(
    path: str | Path,
    image_topic: str,
    pose_topic: str,
    *,
    camera_info_topic: str | None = None,
    intrinsics=None,
    fov: float | None = None,
    convention=DEFAULT_BAG_CONVENTION,
    frame_skip: int = 1,
    max_pose_gap: float = DEFAULT_MAX_POSE_GAP,
    skip_unposed: bool = False,
    ignore_distortion: bool = False,
    size: int | tuple[int, int] | None = None,
    jpeg_idct: str = DEFAULT_JPEG_IDCT,
    calibration: str | Path | Calibration | None = None,
) -> BagFlight:
    """Open a bag flight (see the module docstring). Camera: the first ``camera_info_topic`` message (K, with
    ROS's pixel-centre convention converted: ``cx + 0.5``, ``cy + 0.5``, and its distortion), or ``calibration`` (a
    calibration file or a :class:`~cosemdepth.camera.Calibration`), else ``intrinsics`` (fx, fy, cx, cy in the
    package's convention, as ``--flight``) or ``fov``. A distorting lens is undistorted on the fly to a centred
    pinhole (:class:`~cosemdepth.camera.Undistorter`; frames carry ``source_valid``) unless ``ignore_distortion``
    (K used as if the images were undistorted). ``size``: the output size (default the images'; a
    :class:`~cosemdepth.data.frames.FocalSize` is applied to the native size and ``fx``). ``frame_skip = k`` keeps
    every k-th posed image. ``jpeg_idct``: how compressed JPEG images are
    decoded (as the dataset readers: :mod:`cosemdepth.data.decode`)."""
    path = Path(path)
    if not isinstance(frame_skip, int) or frame_skip < 1:
        raise ConfigError(f"--frame-skip must be a positive integer, got {frame_skip!r}")
    given = sum(x is not None for x in (camera_info_topic, calibration, intrinsics, fov))
    if given != 1:
        raise ConfigError(
            "--bag needs exactly one of --camera-info-topic T, --calibration FILE, --intrinsics FX FY CX CY and "
            "--hfov DEG"
        )
    m = convention_matrix(convention)
    info = read_camera_info(path, camera_info_topic) if camera_info_topic else None
    idx = index_bag(path, image_topic, pose_topic, max_pose_gap=max_pose_gap, skip_unposed=skip_unposed)
    native = idx.native
    undistorter = None
    if info is not None:
        if info.size == (0, 0):  # camera_info without a size: the images'
            info = Calibration(
                native,
                *info.k,
                model=info.model,
                coefficients=info.coefficients,
                skew=info.skew,
                source=info.source,
                layout=info.layout,
            )
        if info.size != native:
            raise DatasetError(
                f"{path}: topic {camera_info_topic}: camera_info is for {info.size[0]}x{info.size[1]} "
                f"images but {image_topic} has {native[0]}x{native[1]}"
            )
        k_native = np.array(info.k)
        if info.has_distortion and not ignore_distortion:
            calibration = info
    elif calibration is None:
        k_native = parse_intrinsics(intrinsics, fov, native)
    if calibration is not None:
        undistorter = undistorter_for(calibration, native, size, f"the images of {image_topic}")
    keep = np.arange(0, len(idx.indices), frame_skip)
    idx = BagIndex(
        idx.indices[keep],
        idx.stamps[keep],
        [idx.frame_ids[i] for i in keep],
        idx.positions[keep],
        idx.quaternions[keep],
        idx.skipped,
        native,
        idx.total,
    )
    q_rel, t_rel = relative_camera_motions(idx.quaternions, idx.positions, m)
    if undistorter is not None:
        out_size = undistorter.size
    else:
        out_size = resolve_size(size, lambda: (native, float(k_native[0]))) or native
    name = image_topic.strip("/").replace("/", "_") or "images"
    traj = Trajectory(
        name if name != "bag" else "bag_images",  # predict's output bag is OUT/bag/: the frames go beside it
        [frame_label(path, image_topic, int(t)) for t in idx.stamps],
        q_rel,
        t_rel,
        idx.indices,
        timestamps=idx.stamps / 1e9,
    )
    loader = BagFrameLoader(path, image_topic, out_size, native, jpeg_idct, undistorter)
    intr = undistorter.intrinsics if undistorter is not None else scale_intrinsics(k_native, native, out_size)

    def size_at(rule) -> Size:  # the size these images open at for a size or size rule, as above
        if calibration is not None:
            return undistorter_for(calibration, native, rule, f"the images of {image_topic}").size
        return resolve_size(rule, lambda: (native, float(k_native[0]))) or native

    dataset = SequenceDataset([traj], loader, intr, seq_len=1, mode="stream", name="flight", size_at=size_at)
    info = None if undistorter is None else undistorter.info()
    dataset.calibration = info
    return BagFlight(path, image_topic, dataset, idx, m, intr, out_size, loader, info)


__all__ = ["BagFlight", "BagFrameLoader", "BagIndex", "frame_label", "index_bag", "open_bag_flight", "read_camera_info"]
