"""SynthAir flights as a drone team has them (``cosemdepth synth --export mp4,ulog,dataflash,tlog,srt``): the
camera's video and the flight controller's logs of the same flight, with exact ground truth.

Per trajectory, under ``DIR/SynthAir/<climate>/flight_export/trajectory_XXXX/``:

* ``video.mp4``: H.264 (PyAV), frame ``k`` at video time ``k / fps`` exactly (the stream's and the codec's time
  base ``1 / fps``), rendered from the mounted camera (``--camera-mount``) at flight time ``S + k / fps``
  (``S`` = ``--time-offset``), for as long as the flight lasts;
* ``flight.ulg`` (PX4: ``vehicle_attitude`` 200 Hz, ``vehicle_odometry`` 100 Hz, ``vehicle_local_position`` 50 Hz,
  ``sensor_gps`` 5 Hz), ``flight.bin`` (ArduPilot DataFlash: ``ATT`` 50 Hz, ``XKF1`` 25 Hz, ``POS`` 10 Hz, ``GPS``
  5 Hz), ``flight.tlog`` (MAVLink 2: ``ATTITUDE`` 50 Hz, ``LOCAL_POSITION_NED`` 20 Hz, ``GLOBAL_POSITION_INT``
  10 Hz, ``SYSTEM_TIME`` and ``HEARTBEAT`` 1 Hz, a ground station's heartbeat): the body's attitude (FRD -> NED)
  and position, each stream at its own rate with its own phase and a little jitter (never aligned to the frames),
  on the clock's grid (microseconds; the tlog's ``time_boot_ms`` milliseconds). Log clock = flight time +
  :data:`BOOT_OFFSET_S`: the video's frame ``k`` is at log time ``k / fps + S + BOOT_OFFSET_S``;
* ``video.SRT``: DJI subtitles (Mavic 3 layout, the 3T's gimbal angles = the camera's attitude), one per frame,
  on the video's clock;
* ``truth.csv``: per video frame, its video and log times, the body's pose and the optical frame's pose (world
  NED, quaternions w, x, y, z), and the Mid-Air frame it equals (-1 if none); ``export.json``: the origins.

The local positions in the logs are NED metres from the flight's start (the estimator's origin, world NED point
``origin_ned``); latitude/longitude come from the NED tangent plane at :data:`GEODETIC_ORIGIN`, placed at that point.
Between the 100 Hz ground-truth samples, the trajectory is the cubic Hermite interpolation of :mod:`.motion` (exact
at the samples, attitudes renormalised): the frames and every log sample are taken from that one curve.
"""

from __future__ import annotations

import csv
import datetime as dt
import io
import json
import math
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..flightlogs.dataflash import GPS_EPOCH_UNIX, GPS_LEAP_SECONDS
from ..flightlogs.dataflash_writer import DataflashWriter
from ..flightlogs.geodetic import ned_to_geodetic
from ..flightlogs.srt_writer import write_srt
from ..flightlogs.tlog_writer import TlogWriter
from ..flightlogs.ulog_writer import PX4_FORMATS, Topic, write_ulog
from ..geometry.attitude import quat_to_euler
from ..geometry.mount import CameraMount, camera_poses, optical_to_camera_frd
from ..optional import require
from ..output_safety.atomic import atomic_path, atomic_write_text
from .motion import hermite
from .trajectory import GT_RATE, Flight, flight_from_poses

