"""Poses as they arrive on a live pose topic, and the pose of each image at its stamp.

A pose topic holds one of (:data:`POSE_TOPIC_TYPES`):

* ``geometry_msgs/msg/PoseStamped``, ``PoseWithCovarianceStamped``, ``nav_msgs/msg/Odometry`` (MAVROS'
  ``/mavros/local_position/odom``...): the pose of the body in the header's frame, read as for bags
  (:func:`cosemdepth.robotics.rosbag.pose_from_msg`);
* ``px4_msgs/msg/VehicleOdometry`` (PX4's uXRCE-DDS bridge, ``/fmu/out/vehicle_odometry``): ``position`` and ``q``
  (w, x, y, z) of the FRD body in the NED (or FRD) world, stamped ``timestamp_sample`` (microseconds); a pose with
  a NaN is not valid and is left out. PX4 stamps are microseconds since boot unless the bridge synchronises them with
  the companion computer's clock; stamps since boot next to images stamped in seconds since 1970 are moved onto the
  images' clock by the offset the first pose shows: the time its writer wrote it minus its stamp, less the time a
  recent image was written minus its stamp (a live camera stamps with the time it writes, give or take its delay;
  a replayed or simulated one with its own clock), so the two transport delays' difference stays in;
* ``tf2_msgs/msg/TFMessage`` (``/tf``, with ``/tf_static``): the pose of ``body_frame`` in ``world_frame``, the
  chain of transforms between them composed (each dynamic one interpolated at the stamp). Without ``body_frame``:
  REP 105's ``base_link`` when the transforms name it, else the one frame a dynamic transform moves (several: the
  frames must be given); without ``world_frame``: the root of the tree above the body (``odom`` or ``map``).

Each image takes the pose at its header stamp exactly as ``predict --bag`` does
(:func:`cosemdepth.robotics.rosbag.pose_at_images`: the pose at the same stamp, else the interpolation of the two
around it when they are at most ``max_gap`` apart), once a pose at or after its stamp has arrived
(:meth:`PoseInput.ready`). Memory is bounded: each track keeps its last :data:`MAX_POSES` poses.
"""

from __future__ import annotations

from bisect import bisect_left
from typing import Any

import numpy as np

from ..data.quaternion import qmul, qrotate
from ..errors import ConfigError, DatasetError
from ..robotics.rosbag import EXACT_NS, POSE_TYPES, check_quaternion, format_stamp, pose_at_images, pose_from_msg

PX4_ODOMETRY = "px4_msgs/msg/VehicleOdometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
#: The message types a ``--pose-topic`` may hold.
POSE_TOPIC_TYPES = (*POSE_TYPES, PX4_ODOMETRY, TF_MESSAGE)
#: Poses kept per track (about 16 s at PX4's 250 Hz).
MAX_POSES = 4096
#: Stamps below this (ns; 2001-09-09) are taken as time since boot, above as time since 1970.
EPOCH_NS = 10**18


def default_convention(msgtype: str) -> str:
    """The axes of the posed frame when ``--convention`` is not given: PX4's FRD body (``ned``), else ROS's FLU body
    (REP 103, ``flu``)."""
    return "ned" if msgtype == PX4_ODOMETRY else "flu"


def _checked(stamp: int, p: np.ndarray, q: np.ndarray, where: str) -> tuple[int, np.ndarray, np.ndarray]:
    if not np.isfinite(p).all():
        raise DatasetError(f"{where}: pose position is not finite")
    return stamp, p, check_quaternion(q, where)


def px4_pose(msg: Any) -> tuple[int, np.ndarray, np.ndarray] | None:
    """``(stamp_ns, position, q)`` of a VehicleOdometry message on PX4's clock (``timestamp_sample``, else
    ``timestamp``), None when its position or attitude is unknown (NaN) or its quaternion is not a unit one."""
    us = int(msg.timestamp_sample) or int(msg.timestamp)
    p = np.asarray(msg.position, dtype=np.float64)
    q = np.asarray(msg.q, dtype=np.float64)
    n = float(np.linalg.norm(q))
    if not (np.isfinite(p).all() and np.isfinite(q).all()) or abs(n - 1) > 1e-2:
        return None
    return us * 1000, p, q / n


