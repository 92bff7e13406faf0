"""The live source: frames from a ROS 2 graph (an image topic, camera_info or given intrinsics, a pose topic) as the
streaming pipeline's :class:`~cosemdepth.streaming.frames.FrameBatch` objects, one frame at a time, the newest first.

A receiver thread takes every sample as it arrives: images wait in a short queue, poses go to a
:class:`~cosemdepth.ros2.poses.PoseInput`, camera_info updates the intrinsics. When the pipeline asks for the next
frame, the source hands over the newest image whose pose is decided (a pose at or after its stamp has arrived) and
drops the older queued ones (counted: the node never builds a backlog). An image whose pose has not come within
``pose_timeout`` seconds of its arrival (the pose stream stopped, or lags) is handed over without a pose: no depth
(status ``reset``), its labels still computed.

Each frame is converted as ``predict --bag`` converts a bag's (the same decoding, resizing, intrinsics scaling, pose
pairing and relative motion), so the same images and poses give the same depth. The motion is that from the
previous *processed* frame. The state starts afresh (``reset``, the reason logged and in the frame's ``meta``) on:
the first frame, a frame after one without a pose, a new image publisher (a restarted camera or replay), an image
stamp that goes back (a clock jump) or jumps forward by more than ``max_frame_gap`` seconds, and new intrinsics.
"""

from __future__ import annotations

import dataclasses
import re
import sys
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import torch

from ..camera import Calibration, Undistorter, calibration_from_camera_info, load_calibration
from ..data.decode import DEFAULT_JPEG_IDCT, check_jpeg_idct
from ..data.flight import parse_intrinsics, scale_intrinsics
from ..data.frames import Size, resolve_size, rgb_to_tensor
from ..data.poses import CONVENTIONS, convention_matrix, relative_camera_motions
from ..data.quaternion import qmatrix
from ..data.undistorted import undistorter_for
from ..errors import ConfigError, CosemdepthError
from ..robotics.rosbag import CAMERA_INFO_TYPES, IMAGE_TYPES, format_stamp, image_to_rgb, stamp_ns
from ..streaming.frames import FrameBatch
from ..streaming.registry import register_source
from .dds import QOS_CHOICES, Graph, Sample, ros_topic
from .idl import decode, idl_type
from .poses import POSE_TOPIC_TYPES, TF_MESSAGE, PoseInput, default_convention

#: Interpolate an image's pose only between poses at most this many seconds apart (as ``predict --bag``).
DEFAULT_MAX_POSE_GAP = 0.05
#: Seconds an image waits for its pose before it is processed without one.
DEFAULT_POSE_TIMEOUT = 0.5
#: An image stamp this many seconds after the previous processed one starts the state afresh.
DEFAULT_MAX_FRAME_GAP = 1.0
#: Images queued at most (older ones are dropped as newer ones arrive).
MAX_PENDING = 16
#: Seconds the receiver lets samples gather after taking some (an image waits at most this long longer).
RECEIVE_BATCH = 0.005
#: Seconds between two log lines of one kind (the others are counted).
LOG_EVERY = 10.0
#: Keep-last depth of the pose readers (the receiver drains them continuously; this covers a stalled second).
POSE_DEPTH = 1000


def log_stderr(message: str) -> None:
    print(f"cosemdepth node: {message}", file=sys.stderr, flush=True)