#: What ``--export`` writes.
EXPORT_FORMATS = ("mp4", "ulog", "dataflash", "tlog", "srt")
#: Folder of the exports in each climate folder.
EXPORT_DIR = "flight_export"
#: File of each format in a trajectory's export folder.
FILE_NAMES = {
    "mp4": "video.mp4",
    "srt": "video.SRT",
    "ulog": "flight.ulg",
    "dataflash": "flight.bin",
    "tlog": "flight.tlog",
}
#: Seconds from the flight controller's boot to the flight's start (log clock = flight time + this).
BOOT_OFFSET_S = 37.5
#: Unix time (UTC) of the boot: 2026-12-07 10:00:00 UTC.
BOOT_UTC_S = 1_796_637_600
#: WGS84 latitude, longitude (degrees) and ellipsoidal altitude (metres) of every flight's start.
GEODETIC_ORIGIN = (46.5191, 6.5668, 420.0)
#: Sample rates (Hz) of each log's streams.
RATES = {
    "ulog": {"vehicle_attitude": 200.0, "vehicle_odometry": 100.0, "vehicle_local_position": 50.0, "sensor_gps": 5.0},
    "dataflash": {"ATT": 50.0, "XKF1": 25.0, "POS": 10.0, "GPS": 5.0},
    "tlog": {"ATTITUDE": 50.0, "LOCAL_POSITION_NED": 20.0, "GLOBAL_POSITION_INT": 10.0, "SYSTEM_TIME": 1.0},
}
#: Frame rates accepted by ``--fps``.
FPS_RANGE = (1, 240)


def parse_fps(text: str | float | Fraction) -> Fraction:
    """``--fps``: ``25``, ``29.97`` or ``30000/1001`` -> an exact fraction; a ConfigError otherwise."""
    try:
        fps = Fraction(str(text).strip())
    except (ValueError, ZeroDivisionError):
        raise ConfigError(f"--fps must be a frame rate such as 25, 29.97 or 30000/1001, got {text!r}") from None
    if not FPS_RANGE[0] <= fps <= FPS_RANGE[1] or fps.denominator > 100_000:
        raise ConfigError(f"--fps must be between {FPS_RANGE[0]} and {FPS_RANGE[1]} frames per second, got {text!r}")
    return fps


def parse_export(text: str | tuple | list) -> tuple[str, ...]:
    """``--export mp4,ulog,...`` -> the formats in :data:`EXPORT_FORMATS` order; a ConfigError for an unknown one."""
    items = [s.strip().lower() for s in (text.split(",") if isinstance(text, str) else text) if s.strip()]
    unknown = [s for s in items if s not in EXPORT_FORMATS]
    if unknown or not items:
        raise ConfigError(f"--export: unknown format(s) {unknown or [text]}; choose from {','.join(EXPORT_FORMATS)}")
    return tuple(f for f in EXPORT_FORMATS if f in items)


def continuous_quaternions(q: np.ndarray) -> np.ndarray:
    """``[N, 4]`` quaternions with signs flipped so that consecutive ones are on the same side (dot >= 0)."""
    q = np.array(q, dtype=np.float64)
    if len(q) > 1:
        flips = np.cumprod(np.where(np.sum(q[1:] * q[:-1], axis=1) < 0, -1.0, 1.0))
        q[1:] *= flips[:, None]
    return q


def camera_flight(flight: Flight, mount: CameraMount) -> Flight:
    """The mounted camera's flight: its FRD frame's attitude and its position at every 100 Hz sample (velocities
    and rates recomputed); ``flight`` itself when the camera is the body."""
    if mount.is_identity:
        return flight
    q_opt, p = camera_poses(flight.attitude, flight.position, mount.R_body_optical, mount.lever_arm)
    q = continuous_quaternions(optical_to_camera_frd(q_opt))
    return flight_from_poses(flight.mode, q, p, flight.altitude)


