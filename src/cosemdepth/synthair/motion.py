"""Motion profiles of SynthAir flights (``cosemdepth synth --motion SPEC``): a time warp of the generated flight.

A profile is a list of segments over the 25 Hz camera frames, in order; a segment of ``N`` frames governs the
``N`` frame intervals from its first frame ``n0`` (the sum of the previous segments) to frame ``n0 + N``::

    fly:N          the normal flight (speed multiplier 1)
    fly*X:N        the flight at X times its speed (0 < X <= MAX_SPEED)
    hover:N        position and attitude held exactly (frames n0 ... n0 + N are identical)
    yaw:N[@DEG]    position held exactly; the drone turns in place about the world vertical by DEG degrees
                   (default 90; positive turns right, clockwise seen from above) at a constant rate
    ramp*A-B:N     the speed multiplier goes linearly from A to B (A, B >= 0) over the N frames

The flight is sampled at a warped progress ``tau(t) = integral of the speed multiplier``: the smooth base flight
(:func:`.trajectory.make_flight`, long enough to reach the last ``tau``) is read at ``tau(t)`` for every 100 Hz
ground-truth time ``t``, so a constant multiplier X gives the base flight's poses at X times the frame times,
hover and yaw hold ``tau``. A yaw turns the rest of the path with the drone: after ``yaw:N@DEG`` the drone flies on
in the direction it now faces (the base path, rotated by DEG about the vertical through the point where it
turned), and the height above the surface and the clearance of the base flight are computed over that turned path
(:func:`make_flight`'s ``ground_track``). Between the base flight's 100 Hz samples, positions, attitudes and
heights are interpolated with cubic Hermite splines (Catmull-Rom tangents; exact at the samples, attitudes
renormalised); velocities, accelerations and angular velocities are recomputed on the warped timeline.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from ..data.midair.splits import GT_PER_FRAME as SAMPLES_PER_FRAME  # ground-truth samples (100 Hz) per frame (25 Hz)
from ..data.quaternion import qmul
from ..errors import ConfigError
from .trajectory import Flight, flight_from_poses

#: Largest speed multiplier of ``fly*X`` and ``ramp*A-B`` (the base flights fly at 4-13 m/s).
MAX_SPEED = 10.0
#: Default turn of ``yaw:N`` (degrees).
DEFAULT_YAW = 90.0
#: Fastest turn of ``yaw:N@DEG`` (degrees per camera frame, i.e. 2250 degrees/s).
MAX_YAW_PER_FRAME = 90.0

GRAMMAR = "fly:N, fly*X:N, hover:N, yaw:N, yaw:N@DEG or ramp*A-B:N (N frames, X > 0, A, B >= 0)"

_NUM = r"(?:\d+(?:\.\d*)?|\.\d+)"
_PATTERNS = {
    "fly": re.compile(rf"fly(?:\*(?P<x>{_NUM}))?:(?P<n>\d+)"),
    "hover": re.compile(r"hover:(?P<n>\d+)"),
    "yaw": re.compile(rf"yaw:(?P<n>\d+)(?:@(?P<deg>[+-]?{_NUM}))?"),
    "ramp": re.compile(rf"ramp\*(?P<a>{_NUM})-(?P<b>{_NUM}):(?P<n>\d+)"),
}


def _fmt(x: float) -> str:
    return f"{x:g}" if abs(x) < 1e6 else repr(x)


@dataclass(frozen=True)
class Segment:
    """One segment: ``frames`` camera frame intervals; the speed multiplier goes linearly from ``speed[0]`` to
    ``speed[1]`` (constant for ``fly``, 0 for ``hover`` and ``yaw``); ``degrees``: a yaw's total turn."""

    kind: str
    frames: int
    speed: tuple[float, float] = (1.0, 1.0)
    degrees: float = 0.0

    @property
    def text(self) -> str:
        """The segment in the spec's grammar (canonical form)."""
        if self.kind == "fly":
            x = self.speed[0]
            return f"fly:{self.frames}" if x == 1.0 else f"fly*{_fmt(x)}:{self.frames}"
        if self.kind == "hover":
            return f"hover:{self.frames}"
        if self.kind == "yaw":
            return f"yaw:{self.frames}@{_fmt(self.degrees)}"
        return f"ramp*{_fmt(self.speed[0])}-{_fmt(self.speed[1])}:{self.frames}"