@dataclass(frozen=True)
class LiveOptions:
    """What the live source reads (``cosemdepth node``'s input flags; docs/robotics.md).

    Attributes:
        image_topic, pose_topic: ROS topics (the types are discovered from the graph: :data:`IMAGE_TYPES`,
            :data:`~cosemdepth.ros2.poses.POSE_TOPIC_TYPES`).
        camera_info_topic / calibration (a calibration file: :func:`cosemdepth.camera.load_calibration`; loaded
            and checked here) / intrinsics (fx, fy, cx, cy; package convention, at the images' size) / hfov
            (degrees): exactly one.
        convention: axes of the posed frame (``cosemdepth.data.poses.CONVENTIONS``); None: ``ned`` for PX4's
            VehicleOdometry, ``flu`` otherwise.
        world_frame, body_frame: the transform of a ``/tf`` pose topic.
        max_pose_gap, pose_timeout, max_frame_gap: seconds (see the module docstring).
        input_qos: ``sensor`` (best effort: takes reliable and best-effort publishers) or ``reliable``.
        ignore_distortion: use K of a distorting lens as if the images were undistorted (default: undistorted to a
            pinhole as ``predict --bag`` does; :class:`~cosemdepth.camera.Undistorter`).
        jpeg_idct: how CompressedImage JPEGs are decoded (:mod:`cosemdepth.data.decode`).
        discovery_timeout: seconds to wait for the publishers (None: until stopped).
    """

    image_topic: str
    pose_topic: str
    camera_info_topic: str | None = None
    calibration: str | Path | Calibration | None = None
    intrinsics: tuple[float, float, float, float] | None = None
    hfov: float | None = None
    convention: str | None = None
    world_frame: str | None = None
    body_frame: str | None = None
    max_pose_gap: float = DEFAULT_MAX_POSE_GAP
    pose_timeout: float = DEFAULT_POSE_TIMEOUT
    max_frame_gap: float = DEFAULT_MAX_FRAME_GAP
    input_qos: str = "sensor"
    ignore_distortion: bool = False
    jpeg_idct: str = DEFAULT_JPEG_IDCT
    discovery_timeout: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "image_topic", ros_topic(self.image_topic, "--image-topic"))
        object.__setattr__(self, "pose_topic", ros_topic(self.pose_topic, "--pose-topic"))
        if self.camera_info_topic is not None:
            object.__setattr__(self, "camera_info_topic", ros_topic(self.camera_info_topic, "--camera-info-topic"))
        given = sum(x is not None for x in (self.camera_info_topic, self.calibration, self.intrinsics, self.hfov))
        if given != 1:
            raise ConfigError(
                "the node needs exactly one of --camera-info-topic T, --calibration FILE, --intrinsics FX FY CX CY, "
                "--hfov DEG"
            )
        if self.calibration is not None and not isinstance(self.calibration, Calibration):
            object.__setattr__(self, "calibration", load_calibration(self.calibration).check())
        if self.hfov is not None and not 0 < self.hfov < 180:
            raise ConfigError(f"--hfov must be in (0, 180) degrees, got {self.hfov}")
        if self.intrinsics is not None:
            parse_intrinsics(self.intrinsics, None, (1, 1))  # the numbers' checks
        if self.convention is not None and self.convention not in CONVENTIONS:
            raise ConfigError(f"--convention must be one of {', '.join(CONVENTIONS)}, got {self.convention!r}")
        for name in ("max_pose_gap", "pose_timeout", "max_frame_gap"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 <= v < float("inf")):
                raise ConfigError(f"--{name.replace('_', '-')} must be a number of seconds >= 0, got {v!r}")
        if self.input_qos not in QOS_CHOICES:
            raise ConfigError(f"--input-qos must be one of {', '.join(QOS_CHOICES)}, got {self.input_qos!r}")
        check_jpeg_idct(self.jpeg_idct)


@dataclass
class LiveStats:
    """Counters of a live run (shared by the source, the sink and the reports)."""

    received: int = 0
    processed: int = 0
    dropped: int = 0
    unposed: int = 0
    rejected: int = 0
    resets: Counter = field(default_factory=Counter)

    def as_dict(self) -> dict[str, Any]:
        return {
            "frames_received": self.received,
            "frames_processed": self.processed,
            "frames_dropped": self.dropped,
            "frames_without_pose": self.unposed,
            "frames_rejected": self.rejected,
            "resets": dict(self.resets),
        }