@dataclass(frozen=True)
class Truth:
    """The body's continuous trajectory: the cubic Hermite interpolation of a flight's 100 Hz samples."""

    flight: Flight

    @property
    def duration(self) -> float:
        """Flight time of the last sample (seconds)."""
        return (len(self.flight) - 1) / GT_RATE

    def body(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(q [N, 4] body FRD -> NED, p [N, 3] NED)`` at flight times ``tau [N]`` in ``[0, duration]``."""
        idx = np.clip(np.asarray(tau, dtype=np.float64) * GT_RATE, 0.0, len(self.flight) - 1.0)
        q = hermite(continuous_quaternions(self.flight.attitude), idx)
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        return q, hermite(self.flight.position, idx)

    def velocity(self, tau: np.ndarray, h: float = 1e-3) -> np.ndarray:
        """``[N, 3]`` NED m/s (central difference of :meth:`body` over ``2 h`` seconds)."""
        tau = np.asarray(tau, dtype=np.float64)
        _, p1 = self.body(np.minimum(tau + h, self.duration))
        _, p0 = self.body(np.maximum(tau - h, 0.0))
        return (p1 - p0) / (np.minimum(tau + h, self.duration) - np.maximum(tau - h, 0.0))[:, None]


def sample_ticks(rng: np.random.Generator, rate: float, duration: float, tick_s: float) -> np.ndarray:
    """Sample times of a stream at ``rate`` Hz over flight times ``[0, duration]``, as integer ticks of the log
    clock (``tick_s`` seconds; log clock = flight time + BOOT_OFFSET_S): a random phase, a jitter of up to 10 % of
    the period, strictly increasing."""
    period = 1.0 / rate
    n = int(math.floor(duration * rate)) + 1
    t = rng.uniform(0, period) + np.arange(n) * period + rng.uniform(-0.1, 0.1, n) * period
    t = t[(t >= 0) & (t <= duration)]
    ticks = np.round((t + BOOT_OFFSET_S) / tick_s).astype(np.int64)
    ticks = np.unique(ticks)
    lo, hi = math.ceil(BOOT_OFFSET_S / tick_s - 1e-9), math.floor((duration + BOOT_OFFSET_S) / tick_s + 1e-9)
    return ticks[(ticks >= lo) & (ticks <= hi)]


def flight_time(ticks: np.ndarray, tick_s: float) -> np.ndarray:
    """Flight times (seconds) of log-clock ticks."""
    return ticks * tick_s - BOOT_OFFSET_S


@dataclass(frozen=True)
class ExportPlan:
    """What to export for one trajectory: formats, the frame rate, ``--time-offset`` and the mount."""

    formats: tuple[str, ...]
    fps: Fraction
    time_offset: float
    mount: CameraMount

    def frame_times(self, duration: float) -> np.ndarray:
        """Flight times ``S + k / fps`` of the video's frames within ``[0, duration]``."""
        n = int(math.floor((duration - self.time_offset) * self.fps + 1e-9)) + 1
        if n < 2:
            raise ConfigError(
                f"--time-offset {self.time_offset:g} leaves fewer than 2 video frames: the flight lasts "
                f"{duration:g} s (lower --time-offset or raise --frames)"
            )
        k = np.arange(n)
        return self.time_offset + k * float(1 / self.fps)


def _stream_rng(seed: int, number: int, name: str) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, 0xE4F0, number, *name.encode()]))


def export_trajectory(
    folder: Path,
    planned_flight: Flight,
    plan: ExportPlan,
    seed: int,
    number: int,
    render_rgb=None,
    midair_frames: list[int] | None = None,
) -> dict:
    """Write the exports of one trajectory into ``folder`` (files already there are kept: the outputs are
    deterministic). ``render_rgb(q_camera_frd [B, 4], p [B, 3]) -> iterable of [H, W, 3] uint8`` renders the video's
    frames (needed for ``mp4``); ``midair_frames``: the Mid-Air frames rendered (for ``truth.csv``). Returns the
    trajectory's export metadata (also written to ``export.json``)."""
    truth = Truth(planned_flight)
    duration = truth.duration
    frames_tau = plan.frame_times(duration)
    q_b, p_b = truth.body(frames_tau)
    q_opt, p_opt = camera_poses(q_b, p_b, plan.mount.R_body_optical, plan.mount.lever_arm)
    origin = planned_flight.position[0].copy()
    video_t = np.arange(len(frames_tau)) * float(1 / plan.fps)
    meta = {
        "frames": len(frames_tau),
        "fps": str(plan.fps),
        "time_offset_s": plan.time_offset,
        "boot_offset_s": BOOT_OFFSET_S,
        "video_start_log_time_s": plan.time_offset + BOOT_OFFSET_S,
        "origin_ned": [float(v) for v in origin],
        "geodetic_origin": list(GEODETIC_ORIGIN),
        "files": {f: FILE_NAMES[f] for f in plan.formats},
    }
    folder.mkdir(parents=True, exist_ok=True)
    writers = {
        "mp4": lambda p: _write_mp4(p, render_rgb(optical_to_camera_frd(q_opt), p_opt), plan.fps),
        "srt": lambda p: _write_srt(p, video_t, q_opt, p_b, origin, plan.time_offset),
        "ulog": lambda p: _write_ulog(p, truth, origin, _rngs(seed, number, "ulog")),
        "dataflash": lambda p: _write_dataflash(p, truth, origin, _rngs(seed, number, "dataflash")),
        "tlog": lambda p: _write_tlog(p, truth, origin, _rngs(seed, number, "tlog")),
    }
    for fmt in plan.formats:
        path = folder / FILE_NAMES[fmt]
        if not path.is_file():
            writers[fmt](path)
    _write_truth(folder / "truth.csv", video_t, frames_tau, q_b, p_b, q_opt, p_opt, midair_frames or [])
    atomic_write_text(folder / "export.json", json.dumps(meta, indent=2) + "\n")
    return meta


