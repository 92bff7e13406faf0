"""A video file and the flight controller's log as a source: the frames decoded as a stream, each frame's camera pose
from the log at the frame's time.

* **Frames**: :func:`cosemdepth.data.video.open_video` (presentation times kept, rotation metadata applied), every
  ``frame_skip``-th frame; outputs are named by the frame's index in decoding order (``name``
  ``"<video>#000042"``); each frame's ``meta`` holds ``pts_s`` and the ``log_time_s`` it was matched to.
* **Clock**: a frame with presentation time ``pts`` is at log time ``offset + (pts - pts_first)``. ``time_offset``
  is that ``offset`` in seconds (the log time of the video's first frame), or ``"auto"``:
  :func:`cosemdepth.flightlogs.timesync.estimate_time_offset` (a DJI subtitle file is the video's own clock; other
  logs are matched by the camera's rotation).
* **Poses**: :func:`cosemdepth.flightlogs.read_log` gives the body's attitude and position,
  :func:`cosemdepth.geometry.mount.camera_poses` the optical frame's (the mount, the lever arm, a logged gimbal's
  angles instead of the mount's rotation); the motions between kept frames in the model's convention
  (:func:`cosemdepth.data.poses.relative_camera_motions` in optical axes).
* **Frames without a usable motion** are still streamed (their labels are estimated) with ``depth_ok`` False and the
  reason in ``meta["depth_invalid_reason"]``: frames outside the log's span or in a gap of it (these are also resets:
  the motion breaks there; counted in :attr:`frames_outside_log` and :meth:`report`), and every frame of a log without
  positions or without attitude. A video none of whose frames falls inside the log is an error. Positions coarser
  than an estimator's (GPS latitude/longitude) set :attr:`min_baseline_m` to :data:`BASELINE_STEPS` times their
  resolution: the baseline policy never estimates depth from a shorter baseline, and under any policy no frame whose
  baseline from its reference is shorter has valid depth (:func:`cosemdepth.streaming.pipeline.no_depth_below_floor`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import torch

from ...data.flight import parse_intrinsics, scale_intrinsics
from ...data.frames import resolve_size, rgb_to_tensor
from ...data.poses import relative_camera_motions
from ...data.quaternion import qmatrix
from ...data.undistorted import undistorter_for
from ...data.video import is_video, open_video
from ...errors import ConfigError, DatasetError
from ...flightlogs import LOG_FORMATS, read_log
from ...flightlogs.timesync import estimate_time_offset
from ...geometry.mount import CameraMount, camera_poses, parse_mount
from ...output_safety.outdir import Input
from ..frames import FrameBatch
from ..registry import register_source

#: ``time_offset`` value that estimates the offset (the default for a video with a log).
AUTO = "auto"
#: The shortest baseline depth is estimated (or carried) on, in steps of the positions' resolution: the difference
#: of two positions each rounded to a step is off by up to a step along every axis, so a baseline of one step may be
#: wrong by all of itself; at three its error stays within about a third.
BASELINE_STEPS = 3.0


@dataclass(frozen=True)
class VideoLogOptions:
    """What a video + flight-log source reads (checked at construction; a ConfigError names the option).

    Attributes:
        video: the video file (mp4, mov, mkv...).
        log: the flight log (PX4 .ulg, ArduPilot .bin, MAVLink .tlog, DJI .SRT).
        log_format: one of :data:`~cosemdepth.flightlogs.LOG_FORMATS`, None: from the content.
        time_offset: seconds (the log time of the video's first frame) or ``"auto"``.
        camera_mount: ``--camera-mount`` spec (:func:`cosemdepth.geometry.mount.parse_mount`).
        lever_arm: ``(x, y, z)`` metres in body FRD (None: the mount spec's, else zero).
        intrinsics: ``(fx, fy, cx, cy)`` in pixels of the displayed video frames, or
        hfov: the horizontal field of view in degrees, or
        calibration: the camera's calibration file (:func:`cosemdepth.camera.load_calibration`: the frames are
            undistorted to a pinhole, the pixels without a source invalid); exactly one of the three.
        intrinsics_convention: ``"model"`` (pixel centres at +0.5) or ``"opencv"``.
        frame_skip: keep every k-th frame.
        max_pose_gap: interpolate the log only across gaps of at most this many seconds (None: the log's default,
            :meth:`cosemdepth.flightlogs.Series.default_max_gap`).
        trajectory: the trajectory's name (output folder), default the video's file stem.
    """

    video: Path
    log: Path
    log_format: str | None = None
    time_offset: float | str = AUTO
    camera_mount: str = "forward"
    lever_arm: tuple[float, float, float] | None = None
    intrinsics: tuple[float, float, float, float] | None = None
    hfov: float | None = None
    calibration: Path | None = None
    intrinsics_convention: str = "model"
    frame_skip: int = 1
    max_pose_gap: float | None = None
    trajectory: str | None = None

    #: the source table's name of this input
    source = "video"

    def __post_init__(self) -> None:
        object.__setattr__(self, "video", Path(self.video))
        object.__setattr__(self, "log", Path(self.log))
        if not is_video(self.video):
            raise ConfigError(f"--images {self.video}: not a video file name (.mp4, .mov, .mkv, ...)")
        if self.log_format is not None and self.log_format not in LOG_FORMATS:
            raise ConfigError(f"--log-format must be one of {', '.join(LOG_FORMATS)}, got {self.log_format!r}")
        offset = self.time_offset
        if isinstance(offset, str) and offset != AUTO:
            try:
                offset = float(offset)
            except ValueError:
                raise ConfigError(f"--time-offset must be seconds or 'auto', got {self.time_offset!r}") from None
        if not isinstance(offset, str) and not (isinstance(offset, (int, float)) and math.isfinite(offset)):
            raise ConfigError(f"--time-offset must be a finite number of seconds or 'auto', got {offset!r}")
        object.__setattr__(self, "time_offset", offset if isinstance(offset, str) else float(offset))
        if self.calibration is not None:
            object.__setattr__(self, "calibration", Path(self.calibration))
        if sum(x is not None for x in (self.intrinsics, self.hfov, self.calibration)) != 1:
            raise ConfigError(
                "a video needs exactly one of --intrinsics FX FY CX CY, --hfov DEG and --calibration FILE"
            )
        if self.hfov is not None and not 0 < float(self.hfov) < 180:
            raise ConfigError(f"--hfov must be in (0, 180) degrees, got {self.hfov}")
        if not isinstance(self.frame_skip, int) or self.frame_skip < 1:
            raise ConfigError(f"--frame-skip must be a positive integer, got {self.frame_skip!r}")
        if self.max_pose_gap is not None and not float(self.max_pose_gap) >= 0:
            raise ConfigError(f"--max-pose-gap must be >= 0 seconds, got {self.max_pose_gap}")
        self.mount()  # the spec and the lever arm checked now

    def inputs(self) -> list[Input]:
        """The paths it reads (the output policy of :mod:`cosemdepth.output_safety.outdir`)."""
        given = [Input("--images", self.video), Input("--log", self.log)]
        return given + ([] if self.calibration is None else [Input("--calibration", self.calibration)])

    def settings(self) -> dict[str, Any]:
        """``predictions.json``'s ``run`` entries about the input that every flight has (the log's: the source's
        :meth:`VideoLogSource.run_entries`)."""
        return {
            "intrinsics_given": None if self.intrinsics is None else [float(v) for v in self.intrinsics],
            "hfov_deg": self.hfov,
            "calibration": None if self.calibration is None else str(self.calibration),
            "convention": "opencv",
            "frame_skip": self.frame_skip,
            "max_pose_gap": self.max_pose_gap,
        }

    def mount(self) -> CameraMount:
        """The camera mount of ``camera_mount`` and ``lever_arm``."""
        m = parse_mount(self.camera_mount)
        if self.lever_arm is None:
            return m
        if np.any(m.lever_arm):
            raise ConfigError(
                f"--lever-arm: the mount {self.camera_mount!r} already has a lever arm; give it in one place"
            )
        lever = np.asarray(self.lever_arm, dtype=np.float64).reshape(-1)
        if lever.shape != (3,) or not np.all(np.isfinite(lever)) or np.any(np.abs(lever) > 1000):
            raise ConfigError(f"--lever-arm must be 3 finite metres (at most 1000), got {self.lever_arm}")
        text = f"{m.spec}@{','.join(f'{v:g}' for v in lever)}"
        return CameraMount(m.R_body_optical, lever, text)


class VideoLogSource:
    """The frames of a video with their poses from a flight log (see the module docstring); built by
    :meth:`from_options` (``SOURCES["video"]``). Opening reads the video's header and first frame, the log, and,
    for ``time_offset="auto"``, estimates the offset (decoding the video once, small and gray)."""

    name = "video"

    def __init__(self, options: VideoLogOptions, size=None, *, progress=None) -> None:
        self.options = options
        self.video = open_video(options.video)
        self.log = read_log(options.log, options.log_format, require_attitude=False)
        self.mount_ = options.mount()
        native = self.video.size
        self.undistorter = None
        if options.calibration is not None:  # undistorted to a pinhole at the size the size rule asks for
            self.undistorter = undistorter_for(options.calibration, native, size, "the video's frames")
            cal = self.undistorter.calibration
            self._k_native = torch.tensor([cal.fx, cal.fy, cal.cx, cal.cy], dtype=torch.float32)
            self.size = tuple(self.undistorter.size)
            self.intrinsics = self.undistorter.intrinsics.clone()
        else:
            k = parse_intrinsics(options.intrinsics, options.hfov, native, options.intrinsics_convention)
            self._k_native = k
            self.size = resolve_size(size, lambda: (native, float(k[0]))) or native
            self.intrinsics = scale_intrinsics(k, native, self.size)
        if options.time_offset == AUTO:
            est = estimate_time_offset(
                self.video, self.log, self.mount_, focal_px=float(self._k_native[0]), progress=progress
            )
            self.time_offset, self.confidence, self.offset_details = est.offset_s, est.confidence, dict(est.details)
        else:
            self.time_offset, self.confidence = float(options.time_offset), None
            self.offset_details = {"method": "given (--time-offset)"}
        self._check_coverage()
        self.frames_outside_log = 0
        self.frames_streamed = 0

    @classmethod
    def from_options(cls, options: VideoLogOptions, size=None) -> "VideoLogSource":
        """The source of ``options`` at ``size`` (an int, ``(H, W)``, a :class:`~cosemdepth.data.frames.FocalSize`
        or None: the video's displayed size)."""
        return cls(options, size)

    # ------------------------------------------------------------------ what it is
    @property
    def trajectory(self) -> str:
        return self.options.trajectory or self.options.video.stem

    @property
    def min_baseline_m(self) -> float:
        """The shortest baseline the log's positions measure well enough: :data:`BASELINE_STEPS` times their
        resolution (0 for an estimator's positions)."""
        return BASELINE_STEPS * float(self.log.position_resolution_m)

    def run_entries(self) -> dict[str, Any]:
        """``predictions.json``'s ``run`` entries of the log and the clock: ``time_offset_s`` (the offset used,
        given or estimated), ``time_offset_confidence`` (None when given), ``time_offset_method``, the log, its
        format, the camera mount."""
        return {
            "log": str(self.options.log),
            "log_format": self.log.format,
            "time_offset_s": self.time_offset,
            "time_offset_confidence": self.confidence,
            "time_offset_method": self.offset_details.get("method"),
            "camera_mount": self.mount_.spec,
            "lever_arm_m": [float(v) for v in self.mount_.lever_arm],
        }

    def log_time(self, pts_s: float) -> float:
        """The log time of a frame with presentation time ``pts_s``."""
        return self.time_offset + (float(pts_s) - self.video.start_s)

    def depth_unavailable(self) -> str | None:
        """Why no frame of this log can have depth (None: frames inside the log can)."""
        if self.log.attitude is None:
            return "the log has no attitude (positions only): the camera's rotation between frames is unknown"
        if self.log.position is None:
            return "the log has no positions (attitude only): the camera's translation between frames is unknown"
        return None

    def frame_size(self) -> tuple[int, int]:
        return tuple(self.size)

    def total_frames(self, max_frames: int | None = None) -> int | None:
        """Frames :meth:`batches` yields (from the container's count; None when it has none)."""
        n = self.video.count_hint
        if n is None:
            return None
        n = -(-n // self.options.frame_skip)
        return n if max_frames is None else min(n, max_frames)

    def describe(self) -> dict[str, Any]:
        v = self.video
        return {
            "name": self.trajectory,
            "root": str(self.options.video),
            "video": {
                "path": str(v.path),
                "size": list(v.size),
                "rotation_deg": v.rotation,
                "codec": v.codec,
                "frames": v.count_hint,
                "duration_s": v.duration_s,
                "first_pts_s": v.start_s,
                "creation_time_utc": v.creation_time_utc,
            },
            "log": {
                "path": str(self.log.path),
                "format": self.log.format,
                "used": dict(self.log.used),
                "position_resolution_m": float(self.log.position_resolution_m),
                "utc_offset_s": self.log.utc_offset_s,
            },
            "camera_mount": self.mount_.metadata(),
            "time_offset_s": self.time_offset,
            "time_offset_confidence": self.confidence,
            "time_offset": self.offset_details,
            "depth_unavailable": self.depth_unavailable(),
            "calibration": None if self.undistorter is None else self.undistorter.info(),
        }

    def calibration_note(self) -> str | None:
        """What the undistortion says about the calibration it was given (e.g. scaled to the frames' size)."""
        if self.undistorter is None:
            return None
        return (self.undistorter.info().get("calibration") or {}).get("note")

    # ------------------------------------------------------------------ poses
    def _spans(self) -> list[tuple[float, float]]:
        series = [s for s in (self.log.attitude, self.log.position) if s is not None]
        return [s.span for s in series]

    def _check_coverage(self) -> None:
        """A video none of whose frames can fall inside the log is an error before anything is streamed."""
        spans = self._spans()
        lo, hi = max(s[0] for s in spans), min(s[1] for s in spans)
        start = self.log_time(self.video.start_s)
        dur = self.video.duration_s
        end = start + dur if dur is not None else math.inf
        if hi < lo or end < lo or start > hi:
            raise DatasetError(
                f"{self.log.path}: the log ({lo:.3f} .. {hi:.3f} s) does not cover the video {self.options.video} "
                f"(log time {start:.3f} .. {end:.3f} s with time offset {self.time_offset:.3f} s)"
            )

    def _pose(self, t: float) -> tuple[np.ndarray | None, np.ndarray | None, str | None]:
        """The optical frame's pose (``q [4]`` optical -> NED, ``p [3]`` NED) at log time ``t``, or a reason why
        there is none; a log without attitude gives ``(None, p, None)`` inside its positions' span (the body's
        position: without the attitude the lever arm cannot be turned)."""
        gap = self.options.max_pose_gap
        tt = np.array([t])
        att, pos = self.log.attitude, self.log.position
        if att is None:
            if pos is None:
                return None, None, "outside"
            p, okp = pos.interpolate(tt, gap)
            return (None, p[0], None) if okp[0] else (None, None, "outside")
        q, ok = att.interpolate(tt, gap, rotation=True)
        if not ok[0]:
            return None, None, "outside"
        p = np.zeros((1, 3))
        if pos is not None:
            p, okp = pos.interpolate(tt, gap)
            if not okp[0]:
                return None, None, "outside"
        gimbal = None
        if self.log.gimbal is not None:
            gimbal, okg = self.log.gimbal.interpolate(tt, gap, rotation=True)
            if not okg[0]:
                gimbal = None  # no gimbal sample near this time: the mount's rotation
        q_opt, p_opt = camera_poses(q, p, self.mount_.R_body_optical, self.mount_.lever_arm, gimbal)
        return q_opt[0], p_opt[0], None

    def _outside_reason(self, t: float) -> str:
        spans = self._spans()
        lo, hi = max(s[0] for s in spans), min(s[1] for s in spans)
        if t < lo or t > hi:
            return f"outside the log (log time {t:.3f} s; the log covers {lo:.3f} .. {hi:.3f} s)"
        return f"in a gap of the log (log time {t:.3f} s)"

    # ------------------------------------------------------------------ frames
    def batches(self, *, lanes: int = 1, max_frames: int | None = None, num_workers: int = 0) -> Iterator[FrameBatch]:
        """One frame per batch, in decoding order (one video is one trajectory: ``lanes`` beyond 1 change nothing;
        decoding is sequential, ``num_workers`` is not used)."""
        if max_frames is not None and (not isinstance(max_frames, int) or max_frames < 1):
            raise ConfigError(f"max_frames must be a positive integer, got {max_frames!r}")
        no_depth = self.depth_unavailable()
        prev = None  # (q, p) of the previous streamed frame with a pose
        row = 0
        covered = 0
        self.frames_outside_log = 0
        for index, pts, image in self.video.frames(self.options.frame_skip):
            if max_frames is not None and row >= max_frames:
                break
            t = self.log_time(pts)
            q, p, why = self._pose(t)
            meta: dict[str, Any] = {"pts_s": float(pts), "log_time_s": float(t)}
            depth_ok = True
            reset = prev is None
            if why is not None:
                self.frames_outside_log += 1
                meta["depth_invalid_reason"] = self._outside_reason(t)
                depth_ok, reset, prev = False, True, None
                rot, trans = np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3)
            else:
                covered += 1
                if prev is None or q is None:  # q None: a log without attitude (no motion, no depth)
                    rot, trans = np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3)
                else:
                    qs, ts = relative_camera_motions(np.stack([prev[0], q]), np.stack([prev[1], p]), "opencv")
                    rot, trans = qs[1], ts[1]
                if self.log.position is None:
                    trans = np.zeros(3)
                prev = None if q is None else (q, p)
                if no_depth is not None:
                    depth_ok = False
                    meta["depth_invalid_reason"] = no_depth
            pose = None
            if q is not None:
                pose = torch.eye(4, dtype=torch.float64)
                pose[:3, :3] = torch.from_numpy(qmatrix(q))
                pose[:3, 3] = torch.from_numpy(np.asarray(p, dtype=np.float64))
            row += 1
            self.frames_streamed = row
            source_valid = None
            if self.undistorter is None:
                rgb = rgb_to_tensor(image, self.size)
            else:
                rgb, valid = self.undistorter(image)
                source_valid = valid[None, None].clone()
            yield FrameBatch(
                rgb=rgb[None],
                rot=torch.tensor(rot, dtype=torch.float32)[None],
                trans=torch.tensor(trans, dtype=torch.float32)[None],
                intrinsics=self.intrinsics[None].clone(),
                reset=torch.tensor([reset]),
                trajectory=[self.trajectory],
                frame=torch.tensor([row - 1], dtype=torch.int64),
                index=[index],
                lanes=(0,),
                name=[f"{self.options.video.name}#{index:06d}"],
                stamp=[float(t)],
                meta=[meta],
                pose=None if pose is None else pose[None].to(torch.float32),
                depth_ok=torch.tensor([depth_ok]),
                source_valid=source_valid,
            )
        if covered == 0 and row > 0:
            raise DatasetError(
                f"{self.log.path}: none of the {row} frames of {self.options.video} falls inside the log "
                f"(time offset {self.time_offset:.3f} s); check --time-offset"
            )

    def report(self) -> str:
        """``"; video: 251 frames, clock offset 49.875 s (estimated from the camera's rotation, confidence 0.81)"``
        (and the frames outside the log, and why there is no depth where there is none)."""
        if self.confidence is None:
            how = "given"
        elif self.log.format == "srt":
            how = "the DJI subtitles are on the video's clock"
        else:
            how = f"estimated from the camera's rotation, confidence {self.confidence:.2f}"
        text = f"; video: {self.frames_streamed} frames, clock offset {self.time_offset:.3f} s ({how})"
        if self.frames_outside_log:
            text += f"; {self.frames_outside_log} frames outside the log (resets without depth)"
        if self.depth_unavailable():
            text += f"; no depth: {self.depth_unavailable()}"
        elif self.min_baseline_m > 0:
            text += (
                f"; positions to {self.log.position_resolution_m:.3g} m: no depth on a baseline under "
                f"{self.min_baseline_m:.3g} m"
            )
        return text

    def close(self) -> None:
        """Nothing stays open between batches (each pass opens the file anew)."""


register_source("video", VideoLogSource)

__all__ = ["AUTO", "VideoLogOptions", "VideoLogSource"]