def lens_key(cal: Calibration) -> tuple:
    """What makes two calibrations the same camera (not where they were read)."""
    return (cal.size, cal.k, cal.model, cal.coefficients, cal.skew)


@dataclass(frozen=True)
class _Camera:
    """How the images of one camera become model inputs: ``key`` (a new one starts the state afresh), the
    ``undistorter`` of a calibrated lens (None: a pinhole, resized), the output ``size`` and ``intrinsics`` ``[4]``
    float32 at it (package convention)."""

    key: tuple
    undistorter: Undistorter | None
    size: Size
    intrinsics: torch.Tensor


@dataclass
class _Image:
    stamp: int
    frame_id: str
    msgtype: str
    msg: Any
    source_ns: int
    received_ns: int
    writer: int


class LiveSource:
    """Frames from the live graph (see the module docstring).

    Args:
        graph: the :class:`~cosemdepth.ros2.dds.Graph` to read from.
        options: :class:`LiveOptions`.
        size: the model's input size: an int, ``(H, W)``, a :class:`~cosemdepth.data.frames.FocalSize` applied to
            the first frame's camera, or None (the images' size).
        log: where notes go (one line each; default stderr).
        stats: the counters to update (default a new :class:`LiveStats`).
    """

    name = "live"

    @classmethod
    def from_options(cls, options: LiveOptions, size=None) -> "LiveSource":
        """A source with a participant of its own in ``ROS_DOMAIN_ID`` (left when the source is closed)."""
        source = cls(Graph(), options, size)
        source._owns_graph = True
        return source

    def __init__(
        self,
        graph: Graph,
        options: LiveOptions,
        size=None,
        *,
        log: Callable[[str], None] = log_stderr,
        stats: LiveStats | None = None,
    ) -> None:
        self.graph, self.options, self.size_rule, self.log = graph, options, size, log
        self.stats = stats if stats is not None else LiveStats()
        self.stopping = threading.Event()
        self._cond = threading.Condition()
        self._pending: deque[_Image] = deque()
        self._thread: threading.Thread | None = None
        self._readers: dict[str, Any] = {}
        self._error: BaseException | None = None
        self.image_type: str | None = None
        self.pose_type: str | None = None
        self.poses: PoseInput | None = None
        self.info: Calibration | None = None
        self.info_error: str | None = None
        self.out_size: Size | None = None
        self._camera: _Camera | None = None
        self.convention: np.ndarray | None = None
        # the motion chain: the last processed frame
        self._last: dict[str, Any] | None = None
        self._segment = 0
        self._row = 0
        self._last_image_stamp: int | None = None
        self._last_image_written: int | None = None
        self._owns_graph = False
        self._noted: dict[str, tuple[float | None, int]] = {}

    # ------------------------------------------------------------------ what it is
    def describe(self) -> dict[str, Any]:
        o = self.options
        return {
            "image_topic": o.image_topic,
            "image_type": self.image_type,
            "pose_topic": o.pose_topic,
            "pose_type": self.pose_type,
            "camera_info_topic": o.camera_info_topic,
            "convention": o.convention or (default_convention(self.pose_type) if self.pose_type else None),
            **({"tf_frames": self.poses.source.frames()} if self.pose_type == TF_MESSAGE and self.poses else {}),
            "max_pose_gap_s": o.max_pose_gap,
            "pose_timeout_s": o.pose_timeout,
            "max_frame_gap_s": o.max_frame_gap,
            "input_qos": o.input_qos,
            "domain": self.graph.domain,
        }

    def frame_size(self) -> tuple[int, int] | None:
        return self.out_size

    def limited(self, key: str, message: str) -> None:
        """Log ``message`` unless a message of ``key`` was logged in the last :data:`LOG_EVERY` seconds (then it is
        counted, and the count said with the next one)."""
        now = time.monotonic()
        key = re.sub(r"[-+0-9.]+", "#", key)[:60]  # one kind whatever its stamps and numbers
        if len(self._noted) > 256:  # bounded over hours of odd input
            self._noted.clear()
        last, skipped = self._noted.get(key, (None, 0))
        if last is not None and now - last < LOG_EVERY:
            self._noted[key] = (last, skipped + 1)
            return
        self._noted[key] = (now, 0)
        self.log(message + (f" ({skipped} more like it since the last such line)" if skipped else ""))

    # ------------------------------------------------------------------ joining the graph
    def start(self) -> bool:
        """Find the input topics' types in the graph (waiting for their publishers), subscribe, and start receiving.
        Returns False when stopped (or ``discovery_timeout`` passed) before the publishers appeared."""
        o = self.options
        self.image_type = self._discover(o.image_topic, IMAGE_TYPES, "--image-topic")
        if self.image_type is None:
            return False
        self.pose_type = self._discover(o.pose_topic, POSE_TOPIC_TYPES, "--pose-topic")
        if self.pose_type is None:
            return False
        self.poses = PoseInput(self.pose_type, world_frame=o.world_frame, body_frame=o.body_frame)
        self.convention = convention_matrix(o.convention or default_convention(self.pose_type))
        qos = o.input_qos
        g = self.graph
        self._readers["image"] = g.reader(o.image_topic, idl_type(self.image_type), qos)
        self._readers["pose"] = g.reader(o.pose_topic, idl_type(self.pose_type), qos, depth=POSE_DEPTH)
        if self.pose_type == TF_MESSAGE:
            self._readers["tf_static"] = g.reader("/tf_static", idl_type(TF_MESSAGE), "static", depth=100)
        if o.camera_info_topic is not None:
            self._readers["camera_info"] = g.reader(o.camera_info_topic, idl_type(CAMERA_INFO_TYPES[0]), qos)
        self._thread = threading.Thread(target=self._receive, name="cosemdepth-live-receiver", daemon=True)
        self._thread.start()
        self.log(
            f"subscribed: {o.image_topic} ({self.image_type}), {o.pose_topic} ({self.pose_type})"
            + (f", {o.camera_info_topic}" if o.camera_info_topic else "")
            + f"; domain {g.domain}, {qos} QoS"
        )
        return True

    def _discover(self, topic: str, types: tuple[str, ...], option: str) -> str | None:
        timeout = self.options.discovery_timeout
        end = None if timeout is None else time.monotonic() + timeout
        waited = False
        while not self.stopping.is_set():
            step = 0.5 if end is None else max(0.0, min(0.5, end - time.monotonic()))
            found = self.graph.discover_type(topic, types, step, option)
            if found is not None:
                return found
            if not waited:
                self.log(f"waiting for a publisher on {topic} ({option}: {' or '.join(types)})")
                waited = True
            if end is not None and time.monotonic() >= end:
                self.log(f"no publisher on {topic} ({option}) within {timeout:g} s")
                break
        return None

    # ------------------------------------------------------------------ receiving (the receiver thread)
    def _receive(self) -> None:
        try:
            while not self.stopping.is_set():
                self.graph.wait(0.1)
                if self._drain():
                    self.stopping.wait(RECEIVE_BATCH)  # let a burst of poses gather: fewer wake-ups, less GIL
        except BaseException as e:  # noqa: BLE001 - handed to the consumer, which raises it
            self._error = e
            with self._cond:
                self._cond.notify_all()

    def _drain(self) -> bool:
        """Take every sample that arrived; whether there was any."""
        notes: list[str] = []
        got = False
        with self._cond:
            for kind, reader in self._readers.items():
                for sample in reader.take(256):
                    got = True
                    try:
                        self._take(kind, sample, notes)
                    except CosemdepthError as e:  # a malformed message: noted, never fatal
                        notes.append(f"{kind} topic: {e}")
            if got:
                self._cond.notify_all()
        for n in notes:
            self.limited(n, n)
        return got

    def _take(self, kind: str, sample: Sample, notes: list[str]) -> None:
        o = self.options
        if kind == "image":
            msg = decode(sample.data, self.image_type)
            t = stamp_ns(msg.header)
            self.stats.received += 1
            if self._last_image_stamp is not None and t < self._last_image_stamp:
                latest = self.poses.latest
                if latest is not None and latest > t + int(o.max_frame_gap * 1e9):
                    self.poses.clear()  # the pose track has not jumped back with the images yet: its poses are stale
            self._last_image_stamp, self._last_image_written = t, sample.source_ns
            self._pending.append(
                _Image(
                    t,
                    str(msg.header.frame_id),
                    self.image_type,
                    msg,
                    sample.source_ns,
                    sample.received_ns,
                    sample.writer,
                )
            )
            while len(self._pending) > MAX_PENDING:
                self._pending.popleft()
                self.stats.dropped += 1
                if not self._intrinsics_known():
                    notes.append(f"no camera_info on {o.camera_info_topic} yet: the images wait, the oldest dropped")
        elif kind in ("pose", "tf_static"):
            msg = decode(sample.data, self.pose_type)
            notes.extend(
                self.poses.add(
                    msg,
                    sample.source_ns,
                    static=kind == "tf_static",
                    image_stamp=self._last_image_stamp,
                    image_source_ns=self._last_image_written,
                )
            )
        elif kind == "camera_info":
            msg = decode(sample.data, CAMERA_INFO_TYPES[0])
            where = f"{o.camera_info_topic} at stamp {format_stamp(stamp_ns(msg.header))}"
            try:
                info = calibration_from_camera_info(msg, where)
            except CosemdepthError as e:  # the images are left out (said) until a usable camera_info comes
                self.info, self.info_error = None, str(e)
                raise
            self.info_error = None
            if self.info is not None and lens_key(info) != lens_key(self.info):
                notes.append(
                    f"{o.camera_info_topic}: new camera {info.model} {info.k} for {info.size[1]}x{info.size[0]}"
                )
            self.info = info

    # ------------------------------------------------------------------ choosing the next frame
    def _intrinsics_known(self) -> bool:
        return self.options.camera_info_topic is None or self.info is not None or self.info_error is not None

    def _select(self) -> tuple[_Image, bool, int] | None:
        """``(image, posed, dropped)``: the newest queued image whose pose is decided, or else the newest that waited
        for its pose longer than the timeout; the older queued images are dropped. None: nothing to process yet."""
        if not self._pending or not self._intrinsics_known():
            return None
        chosen, posed = None, True
        for i in range(len(self._pending) - 1, -1, -1):
            if self.poses.ready(self._pending[i].stamp):
                chosen = i
                break
        if chosen is None:
            limit = time.time_ns() - int(self.options.pose_timeout * 1e9)
            late = [i for i, im in enumerate(self._pending) if im.received_ns <= limit]
            if not late:
                return None
            chosen, posed = late[-1], False
        for _ in range(chosen):
            self._pending.popleft()
        self.stats.dropped += chosen
        return self._pending.popleft(), posed, chosen

    # ------------------------------------------------------------------ frames
    def batches(self, *, lanes: int = 1, max_frames: int | None = None, num_workers: int = 0) -> Iterator[FrameBatch]:
        """The frames as they arrive, one per batch, until :meth:`stop` (or ``max_frames`` frames)."""
        if lanes != 1:
            raise ConfigError("a live source streams one camera: --trajectories-per-batch must be 1")
        if self._thread is None and not self.start():
            return
        done = 0
        while max_frames is None or done < max_frames:
            with self._cond:
                picked = None
                while not self.stopping.is_set() and self._error is None:
                    picked = self._select()
                    if picked is not None:
                        break
                    self._cond.wait(0.05)
                if self._error is not None:
                    raise self._error
                if picked is None:
                    return
            image, posed, dropped = picked
            picked_ns = time.time_ns()
            try:
                batch = self._frame(image, posed, dropped)
            except CosemdepthError as e:  # an image that cannot be decoded or fits no camera: noted and left out
                self.stats.rejected += 1
                self._last = None
                self.limited("left out", f"frame left out: {e}")
                continue
            batch.meta[0]["picked_ns"], batch.meta[0]["ready_ns"] = picked_ns, time.time_ns()
            done += 1
            yield batch

    def _camera_for(self, native: Size) -> _Camera:
        """The camera of images of ``native`` size, as ``predict --bag`` sets it up: a calibration file always
        through its :class:`~cosemdepth.camera.Undistorter`; camera_info with a distortion through its own (unless
        ``ignore_distortion``), without one its K resized; given intrinsics or hfov resized. The first camera's
        output size is kept for later ones (the model's input size stays)."""
        o = self.options
        if self.info is None and self.info_error is not None:
            raise CosemdepthError(self.info_error)
        cal, lens = o.calibration, o.calibration is not None
        if self.info is not None:
            cal = self.info
            if cal.size == (0, 0):  # camera_info without a size: the images'
                cal = dataclasses.replace(cal, size=tuple(native))
            if cal.size != tuple(native):
                raise CosemdepthError(
                    f"{o.camera_info_topic}: camera_info is for {cal.size[0]}x{cal.size[1]} images but "
                    f"{o.image_topic} has {native[0]}x{native[1]}"
                )
            lens = cal.has_distortion and not o.ignore_distortion
        if cal is not None:
            key: tuple = (tuple(native), lens, lens_key(cal))
            k_native = np.array(cal.k)
        else:
            k_native = parse_intrinsics(o.intrinsics, o.hfov, native)
            key = (tuple(native), False, tuple(float(v) for v in k_native))
        if self._camera is not None and self._camera.key == key:
            return self._camera
        rule = self.size_rule if self.out_size is None else self.out_size
        if lens:
            u = undistorter_for(cal, native, rule, f"the images of {o.image_topic}")
            camera = _Camera(key, u, u.size, u.intrinsics)
        else:
            size = resolve_size(rule, lambda: (native, float(k_native[0]))) or native
            camera = _Camera(key, None, size, scale_intrinsics(k_native, native, size))
        self.out_size = self.out_size or camera.size
        self._camera = camera
        return camera

    def _frame(self, image: _Image, posed: bool, dropped: int) -> FrameBatch:
        o = self.options
        where = f"{o.image_topic} at stamp {format_stamp(image.stamp)}"
        rgb = image_to_rgb(image.msgtype, image.msg, where, o.jpeg_idct)
        native = tuple(rgb.shape[:2])
        camera = self._camera_for(native)
        pose = self.poses.at(image.stamp, int(round(o.max_pose_gap * 1e9))) if posed else None
        intrinsics = camera.intrinsics
        meta: dict[str, Any] = {
            "stamp_ns": image.stamp,
            "frame_id": image.frame_id,
            "source_ns": image.source_ns,
            "received_ns": image.received_ns,
            "dropped_before": dropped,
            "intrinsics": [float(v) for v in intrinsics],  # float32's values (the batch's may be cast to the model's)
        }
        reason = self._break(image, camera.key)
        if pose is None:
            last = self.poses.latest
            why = (
                f"no pose within {o.pose_timeout:g} s of its arrival"
                if not posed
                else f"no pose at its stamp (poses more than --max-pose-gap {o.max_pose_gap:g} s apart)"
            )
            if last is not None:
                why += f"; last pose {(last - image.stamp) / 1e9:+.3f} s from it"
            if self.poses.unresolved():
                why += f"; {self.poses.unresolved()}"
            meta["depth_invalid_reason"] = why
            self.stats.unposed += 1
            self.limited("unposed", f"image at {format_stamp(image.stamp)}: {why}: no depth (status reset)")
        if reason is not None:
            meta["reset_reason"] = reason
            self.stats.resets[reason.split(":")[0]] += 1
            self.limited(reason.split(":")[0], f"reset at {format_stamp(image.stamp)}: {reason}")
        reset = reason is not None or pose is None
        q, t = np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3)
        if not reset:
            prev = self._last
            qs, ts_ = relative_camera_motions(
                np.stack([prev["q"], pose[1]]), np.stack([prev["p"], pose[0]]), self.convention
            )
            q, t = qs[1], ts_[1]
        else:
            self._segment += 1
            self._row = 0
        cam_to_world = None
        if pose is not None:
            cam_to_world = torch.eye(4, dtype=torch.float64)
            cam_to_world[:3, :3] = torch.from_numpy(qmatrix(pose[1]) @ self.convention.T)
            cam_to_world[:3, 3] = torch.from_numpy(np.asarray(pose[0], dtype=np.float64))
        p_, q_ = (None, None) if pose is None else pose
        self._last = {
            "p": p_,
            "q": q_,
            "stamp": image.stamp,
            "writer": image.writer,
            "camera": camera.key,
        }
        index = self.stats.processed
        self.stats.processed += 1
        row = self._row
        self._row += 1
        source_valid = None
        if camera.undistorter is not None:
            rgb_t, valid = camera.undistorter(rgb)
            source_valid = valid[None, None].clone()
        else:
            rgb_t = rgb_to_tensor(rgb, camera.size)
        return FrameBatch(
            rgb=rgb_t[None],
            rot=torch.from_numpy(np.asarray(q, dtype=np.float32))[None],
            trans=torch.from_numpy(np.asarray(t, dtype=np.float32))[None],
            intrinsics=intrinsics[None],
            reset=torch.tensor([reset]),
            trajectory=[f"{o.image_topic}#{self._segment}"],
            frame=torch.tensor([row], dtype=torch.int64),
            index=[index],
            lanes=(0,),
            name=[f"{o.image_topic}@{image.stamp // 1_000_000_000:010d}.{image.stamp % 1_000_000_000:09d}"],
            stamp=[image.stamp / 1e9],
            meta=[meta],
            pose=None if cam_to_world is None else cam_to_world[None],
            depth_ok=torch.tensor([pose is not None]),
            source_valid=source_valid,
        )

    def _break(self, image: _Image, camera: tuple) -> str | None:
        """Why the state starts afresh at ``image`` (None: it goes on from the previous processed frame)."""
        last = self._last
        if last is None:
            return "first frame" if self.stats.processed == 0 else "after a frame that was left out"
        if last["p"] is None:
            return "after a frame without a pose"
        if image.writer != last["writer"]:
            return "image publisher changed: a restarted camera or replay"
        if image.stamp <= last["stamp"]:
            return f"clock jump back: image stamp {format_stamp(image.stamp)} after {format_stamp(last['stamp'])}"
        gap = (image.stamp - last["stamp"]) / 1e9
        if gap > self.options.max_frame_gap:
            return f"gap: {gap:.3f} s since the previous frame (--max-frame-gap {self.options.max_frame_gap:g})"
        if camera != last["camera"]:
            return "new camera: image size or intrinsics changed"
        return None

    # ------------------------------------------------------------------ stopping
    def stop(self) -> None:
        """End :meth:`batches` (from a signal handler or another thread)."""
        self.stopping.set()
        if self.graph.wake is not None:
            self.graph.interrupt()

    def close(self) -> None:
        self.stop()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        self._readers.clear()
        self._pending.clear()
        if self._owns_graph:
            self.graph.close()


register_source("live", LiveSource)


__all__ = [
    "DEFAULT_MAX_FRAME_GAP",
    "DEFAULT_MAX_POSE_GAP",
    "DEFAULT_POSE_TIMEOUT",
    "LiveOptions",
    "LiveSource",
    "LiveStats",
]