def _rngs(seed: int, number: int, fmt: str) -> dict[str, np.random.Generator]:
    return {name: _stream_rng(seed, number, f"{fmt}/{name}") for name in [*RATES[fmt], "latency"]}


def _geodetic(p: np.ndarray, origin: np.ndarray):
    return ned_to_geodetic(p - origin, GEODETIC_ORIGIN)


def _euler_deg(q: np.ndarray) -> np.ndarray:
    roll, pitch, yaw = quat_to_euler(q)
    return np.degrees(np.stack([roll, pitch, yaw], 1))


def _write_ulog(path: Path, truth: Truth, origin: np.ndarray, rng: dict) -> None:
    tick = 1e-6
    topics = []
    for name, rate in RATES["ulog"].items():
        ticks = sample_ticks(rng[name], rate, truth.duration, tick)
        tau = flight_time(ticks, tick)
        q, p = truth.body(tau)
        latency = rng["latency"].integers(150, 900, len(ticks))  # publication after the sample, microseconds
        data: dict = {"timestamp": ticks + latency, "timestamp_sample": ticks}
        if name == "vehicle_attitude":
            data["q"] = q
        elif name == "vehicle_odometry":
            frame_ned = np.ones(len(ticks))  # pose_frame / velocity_frame 1: NED
            data.update(position=p - origin, q=q, velocity=truth.velocity(tau), pose_frame=frame_ned)
            data["velocity_frame"] = frame_ned
        elif name == "vehicle_local_position":
            v = truth.velocity(tau)
            data.update(x=(p - origin)[:, 0], y=(p - origin)[:, 1], z=(p - origin)[:, 2])
            data.update(vx=v[:, 0], vy=v[:, 1], vz=v[:, 2], heading=np.radians(_euler_deg(q)[:, 2]))
            data.update(
                ref_lat=np.full(len(ticks), GEODETIC_ORIGIN[0]), ref_lon=np.full(len(ticks), GEODETIC_ORIGIN[1])
            )
            data.update(ref_alt=np.full(len(ticks), GEODETIC_ORIGIN[2]), ref_timestamp=np.full(len(ticks), ticks[0]))
            for flag in ("xy_valid", "z_valid", "v_xy_valid", "v_z_valid", "xy_global", "z_global"):
                data[flag] = np.ones(len(ticks))
        else:  # sensor_gps
            lat, lon, alt = _geodetic(p, origin)
            data.update(time_utc_usec=ticks + BOOT_UTC_S * 1_000_000, lat=np.round(lat * 1e7), lon=np.round(lon * 1e7))
            data.update(
                alt=np.round(alt * 1e3), fix_type=np.full(len(ticks), 3), satellites_used=np.full(len(ticks), 14)
            )
        topics.append(Topic(name, PX4_FORMATS[name], data))
    write_ulog(
        path, topics, start_us=int(round(BOOT_OFFSET_S * 1e6)) - 1000, info={"sys_name": "PX4", "ver_hw": "SYNTHAIR"}
    )