class PoseTrack:
    """The poses of one frame in another, in stamp order (strictly increasing), the last ``max_poses`` of them."""

    def __init__(self, max_poses: int = MAX_POSES) -> None:
        self.max_poses = int(max_poses)
        self.stamps: list[int] = []
        self.poses: list[tuple[np.ndarray, np.ndarray]] = []

    def __len__(self) -> int:
        return len(self.stamps)

    @property
    def latest(self) -> int | None:
        return self.stamps[-1] if self.stamps else None

    def clear(self) -> None:
        self.stamps.clear()
        self.poses.clear()

    def add(self, stamp: int, p: np.ndarray, q: np.ndarray) -> str | None:
        """Append a pose; one that does not follow the last one is not kept: a repeated stamp is ignored, an earlier
        one (a clock jump back, a restarted publisher) clears the track first. Returns a note for the log, or None."""
        note = None
        if self.stamps and stamp <= self.stamps[-1]:
            if stamp == self.stamps[-1]:
                return None
            note = f"pose stamps went back ({format_stamp(stamp)} after {format_stamp(self.stamps[-1])}): poses cleared"
            self.clear()
        self.stamps.append(int(stamp))
        self.poses.append((p, q))
        if len(self.stamps) > self.max_poses:
            del self.stamps[: len(self.stamps) - self.max_poses]
            del self.poses[: len(self.poses) - self.max_poses]
        return note

    def ready(self, t: int) -> bool:
        """Whether the pose at ``t`` is decided: a pose at (within 1 us) or after ``t`` has arrived."""
        return bool(self.stamps) and self.stamps[-1] >= t - EXACT_NS

    def at(self, t: int, max_gap_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The pose at ``t`` (``predict --bag``'s pairing, on the poses around ``t``), None without one."""
        i = bisect_left(self.stamps, t - EXACT_NS)
        lo = max(i - 1, 0)
        near = [(self.stamps[k], *self.poses[k]) for k in range(lo, min(i + 2, len(self.stamps)))]
        if not near:
            return None
        posed = next(pose_at_images([(0, int(t), "")], near, max_gap_ns, skip_unposed=True))
        return None if posed.position is None else (posed.position, posed.quaternion)


#: The body frame of REP 105 (chosen on ``/tf`` when no body frame is given and the transforms name it).
BASE_LINK = "base_link"


class TfTree:
    """The pose of ``body`` in ``world`` from ``/tf`` and ``/tf_static``: static transforms as last given, each
    dynamic one as a :class:`PoseTrack` (``X_parent = R X_child + p``). ``world`` / ``body`` None: chosen from the
    transforms (see the module docstring; :meth:`frames`)."""

    def __init__(self, world: str | None, body: str | None, max_poses: int = MAX_POSES) -> None:
        self.world = None if not world else world.strip("/")
        self.body = None if not body else body.strip("/")
        self.max_poses = max_poses
        self.static: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}
        self.dynamic: dict[str, tuple[str, PoseTrack]] = {}
        self._said: tuple[str, str] | str | None = None

    def _parent(self, frame: str) -> str | None:
        edge = self.dynamic.get(frame) or self.static.get(frame)
        return None if edge is None else edge[0]

    def frames(self) -> tuple[str, str] | str:
        """``(world, body)``, or why they cannot be chosen yet (a sentence)."""
        body = self.body
        if body is None:
            moved = sorted(self.dynamic)
            known = set(moved) | set(self.static)
            if BASE_LINK in known:
                body = BASE_LINK
            elif len(moved) == 1:
                body = moved[0]
            elif not moved:
                return "no dynamic transform on /tf yet"
            else:
                return f"/tf moves several frames ({', '.join(moved[:6])}): give --body-frame (and --world-frame)"
        world = self.world
        if world is None:
            world, hops = body, 0
            while (parent := self._parent(world)) is not None and hops < 64:
                world, hops = parent, hops + 1
            if world == body:
                return f"no transform on /tf leads from {body} to a parent frame yet"
        return world, body

    def add(self, msg: Any, static: bool = False) -> list[str]:
        notes = []
        for tr in msg.transforms:
            parent, child = str(tr.header.frame_id).strip("/"), str(tr.child_frame_id).strip("/")
            t = tr.transform
            p = np.array([t.translation.x, t.translation.y, t.translation.z], dtype=np.float64)
            q = np.array([t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z], dtype=np.float64)
            stamp = int(tr.header.stamp.sec) * 1_000_000_000 + int(tr.header.stamp.nanosec)
            try:
                stamp, p, q = _checked(stamp, p, q, f"transform {parent} -> {child} at {format_stamp(stamp)}")
            except DatasetError as e:
                notes.append(str(e))
                continue
            if static:
                self.static[child] = (parent, p, q)
                continue
            old = self.dynamic.get(child)
            if old is None or old[0] != parent:
                old = self.dynamic[child] = (parent, PoseTrack(self.max_poses))
            note = old[1].add(stamp, p, q)
            if note:
                notes.append(f"transform {parent} -> {child}: {note}")
        if self.world is None or self.body is None:  # say the frames chosen, and when they change
            chosen = self.frames()
            if isinstance(chosen, tuple) and chosen != self._said:
                notes.append(f"/tf: the pose of {chosen[1]} in {chosen[0]} (--body-frame, --world-frame to choose)")
                self._said = chosen
        return notes

    def chain(self) -> list[tuple[str, Any]] | None:
        """The edges from ``body`` up to ``world`` (child, (parent, PoseTrack) or (parent, p, q)), None while the
        transforms seen do not connect them."""
        chosen = self.frames()
        if isinstance(chosen, str):
            return None
        world, frame = chosen
        edges = []
        while frame != world:
            edge = self.dynamic.get(frame) or self.static.get(frame)
            if edge is None or len(edges) > 64:
                return None
            edges.append((frame, edge))
            frame = edge[0]
        return edges

    def clear(self) -> None:
        for _, track in self.dynamic.values():
            track.clear()

    @property
    def latest(self) -> int | None:
        chain = self.chain()
        tracks = [e[1] for _, e in chain if isinstance(e[1], PoseTrack)] if chain is not None else []
        stamps = [t.latest for t in tracks]
        return None if not stamps or None in stamps else min(stamps)

    def ready(self, t: int) -> bool:
        chain = self.chain()
        if chain is None:
            return False
        return all(e[1].ready(t) for _, e in chain if isinstance(e[1], PoseTrack))

    def at(self, t: int, max_gap_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        chain = self.chain()
        if chain is None:
            return None
        p, q = np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])
        for _, edge in chain:  # body first: T_world_body = T_world_a ... T_z_body
            if isinstance(edge[1], PoseTrack):
                got = edge[1].at(t, max_gap_ns)
                if got is None:
                    return None
                pe, qe = got
            else:
                pe, qe = edge[1], edge[2]
            p, q = pe + qrotate(qe, p), qmul(qe, q)
        return p, q / np.linalg.norm(q)