@dataclass(frozen=True)
class MotionProfile:
    """A flight's timeline warp: its segments in order (what ``--motion`` parses into)."""

    segments: tuple[Segment, ...]

    @property
    def frames(self) -> int:
        """Camera frames of the flight: the sum of the segments' frames."""
        return sum(s.frames for s in self.segments)

    @property
    def spec(self) -> str:
        return ",".join(s.text for s in self.segments)

    def metadata(self) -> dict:
        """What ``synthair.json`` records: the canonical spec and each segment's frame range ``[n0, n0 + N]``."""
        out, n0 = [], 0
        for s in self.segments:
            out.append({"segment": s.text, "frames": [n0, n0 + s.frames]})
            n0 += s.frames
        return {"spec": self.spec, "segments": out}


def _bad(part: str, spec: str, why: str = "") -> ConfigError:
    detail = f": {why}" if why else f"; expected {GRAMMAR}"
    return ConfigError(f"--motion: bad segment {part!r} in {spec!r}{detail}")


def _parse_segment(part: str, spec: str) -> Segment:
    for kind, pattern in _PATTERNS.items():
        m = pattern.fullmatch(part)
        if m is None:
            continue
        n = int(m["n"])
        if n < 1:
            raise _bad(part, spec, "a segment needs at least 1 frame")
        if kind == "fly":
            x = float(m["x"]) if m["x"] is not None else 1.0
            if not 0.0 < x <= MAX_SPEED:
                raise _bad(part, spec, f"the speed multiplier X must be in (0, {MAX_SPEED:g}]")
            return Segment("fly", n, (x, x))
        if kind == "hover":
            return Segment("hover", n, (0.0, 0.0))
        if kind == "yaw":
            deg = float(m["deg"]) if m["deg"] is not None else DEFAULT_YAW
            if abs(deg) > MAX_YAW_PER_FRAME * n:
                raise _bad(
                    part,
                    spec,
                    f"at most {MAX_YAW_PER_FRAME:g} degrees per frame ({n} frames: |DEG| <= {MAX_YAW_PER_FRAME * n:g})",
                )
            return Segment("yaw", n, (0.0, 0.0), deg)
        a, b = float(m["a"]), float(m["b"])
        if not (a <= MAX_SPEED and b <= MAX_SPEED):
            raise _bad(part, spec, f"the speed multipliers A and B must be in [0, {MAX_SPEED:g}]")
        return Segment("ramp", n, (a, b))
    raise _bad(part, spec)


def parse_motion(spec: str) -> MotionProfile:
    """Parse ``--motion SPEC`` (comma-separated segments, see the module docstring); a :class:`ConfigError` names
    the bad segment."""
    if not isinstance(spec, str) or not spec.strip():
        raise ConfigError(
            f"--motion: empty motion profile {spec!r}; expected segments such as "
            f"'fly:40,hover:10,fly*0.5:30' ({GRAMMAR})"
        )
    return MotionProfile(tuple(_parse_segment(p.strip(), spec) for p in spec.split(",")))


# ----------------------------------------------------------------------------------------------------------------
# the warped timeline