def _write_dataflash(path: Path, truth: Truth, origin: np.ndarray, rng: dict) -> None:
    tick = 1e-6
    w = DataflashWriter()
    for name, rate in RATES["dataflash"].items():
        ticks = sample_ticks(rng[name], rate, truth.duration, tick)
        tau = flight_time(ticks, tick)
        q, p = truth.body(tau)
        rpy = _euler_deg(q)
        rpy[:, 2] %= 360.0
        local = p - origin
        v = truth.velocity(tau)
        lat, lon, alt = _geodetic(p, origin)
        for i, us in enumerate(ticks):
            r, pi, y = (float(a) for a in rpy[i])
            if name == "ATT":
                w.add("ATT", us, DesRoll=r, Roll=r, DesPitch=pi, Pitch=pi, DesYaw=y, Yaw=y % 360.0, AEKF=3)
            elif name == "XKF1":
                n, e, d = (float(a) for a in local[i])
                w.add(
                    "XKF1",
                    us,
                    C=0,
                    Roll=r,
                    Pitch=pi,
                    Yaw=y % 360.0,
                    VN=v[i, 0],
                    VE=v[i, 1],
                    VD=v[i, 2],
                    PN=n,
                    PE=e,
                    PD=d,
                )
            elif name == "POS":
                rel = float(-local[i, 2])
                w.add(
                    "POS", us, Lat=float(lat[i]), Lng=float(lon[i]), Alt=float(alt[i]), RelHomeAlt=rel, RelOriginAlt=rel
                )
            else:  # GPS: GPS week and milliseconds of the week
                gps_ms = round((BOOT_UTC_S + us * 1e-6 + GPS_LEAP_SECONDS - GPS_EPOCH_UNIX) * 1000)
                week, ms = divmod(gps_ms, 604_800_000)
                w.add(
                    "GPS",
                    us,
                    Status=3,
                    GMS=ms,
                    GWk=week,
                    NSats=14,
                    HDop=0.8,
                    Lat=float(lat[i]),
                    Lng=float(lon[i]),
                    Alt=float(alt[i]),
                )
    w.write(path)


def _write_tlog(path: Path, truth: Truth, origin: np.ndarray, rng: dict) -> None:
    tick = 1e-3
    w = TlogWriter()
    boot_us = BOOT_UTC_S * 1_000_000
    last_ms = int(math.floor((truth.duration + BOOT_OFFSET_S) * 1000))
    first_ms = int(math.ceil(BOOT_OFFSET_S * 1000))
    for ms in range(first_ms, last_ms + 1, 1000):  # heartbeats: the vehicle's and a ground station's
        w.add(
            boot_us + ms * 1000 + 20_000,
            "HEARTBEAT",
            type=2,
            autopilot=3,
            base_mode=81,
            system_status=4,
            mavlink_version=3,
        )
        w.add(
            boot_us + ms * 1000 + 500_000,
            "HEARTBEAT",
            system=255,
            component=190,
            type=6,
            autopilot=8,
            mavlink_version=3,
        )
    for name, rate in RATES["tlog"].items():
        ticks = sample_ticks(rng[name], rate, truth.duration, tick)
        tau = flight_time(ticks, tick)
        q, p = truth.body(tau)
        roll, pitch, yaw = quat_to_euler(q)
        local = p - origin
        v = truth.velocity(tau)
        lat, lon, alt = _geodetic(p, origin)
        latency = rng["latency"].integers(15_000, 25_000, len(ticks))  # the link's delay, microseconds
        for i, ms in enumerate(ticks):
            ms = int(ms)
            received = boot_us + ms * 1000 + int(latency[i])
            if name == "ATTITUDE":
                w.add(received, name, time_boot_ms=ms, roll=roll[i], pitch=pitch[i], yaw=yaw[i])
            elif name == "LOCAL_POSITION_NED":
                x, y, z = (float(a) for a in local[i])
                w.add(received, name, time_boot_ms=ms, x=x, y=y, z=z, vx=v[i, 0], vy=v[i, 1], vz=v[i, 2])
            elif name == "GLOBAL_POSITION_INT":
                w.add(
                    received,
                    name,
                    time_boot_ms=ms,
                    lat=int(round(lat[i] * 1e7)),
                    lon=int(round(lon[i] * 1e7)),
                    alt=int(round(alt[i] * 1e3)),
                    relative_alt=int(round(-local[i, 2] * 1e3)),
                    vx=int(round(v[i, 0] * 100)),
                    vy=int(round(v[i, 1] * 100)),
                    vz=int(round(v[i, 2] * 100)),
                    hdg=int(round(math.degrees(yaw[i]) % 360 * 100)) % 36000,
                )
            else:  # SYSTEM_TIME
                w.add(received, name, time_unix_usec=boot_us + ms * 1000, time_boot_ms=ms)
    w.write(path)


