"""The clock offset between a video and a flight log, found by matching the camera's rotation.

The offset ``tau`` is the log time of the video's first frame: a frame with presentation time ``pts`` was taken at
log time ``tau + (pts - pts_first)``. Nothing in a video file says ``tau`` (its clock starts at 0, the log's counts
microseconds since boot), so it is estimated from what both record: the camera turning.

* **The video's rotation** (:func:`measure_video_rotations`): for consecutive frames, the rotation ``R`` with
  ``X_prev = R X_curr`` in camera axes, measured from the images (:mod:`.image_rotation`, a rotation-only
  homography on small gray frames), with a flag saying whether the images determine it.
* **The log's rotation** (:func:`pair_rotations`): for the same pair of frames placed at ``tau``, the camera's
  rotation between the two log times, ``R(t0)^T R(t1)``, from the log's attitude carried to the camera's optical
  frame by the mount (and the gimbal, where logged), interpolated (slerp) between samples.
* **The match** (:func:`match_rotations`): the offset minimising the squared difference of the two rotation-vector
  series over the frame pairs the images determine. Both series are high-passed first (each pair's rotation minus
  their average over :data:`HIGHPASS_S` around it, on both sides alike): a drone's translation adds a slowly varying
  image motion that a rotation-only model reads as a rotation (a forward flight over the ground looks like a pitch),
  and that bias, unlike the rotation's turns, does not move with the clock. The search is coarse first, over every
  offset that keeps the whole video inside the log (one FFT correlation on a grid of half a frame interval: a video
  minutes into an hour-long log costs a fraction of a second), then refines the best few minima on the exact cost
  (each pair at its own presentation times, the log interpolated) to sub-millisecond steps.

The translation's bias is not gone after the high-pass (it changes with the height and the speed): on SynthAir
flights the log explains about half of the video's high-passed rotation at the right offset (a camera looking
straight down at low altitude, a third) and almost nothing at any other; the estimate is within a few milliseconds
(``benchmarks/own_flight.py``). Without the high-pass the fit is better but its minimum moves by several frames.

Still stretches (no rotation in the video) carry no timing: they do not count towards the rotation the flight must
show (:data:`STILL_RATE`, :data:`MIN_MOVING_S`), and weigh in the search only as "the log must be still there
too". The result comes with its **fit** (the fraction of the video's high-passed rotation the log explains at the
offset) and a **confidence** in [0, 1]: the share of that fit that no other offset reaches, ``1 - fit_runner_up /
fit``, the runner-up being the best offset outside the best one's valley of the cost (a periodic motion or a chance
match in a long log has a runner-up nearly as good: confidence near 0). Below :data:`MIN_CONFIDENCE` or
:data:`MIN_FIT`, or when the video rotates too little, :class:`~cosemdepth.errors.ConfigError` asks for
``--time-offset``: a clock that the images do not decide is never used silently.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterable

import numpy as np

from ..errors import ConfigError
from ..geometry.attitude import quat_conjugate, quat_multiply, slerp
from ..geometry.mount import CameraMount, camera_poses
from .image_rotation import frame_rotation

#: Rotation rate (radians per second, 2 degrees/s) under which a frame pair counts as still.
STILL_RATE = np.deg2rad(2.0)
#: Seconds of video that must rotate faster than :data:`STILL_RATE` for the offset to be estimated.
MIN_MOVING_S = 1.0
#: The smallest confidence at which an estimated offset is used ...
MIN_CONFIDENCE = 0.5
#: ... and the smallest fraction of the video's (high-passed) rotation the log must explain at that offset.
MIN_FIT = 0.15
#: Width (seconds) of the moving average the rotation series are high-passed with.
HIGHPASS_S = 1.5
#: Width (pixels) of the gray frames the video's rotation is measured on.
MEASURE_WIDTH = 160
#: Frame pairs measured at most; a longer video is measured in :data:`MEASURE_WINDOWS` evenly spread windows.
MAX_PAIRS = 1500
MEASURE_WINDOWS = 10
#: Coarse minima refined on the exact cost.
CANDIDATES = 5

ASK = "give --time-offset SECONDS (the log time of the video's first frame)"


@dataclass(frozen=True)
class VideoRotations:
    """The video's measured rotation between frame pairs: ``t0``, ``t1`` [P] presentation times (seconds) of each
    pair's previous and current frame, ``rotvec`` [P, 3] (radians, camera axes; ``X_prev = R X_curr``), ``ok`` [P]
    (the images determine it), ``start_s`` (the presentation time of the video's first frame)."""

    t0: np.ndarray
    t1: np.ndarray
    rotvec: np.ndarray
    ok: np.ndarray
    start_s: float

    def __len__(self) -> int:
        return len(self.t0)


@dataclass(frozen=True)
class Attitude:
    """The camera's attitude on the log's clock: ``t`` [M] seconds, strictly increasing; ``q`` [M, 4] unit
    quaternions (w, x, y, z) rotating optical-frame vectors into the world (camera-to-world)."""

    t: np.ndarray
    q: np.ndarray


@dataclass(frozen=True)
class OffsetEstimate:
    """``offset_s`` (the log time of the video's first frame), ``confidence`` in [0, 1], and ``details`` (how it
    was found: ``method``, ``fit``, ``runner_up_s``, ``runner_up_fit``, ``uncertainty_s``, ``rotation_scale``,
    ``pairs``, ``moving_s``, ``search_s``...). Unpacks as ``(offset_s, confidence, details)``."""

    offset_s: float
    confidence: float
    details: dict = field(default_factory=dict)

    def __iter__(self):
        return iter((self.offset_s, self.confidence, self.details))


# --- quaternions on arrays ---------------------------------------------------------------------------------------


def quaternion_to_rotvec(q: np.ndarray) -> np.ndarray:
    """``[..., 4]`` unit quaternions (w, x, y, z) -> ``[..., 3]`` rotation vectors (the shorter rotation)."""
    q = np.where(q[..., :1] < 0, -q, q)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2 * np.arctan2(s, q[..., :1])
    scale = np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 2.0)
    return v * scale