class PoseInput:
    """The poses of one ``--pose-topic`` of type ``msgtype`` (:data:`POSE_TOPIC_TYPES`); ``world_frame`` and
    ``body_frame`` name the transform of a ``/tf`` topic (None: chosen from the transforms, :class:`TfTree`)."""

    def __init__(
        self, msgtype: str, *, world_frame: str | None = None, body_frame: str | None = None, max_poses=MAX_POSES
    ) -> None:
        if msgtype not in POSE_TOPIC_TYPES:
            raise ConfigError(
                f"--pose-topic: {msgtype} is not a pose type; expected one of {', '.join(POSE_TOPIC_TYPES)}"
            )
        self.msgtype = msgtype
        if msgtype == TF_MESSAGE:
            self.source: Any = TfTree(world_frame, body_frame, max_poses)
        else:
            self.source = PoseTrack(max_poses)
        self.px4_offset: int | None = None

    def add(
        self,
        msg: Any,
        source_ns: int,
        *,
        static: bool = False,
        image_stamp: int | None = None,
        image_source_ns: int | None = None,
    ) -> list[str]:
        """Take a pose message (``source_ns``: when its writer wrote it; ``image_stamp``: a recent image's stamp,
        telling which clock the images use, ``image_source_ns``: when that image was written). Returns notes for the
        log."""
        if self.msgtype == TF_MESSAGE:
            return self.source.add(msg, static)
        if self.msgtype == PX4_ODOMETRY:
            pose = px4_pose(msg)
            if pose is None:
                return []
            stamp, p, q = pose
            if stamp < EPOCH_NS and image_stamp is not None and image_stamp >= EPOCH_NS:
                if self.px4_offset is None:  # PX4's clock -> the writers' -> the images' (their stamp - write time)
                    lag = 0 if image_source_ns is None else int(image_source_ns) - int(image_stamp)
                    self.px4_offset = int(source_ns) - stamp - lag
                stamp += self.px4_offset
        else:
            stamp, p, q = pose_from_msg(self.msgtype, msg)
            try:
                stamp, p, q = _checked(stamp, p, q, f"pose at {format_stamp(stamp)}")
            except DatasetError as e:
                return [str(e)]
        note = self.source.add(stamp, p, q)
        return [note] if note else []

    def unresolved(self) -> str | None:
        """Why a ``/tf`` pose topic gives no pose yet (its frames cannot be chosen), else None."""
        chosen = self.source.frames() if self.msgtype == TF_MESSAGE else None
        return chosen if isinstance(chosen, str) else None

    def clear(self) -> None:
        """Forget the poses (a restarted pose publisher); PX4's clock offset is measured again."""
        self.source.clear()
        self.px4_offset = None

    @property
    def latest(self) -> int | None:
        return self.source.latest

    def ready(self, t: int) -> bool:
        return self.source.ready(t)

    def at(self, t: int, max_gap_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        return self.source.at(t, max_gap_ns)


__all__ = [
    "BASE_LINK",
    "MAX_POSES",
    "POSE_TOPIC_TYPES",
    "PX4_ODOMETRY",
    "PoseInput",
    "PoseTrack",
    "TF_MESSAGE",
    "TfTree",
    "default_convention",
    "px4_pose",
]