def _write_srt(path: Path, video_t, q_opt, p_body, origin, time_offset: float) -> None:
    lat, lon, alt = _geodetic(p_body, origin)
    rel = -(p_body - origin)[:, 2]
    rpy = _euler_deg(optical_to_camera_frd(q_opt))  # the camera's attitude: DJI's gimbal angles
    start = dt.datetime(1970, 1, 1) + dt.timedelta(seconds=BOOT_UTC_S + BOOT_OFFSET_S + time_offset)  # UTC, naive
    write_srt(path, video_t, lat, lon, rel, alt, rpy[:, ::-1].copy(), start=start)


def _write_mp4(path: Path, frames, fps: Fraction) -> None:
    av = require("av", "writing the video (--export mp4)")
    codec = "libx264" if "libx264" in av.codecs_available else "h264"
    time_base = Fraction(fps.denominator, fps.numerator)
    with atomic_path(path) as tmp:
        with av.open(str(tmp), mode="w", format="mp4") as container:
            stream = None
            for k, rgb in enumerate(frames):
                if stream is None:
                    h, w = rgb.shape[:2]
                    stream = container.add_stream(codec, rate=fps)
                    stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
                    stream.time_base = time_base
                    stream.codec_context.time_base = time_base
                    stream.options = {"crf": "16", "threads": "1"}
                frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
                frame.pts, frame.time_base = k, time_base
                container.mux(stream.encode(frame))
            if stream is not None:
                container.mux(stream.encode(None))


#: Columns of ``truth.csv``.
TRUTH_COLUMNS = (
    "frame",
    "video_time_s",
    "log_time_s",
    "body_qw",
    "body_qx",
    "body_qy",
    "body_qz",
    "body_x",
    "body_y",
    "body_z",
    "camera_qw",
    "camera_qx",
    "camera_qy",
    "camera_qz",
    "camera_x",
    "camera_y",
    "camera_z",
    "midair_frame",
)


def _write_truth(path, video_t, tau, q_b, p_b, q_opt, p_opt, midair_frames: list[int]) -> None:
    rendered = {int(k): k for k in midair_frames}
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")
    out.writerow(TRUTH_COLUMNS)
    for k in range(len(tau)):
        gt = tau[k] * GT_RATE
        mid = int(round(gt / 4))
        same = abs(gt - 4 * mid) < 1e-6 and mid in rendered
        row = [k, repr(float(video_t[k])), repr(float(tau[k] + BOOT_OFFSET_S))]
        row += [repr(float(v)) for v in (*q_b[k], *p_b[k], *q_opt[k], *p_opt[k])]
        out.writerow(row + [mid if same else -1])
    atomic_write_text(path, buf.getvalue())


__all__ = [
    "BOOT_OFFSET_S",
    "BOOT_UTC_S",
    "EXPORT_DIR",
    "EXPORT_FORMATS",
    "ExportPlan",
    "FILE_NAMES",
    "FPS_RANGE",
    "GEODETIC_ORIGIN",
    "RATES",
    "TRUTH_COLUMNS",
    "Truth",
    "camera_flight",
    "continuous_quaternions",
    "export_trajectory",
    "flight_time",
    "parse_export",
    "parse_fps",
    "sample_ticks",
]