def attitude_at(att: Attitude, t: np.ndarray) -> np.ndarray:
    """Slerp of the attitude at times ``t`` [N] (clamped to the samples' span) -> ``[N, 4]``."""
    t = np.asarray(t, dtype=np.float64)
    ts = att.t
    i = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, len(ts) - 2)
    a = np.clip((t - ts[i]) / (ts[i + 1] - ts[i]), 0.0, 1.0)
    return slerp(att.q[i], att.q[i + 1], a)


def pair_rotations(att: Attitude, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """The camera's rotation vectors ``[N, 3]`` of ``R(t0)^T R(t1)`` (camera axes at ``t0``; the motion convention
    ``X_prev = R X_curr``) between log times ``t0`` and ``t1`` [N]."""
    return quaternion_to_rotvec(quat_multiply(quat_conjugate(attitude_at(att, t0)), attitude_at(att, t1)))


def check_attitude(att: Attitude, what: str = "attitude") -> Attitude:
    t = np.asarray(att.t, dtype=np.float64)
    q = np.asarray(att.q, dtype=np.float64)
    if t.ndim != 1 or q.shape != (len(t), 4) or len(t) < 2:
        raise ConfigError(f"{what}: needs at least 2 samples of times [M] and quaternions [M, 4]")
    if not (np.isfinite(t).all() and np.isfinite(q).all() and np.all(np.diff(t) > 0)):
        raise ConfigError(f"{what}: times must be finite and strictly increasing, quaternions finite")
    return Attitude(t, q / np.linalg.norm(q, axis=-1, keepdims=True))


# --- the video's side ---------------------------------------------------------------------------------------------


def _measured_windows(count: int | None) -> Callable[[int], bool] | None:
    """Which pairs (by the index of their current frame) to measure when a video has more than :data:`MAX_PAIRS`;
    None: all."""
    if count is None or count - 1 <= MAX_PAIRS:
        return None
    length = MAX_PAIRS // MEASURE_WINDOWS
    starts = np.linspace(1, count - length, MEASURE_WINDOWS).astype(int)
    return lambda i: bool(np.any((i >= starts) & (i < starts + length)))


def measure_video_rotations(
    frames: Iterable, focal_px: float, width: int, *, count: int | None = None, progress=None
) -> VideoRotations:
    """The rotation between consecutive frames of ``frames`` (``(index, pts_s, gray [h, w(, 1)])`` in order, e.g.
    ``VideoReader.frames(size=..., gray=True)``) of a centred camera of focal length ``focal_px`` at the full image
    ``width`` (rescaled to the frames' width). ``count``: the number of frames when known (longer videos are
    measured in windows, :data:`MAX_PAIRS`); ``progress``: called with each frame index."""
    pick = _measured_windows(count)
    t0, t1, rv, ok = [], [], [], []
    prev = None
    start = None
    for index, pts, img in frames:
        img = np.asarray(img, dtype=np.float64)
        img = img[..., 0] if img.ndim == 3 else img
        if start is None:
            start = float(pts)
        if prev is not None and (pick is None or pick(index)):
            f = focal_px * img.shape[1] / width
            r = frame_rotation(prev[1], img, f)
            t0.append(prev[0])
            t1.append(float(pts))
            rv.append(r.rotvec)
            ok.append(r.ok)
        prev = (float(pts), img)
        if progress is not None:
            progress(index)
    if start is None:
        raise ConfigError("the video has no frames to measure its rotation on")
    return VideoRotations(
        np.asarray(t0, dtype=np.float64),
        np.asarray(t1, dtype=np.float64),
        np.asarray(rv, dtype=np.float64).reshape(-1, 3),
        np.asarray(ok, dtype=bool),
        start,
    )


def measure_size(size: tuple[int, int]) -> tuple[int, int]:
    """The ``(h, w)`` of the gray frames the rotation is measured on for a video of displayed ``size``."""
    h, w = size
    mw = min(MEASURE_WIDTH, w)
    return max(8, round(h * mw / w)), mw


# --- the match -----------------------------------------------------------------------------------------------------


def _highpass_pairs(x: np.ndarray, w: np.ndarray, mid: np.ndarray, width: float) -> np.ndarray:
    """Each row of ``x`` [P, 3] minus the ``w``-weighted mean of the rows whose ``mid`` time is within ``width / 2``
    (rows sorted by ``mid``)."""
    lo = np.searchsorted(mid, mid - width / 2, side="left")
    hi = np.searchsorted(mid, mid + width / 2, side="right")
    cw = np.concatenate([[0.0], np.cumsum(w)])
    cx = np.concatenate([np.zeros((1, 3)), np.cumsum(x * w[:, None], axis=0)])
    sw = cw[hi] - cw[lo]
    mean = (cx[hi] - cx[lo]) / np.maximum(sw, 1e-12)[:, None]
    return x - mean


def _highpass_grid(x: np.ndarray, w: np.ndarray, n: int) -> np.ndarray:
    """Grid version: ``x`` [N, 3] minus its ``w``-weighted moving average over ``2n + 1`` bins."""
    cw = np.concatenate([[0.0], np.cumsum(w)])
    cx = np.concatenate([np.zeros((1, 3)), np.cumsum(x * w[:, None], axis=0)])
    idx = np.arange(len(x))
    lo = np.clip(idx - n, 0, len(x))
    hi = np.clip(idx + n + 1, 0, len(x))
    sw = cw[hi] - cw[lo]
    return x - (cx[hi] - cx[lo]) / np.maximum(sw, 1e-12)[:, None]


def _correlate(a: np.ndarray, b: np.ndarray, valid: int) -> np.ndarray:
    """``out[k] = sum_j a[j] b[k + j]`` for ``k < valid`` (1-D arrays, by FFT)."""
    n = 1 << int(np.ceil(np.log2(len(a) + len(b))))
    return np.fft.irfft(np.fft.rfft(b, n) * np.conj(np.fft.rfft(a, n)), n)[:valid]


class _Problem:
    """The exact cost of an offset: the pairs at their own times, the log interpolated, both high-passed."""

    def __init__(self, rot: VideoRotations, att: Attitude, highpass_s: float):
        self.att = att
        self.a = rot.t0 - rot.start_s
        self.b = rot.t1 - rot.start_s
        self.w = rot.ok.astype(np.float64)
        self.mid = (self.a + self.b) / 2
        self.highpass_s = highpass_s
        self.video = _highpass_pairs(rot.rotvec, self.w, self.mid, highpass_s) if highpass_s > 0 else rot.rotvec
        self.energy = float(np.sum(self.w * np.sum(self.video**2, -1)))

    def log(self, tau: float) -> np.ndarray:
        raw = pair_rotations(self.att, tau + self.a, tau + self.b)
        return _highpass_pairs(raw, self.w, self.mid, self.highpass_s) if self.highpass_s > 0 else raw

    def residuals(self, tau: float) -> np.ndarray:
        return self.video - self.log(tau)

    def cost(self, tau: float) -> float:
        return float(np.sum(self.w * np.sum(self.residuals(tau) ** 2, -1)))


def _refine(problem: _Problem, tau: float, step: float, lo: float, hi: float) -> tuple[float, float]:
    """Minimise the exact cost near ``tau`` (grids of ``step / 8`` then ``step / 64`` and a parabola):
    ``(tau, cost)``."""
    for span, n in ((2 * step, 33), (step / 8, 17)):
        grid = np.clip(tau + np.linspace(-span, span, n), lo, hi)
        costs = np.array([problem.cost(g) for g in grid])
        k = int(np.argmin(costs))
        tau = float(grid[k])
        if 0 < k < n - 1:
            c_m, c_0, c_p = costs[k - 1], costs[k], costs[k + 1]
            den = c_m - 2 * c_0 + c_p
            if den > 0:
                tau = float(np.clip(tau + 0.5 * (c_m - c_p) / den * (grid[1] - grid[0]), lo, hi))
    return tau, problem.cost(tau)


def match_rotations(
    rot: VideoRotations,
    att: Attitude,
    *,
    search: tuple[float, float] | None = None,
    highpass_s: float = HIGHPASS_S,
    min_confidence: float = MIN_CONFIDENCE,
    what: str = "the video",
) -> OffsetEstimate:
    """The offset ``tau`` (log time of the video's first frame) at which the log's camera rotation best matches
    the video's (see the module docstring). ``search``: the range of offsets to consider (default: every offset
    that keeps the video inside the attitude's span). ``what`` names the inputs in the error messages.

    Raises :class:`~cosemdepth.errors.ConfigError` (asking for ``--time-offset``) when the video rotates too little,
    the log is shorter than the video, or the confidence is below ``min_confidence``."""
    att = check_attitude(att, what)
    if len(rot) == 0:
        raise ConfigError(f"cannot find the clock offset of {what}: it has fewer than 2 frames; {ASK}")
    a = rot.t0 - rot.start_s
    b = rot.t1 - rot.start_s
    dur = b - a
    ok = rot.ok & np.isfinite(rot.rotvec).all(-1) & (dur > 0)
    rot = VideoRotations(rot.t0, rot.t1, np.where(ok[:, None], rot.rotvec, 0.0), ok, rot.start_s)
    rate = np.linalg.norm(rot.rotvec, axis=-1) / np.where(dur > 0, dur, 1.0)
    moving = ok & (rate > STILL_RATE)
    moving_s = float(dur[moving].sum())
    details: dict = {
        "method": "image rotation matched to the log's attitude",
        "pairs": int(len(rot)),
        "pairs_measured_ok": int(ok.sum()),
        "moving_s": round(moving_s, 3),
    }
    if moving_s < MIN_MOVING_S:
        raise ConfigError(
            f"cannot find the clock offset of {what}: the camera hardly rotates in the video "
            f"({moving_s:.1f} s of the frame pairs turn faster than {np.rad2deg(STILL_RATE):g} deg/s, "
            f"{MIN_MOVING_S:g} s needed); {ASK}"
        )
    end = float(b[-1])
    lo, hi = float(att.t[0]), float(att.t[-1]) - end
    if search is not None:
        lo, hi = max(lo, float(search[0])), min(hi, float(search[1]))
    if hi < lo:
        raise ConfigError(
            f"cannot find the clock offset of {what}: the video ({end:.2f} s) does not fit inside the log's "
            f"attitude ({att.t[0]:.2f} .. {att.t[-1]:.2f} s)"
            + (f" within the search range {search[0]:g} .. {search[1]:g} s" if search is not None else "")
            + f"; {ASK}"
        )
    details["search_s"] = [round(lo, 6), round(hi, 6)]
    problem = _Problem(rot, att, highpass_s)

    # coarse: every offset on a grid of half the median frame interval
    d = float(np.median(dur[ok])) if ok.any() else float(np.median(dur))
    h = d / 2
    j = np.clip(np.round(a / h).astype(int), 0, None)
    m = int(j.max()) + 1
    v = np.zeros((m, 3))
    wv = np.zeros(m)
    np.add.at(v, j, rot.rotvec * (d / dur)[:, None])
    np.add.at(wv, j, ok.astype(np.float64))
    v /= np.maximum(wv, 1.0)[:, None]
    wv = (wv > 0).astype(np.float64)
    n_off = int(np.floor((hi - lo) / h)) + 1
    grid_t = lo + h * np.arange(n_off + m - 1)
    lg = pair_rotations(att, grid_t, np.minimum(grid_t + d, att.t[-1]))
    nb = max(1, int(round(highpass_s / h / 2))) if highpass_s > 0 else 0
    if nb:
        v = _highpass_grid(v, wv, nb) * wv[:, None]
        lg = _highpass_grid(lg, np.ones(len(lg)), nb)
    ev = float(np.sum(v**2))
    cross = sum(_correlate(v[:, c], lg[:, c], n_off) for c in range(3))
    quad = _correlate(wv, np.sum(lg**2, -1), n_off)
    coarse = (ev - 2 * cross + quad) / max(ev, 1e-30)
    offsets = lo + h * np.arange(n_off)

    # the best few local minima, refined on the exact cost
    radius = max(2, int(round(0.25 / h)))
    order = np.argsort(coarse)
    picked: list[int] = []
    for k in order:
        if all(abs(int(k) - p) > radius for p in picked):
            picked.append(int(k))
        if len(picked) == CANDIDATES:
            break
    refined = [_refine(problem, float(offsets[k]), h, lo, hi) for k in picked]
    best = int(np.argmin([c for _, c in refined]))
    tau, cost = refined[best]
    k_best = picked[best]

    # the valley of the best minimum (the coarse cost below halfway to the median) and the best offset outside it
    c_best = float(coarse[k_best])
    level = c_best + 0.5 * (float(np.median(coarse)) - c_best)
    left = k_best
    while left > 0 and coarse[left - 1] < level:
        left -= 1
    right = k_best
    while right < n_off - 1 and coarse[right + 1] < level:
        right += 1
    outside = np.ones(n_off, dtype=bool)
    outside[left : right + 1] = False
    fit = 1.0 - cost / max(problem.energy, 1e-30)
    fit2 = 0.0
    details["runner_up_s"] = None
    if outside.any():
        # the runner-up: the best refined candidate outside the valley, else the coarse minimum there, refined
        others = [(t, c) for k, (t, c) in zip(picked, refined) if outside[k]]
        if not others:
            k2 = int(np.flatnonzero(outside)[np.argmin(coarse[outside])])
            others = [_refine(problem, float(offsets[k2]), h, lo, hi)]
        tau2, cost2 = min(others, key=lambda tc: tc[1])
        fit2 = 1.0 - cost2 / max(problem.energy, 1e-30)
        details["runner_up_s"] = round(float(tau2), 4)
        details["runner_up_fit"] = round(float(fit2), 4)
    # the share of the best offset's fit that no other offset reaches
    confidence = float(np.clip(1.0 - max(fit2, 0.0) / fit, 0.0, 1.0)) if fit > 0 else 0.0

    # diagnostics: the scale of the video's rotation against the log's (focal length / mount check) and the
    # offset's standard error from the cost's curvature
    lv = problem.log(tau)
    wl = problem.w[:, None]
    scale = float(np.sum(wl * lv * problem.video) / max(np.sum(wl * lv * lv), 1e-30))
    e = max(h / 16, 1e-4)
    curv = (problem.cost(tau + e) - 2 * cost + problem.cost(tau - e)) / e**2
    dof = max(3 * ok.sum() - 1, 1)
    unc = float(np.sqrt(2 * (cost / dof) / curv)) if curv > 0 else float("inf")
    details.update(
        fit=round(float(fit), 4),
        rotation_scale=round(scale, 4),
        uncertainty_s=round(unc, 5) if np.isfinite(unc) else None,
        grid_step_s=round(h, 6),
        highpass_s=highpass_s,
    )
    why = None
    if fit < MIN_FIT:
        why = f"the log's rotation explains only {100 * max(fit, 0):.0f} % of the video's at best"
    elif confidence < min_confidence:
        why = f"another offset ({details['runner_up_s']:.2f} s) fits almost as well"
    if why is not None:
        raise ConfigError(
            f"cannot find the clock offset of {what} from the camera's rotation: best {tau:.3f} s, confidence "
            f"{confidence:.2f} ({why}; offsets tried {lo:.2f} .. {hi:.2f} s, those that keep the whole video inside "
            f"the log's attitude); {ASK}"
        )
    return OffsetEstimate(float(tau), confidence, details)


# --- a video and a log ------------------------------------------------------------------------------------------


def camera_attitude(log, mount: CameraMount) -> Attitude:
    """The camera's optical-frame attitude on the log's clock from a :class:`~cosemdepth.flightlogs.FlightLog`'s
    attitude and ``mount`` (the gimbal's rotation instead of the mount's where the log records one: only the
    attitude samples inside the gimbal's series are kept then)."""
    att = log.attitude
    if att is None:
        raise ConfigError(
            f"{log.path}: the log has no attitude, so the clock offset cannot be found from the camera's rotation; {ASK}"
        )
    t, q = att.t, att.v
    gimbal = None
    if getattr(log, "gimbal", None) is not None:
        gimbal, ok = log.gimbal_at(t)
        t, q, gimbal = t[ok], q[ok], gimbal[ok]
        if len(t) < 2:
            raise ConfigError(f"{log.path}: the log's gimbal angles do not overlap its attitude; {ASK}")
    q_opt, _ = camera_poses(q, np.zeros((len(t), 3)), mount.R_body_optical, mount.lever_arm, gimbal)
    return Attitude(t, q_opt)


def estimate_time_offset(
    video, log, mount: CameraMount, *, focal_px: float, progress=None, min_confidence: float = MIN_CONFIDENCE
) -> OffsetEstimate:
    """The log time of ``video``'s first frame (a :class:`~cosemdepth.data.video.VideoReader`) for ``log`` (a
    :class:`~cosemdepth.flightlogs.FlightLog`) with the camera on ``mount``, ``focal_px`` the horizontal focal
    length in pixels of the video's displayed frames.

    * A DJI subtitle file is on the video's own clock: the offset is the first frame's presentation time (confidence
      1, nothing measured).
    * Otherwise the camera's rotation is matched (:func:`match_rotations`; the video decoded once more, small and
      gray). Where both the video (its ``creation_time``) and the log (``utc_offset_s``: ULog GPS time, a tlog's
      wall clock...) have an absolute clock, the offset they imply is recorded beside the estimate as a check
      (``details["creation_time_offset_s"]``, ``details["creation_time_difference_s"]``); camera clocks are
      whole seconds at best and may mark the end of the recording, so it does not steer the estimate.

    Raises the one-line :class:`~cosemdepth.errors.ConfigError` of :func:`match_rotations` asking for
    ``--time-offset`` when the rotation does not decide."""
    what = f"{video.path} against {log.path}"
    if log.format == "srt":
        return OffsetEstimate(
            float(video.start_s), 1.0, {"method": "srt: the subtitles are on the video's clock (nothing estimated)"}
        )
    att = camera_attitude(log, mount)
    h, w = measure_size(video.size)
    rot = measure_video_rotations(
        video.frames(size=(h, w), gray=True), focal_px, video.size[1], count=video.count_hint, progress=progress
    )
    est = match_rotations(rot, att, what=what, min_confidence=min_confidence)
    details = dict(est.details)
    details["measured_on"] = [h, w]
    utc = getattr(log, "utc_offset_s", None)
    if video.creation_time_utc is not None and utc is not None:
        prior = float(video.creation_time_utc - utc)
        details["creation_time_offset_s"] = round(prior, 3)
        details["creation_time_difference_s"] = round(est.offset_s - prior, 3)
    return OffsetEstimate(est.offset_s, est.confidence, details)


__all__ = [
    "Attitude",
    "camera_attitude",
    "estimate_time_offset",
    "MIN_CONFIDENCE",
    "OffsetEstimate",
    "VideoRotations",
    "attitude_at",
    "match_rotations",
    "measure_size",
    "measure_video_rotations",
    "pair_rotations",
    "quaternion_to_rotvec",
]