@dataclass(frozen=True)
class Timeline:
    """Where each 100 Hz ground-truth sample reads the base flight.

    ``tau [4F]``: base-flight time in ground-truth samples (sample ``j`` of the plain flight is ``tau = j``);
    ``yaw [4F]``: the heading offset (radians, about the world vertical, NED: positive turns right) accumulated by
    the yaw segments so far; ``turns``: ``(tau, radians)`` of each yaw segment, where the rest of the path turns.
    """

    tau: np.ndarray
    yaw: np.ndarray
    turns: tuple[tuple[float, float], ...]

    @property
    def base_samples(self) -> int:
        """Ground-truth samples the base flight needs (it is read up to ``tau[-1]``)."""
        return int(math.ceil(float(self.tau[-1]))) + 1

    @property
    def base_frames(self) -> int:
        """Camera frames of the base flight (:func:`make_flight`'s ``n_frames``)."""
        return -(-self.base_samples // SAMPLES_PER_FRAME)

    def ground_track(self, xy: np.ndarray) -> np.ndarray:
        """The turned path over the base flight's samples ``xy [n, 2]`` (``make_flight``'s ``ground_track``)."""
        return turn_path(xy, np.arange(len(xy), dtype=np.float64), xy, self.turns)


def timeline(profile: MotionProfile) -> Timeline:
    """The warp of a profile at the ground-truth samples ``j = 0 .. 4F - 1`` (``F = profile.frames``).

    In a segment starting at sample ``j0`` with ``L = 4N`` samples and multipliers ``A -> B``,
    ``tau(j) = tau(j0) + A (j - j0) + (B - A) (j - j0)^2 / (2 L)``; the yaw offset grows by ``DEG (j - j0) / L``.
    """
    n = SAMPLES_PER_FRAME * profile.frames
    tau = np.empty(n)
    yaw = np.empty(n)
    turns = []
    tau0, yaw0, j0 = 0.0, 0.0, 0
    for seg in profile.segments:
        length = SAMPLES_PER_FRAME * seg.frames
        u = np.arange(length + 1, dtype=np.float64)  # samples j0 .. j0 + L (the last is the next segment's first)
        a, b = seg.speed
        seg_tau = tau0 + a * u + (b - a) * u * u / (2 * length) if a != b else tau0 + a * u
        seg_yaw = yaw0 + math.radians(seg.degrees) * u / length if seg.kind == "yaw" else np.full(length + 1, yaw0)
        if seg.kind == "yaw":
            turns.append((tau0, math.radians(seg.degrees)))
        end = min(j0 + length + 1, n)
        tau[j0:end] = seg_tau[: end - j0]
        yaw[j0:end] = seg_yaw[: end - j0]
        tau0, yaw0, j0 = float(seg_tau[-1]), float(seg_yaw[-1]), j0 + length
    return Timeline(tau, yaw, tuple(turns))


def hermite(samples: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Cubic Hermite interpolation of uniformly spaced ``samples [n, d]`` (n >= 2) at fractional indices
    ``tau [m]`` in ``[0, n - 1]``, with central-difference (Catmull-Rom) tangents; exact at integer ``tau``.
    Returns ``[m, d]``."""
    s = np.asarray(samples, dtype=np.float64)
    tangent = np.gradient(s, axis=0)
    i = np.clip(np.floor(tau).astype(np.int64), 0, len(s) - 2)
    u = (np.asarray(tau, dtype=np.float64) - i)[:, None]
    h00 = (1 + 2 * u) * (1 - u) ** 2
    h10 = u * (1 - u) ** 2
    h01 = u * u * (3 - 2 * u)
    h11 = u * u * (u - 1)
    return h00 * s[i] + h10 * tangent[i] + h01 * s[i + 1] + h11 * tangent[i + 1]


def _rotation2(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])  # (north, east): heading atan2(east, north) grows by angle


def turn_path(
    points: np.ndarray, tau: np.ndarray, base_xy: np.ndarray, turns: tuple[tuple[float, float], ...]
) -> np.ndarray:
    """Horizontal ``points [m, 2]`` of the base path at base times ``tau [m]`` -> where the turned path puts them.

    Turn ``k`` at ``tau_k`` rotates everything after it (``tau > tau_k``) by its angle about the vertical through
    the (already turned) point of the path at ``tau_k``; ``base_xy [n, 2]`` is the base path's samples (for the
    pivots). Returns ``[m, 2]``.
    """
    out = np.array(points, dtype=np.float64)
    if not turns:
        return out
    tau = np.asarray(tau, dtype=np.float64)
    pivots = hermite(base_xy, np.array([t for t, _ in turns]))
    rot, off = np.eye(2), np.zeros(2)  # the current piece's map x -> rot @ x + off
    for k, (t_k, angle) in enumerate(turns):
        pivot = rot @ pivots[k] + off
        r = _rotation2(angle)
        rot, off = r @ rot, r @ (off - pivot) + pivot
        later = tau > t_k
        if k + 1 < len(turns):
            later &= tau <= turns[k + 1][0]
        out[later] = points[later] @ rot.T + off
    return out


def warp_flight(base: Flight, tl: Timeline) -> Flight:
    """The base flight read along the warped timeline: ``[4F]`` ground-truth samples at 100 Hz, with velocity,
    acceleration and angular velocity recomputed on them."""
    tau = tl.tau
    if tl.base_samples > len(base):
        raise ValueError(f"the base flight has {len(base)} samples, the timeline reads {tl.base_samples}")
    xy = turn_path(hermite(base.position[:, :2], tau), tau, base.position[:, :2], tl.turns)
    z = hermite(base.position[:, 2:], tau)
    attitude = hermite(base.attitude, tau)
    between = tau != np.floor(tau)  # exact samples keep their bits
    attitude[between] /= np.linalg.norm(attitude[between], axis=1, keepdims=True)
    turned = tl.yaw != 0.0
    if turned.any():
        half = tl.yaw[turned] / 2
        z_rot = np.stack([np.cos(half), np.zeros_like(half), np.zeros_like(half), np.sin(half)], 1)
        attitude[turned] = qmul(z_rot, attitude[turned])  # about the world (NED) vertical
    altitude = hermite(base.altitude[:, None], tau)[:, 0]
    return flight_from_poses(base.mode, attitude, np.concatenate([xy, z], 1), altitude)
