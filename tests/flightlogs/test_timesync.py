"""The clock offset between a video and a log, from the camera's rotation: synthetic attitudes with known offsets
(minutes into the log, fractions of a frame, noise, a still stretch, a translation's slowly varying pseudo-rotation,
a variable frame rate), flights that cannot decide (no rotation, periodic rotation, a log shorter than the video),
and a whole video rendered from an attitude, measured from its images."""

from __future__ import annotations

import numpy as np
import pytest
from _rotation_signals import euler_quaternions, random_attitude, render_sphere, video_of

from cosemdepth.errors import ConfigError
from cosemdepth.flightlogs.timesync import (
    Attitude,
    VideoRotations,
    attitude_at,
    match_rotations,
    measure_video_rotations,
    pair_rotations,
)

FPS = 25.0


def frames(seconds: float, fps: float = FPS, start: float = 0.0) -> np.ndarray:
    return start + np.arange(int(round(seconds * fps))) / fps


def test_pair_rotations_of_a_constant_yaw_rate():
    t = np.linspace(0.0, 10.0, 101)
    rate = 0.3  # rad/s about the camera's y axis (down): the world turns, camera-to-world R = Ry(rate t)
    q = np.stack([np.cos(rate * t / 2), 0 * t, np.sin(rate * t / 2), 0 * t], -1)
    att = Attitude(t, q)
    np.testing.assert_allclose(attitude_at(att, np.array([0.05]))[0], [np.cos(0.0075), 0, np.sin(0.0075), 0])
    got = pair_rotations(att, np.array([1.0, 2.5]), np.array([1.04, 2.6]))
    np.testing.assert_allclose(got, [[0, 0.3 * 0.04, 0], [0, 0.3 * 0.1, 0]], atol=1e-12)


@pytest.mark.parametrize(
    "offset, fps, noise",
    [
        (1012.37, 25.0, 0.0),  # 12.37 s into the log: not a whole number of frames
        (1183.4567, 29.97, 0.002),  # minutes into the log, NTSC rate, noise of 0.1 degree per axis per pair
        (1300.0123, 60.0, 0.001),
    ],
)
def test_known_offsets_are_found_to_a_few_milliseconds(offset, fps, noise):
    rng = np.random.default_rng(0)
    att = random_attitude(420.0, rng)
    video = video_of(att, offset, frames(20.0, fps, start=0.5), rng, noise)  # pts start at 0.5 s: offset is frame 0's
    est = match_rotations(video, att)
    assert abs(est.offset_s - offset) < 0.002
    assert est.confidence > 0.8 and 0.95 < est.details["rotation_scale"] < 1.05
    video_span = video.t1[-1] - video.start_s
    assert est.details["search_s"] == [1000.0, pytest.approx(1000.0 + 420.0 - 1 / 200 - video_span, abs=1e-5)]
    offset_s, confidence, details = est  # unpacks as the contract's tuple
    assert (offset_s, confidence, details) == (est.offset_s, est.confidence, est.details)


def test_a_variable_frame_rate_and_unmeasured_pairs():
    rng = np.random.default_rng(1)
    att = random_attitude(120.0, rng)
    pts = np.cumsum(rng.choice([0.033, 0.04, 0.05, 0.1], size=400))
    video = video_of(att, 1040.25, pts, rng, 0.001)
    ok = video.ok.copy()
    ok[rng.random(len(ok)) < 0.2] = False  # a fifth of the pairs not determined by their images
    rv = np.where(ok[:, None], video.rotvec, 5.0)  # and garbage there, which must be ignored
    est = match_rotations(VideoRotations(video.t0, video.t1, rv, ok, video.start_s), att)
    assert abs(est.offset_s - 1040.25) < 0.002


def test_a_still_stretch_in_the_video_does_not_mislead():
    rng = np.random.default_rng(2)
    base = random_attitude(200.0, rng)
    q = base.q.copy()
    still = (base.t > 1050.0) & (base.t < 1058.0)  # hovering without turning for 8 s, inside the video
    q[still] = q[np.flatnonzero(still)[0]]
    att = Attitude(base.t, q)
    est = match_rotations(video_of(att, 1046.6, frames(20.0), rng, 0.002), att)
    assert abs(est.offset_s - 1046.6) < 0.002


def test_a_slow_pseudo_rotation_from_the_translation_is_filtered_out():
    rng = np.random.default_rng(3)
    att = random_attitude(150.0, rng, amp_deg=8.0)
    video = video_of(att, 1077.7, frames(30.0), rng, 0.001)
    a = video.t0 - video.start_s
    bias = np.stack([0.6 * (1 + np.sin(a / 4)), 0.2 * np.cos(a / 3), 0 * a], -1) / FPS  # rad/s, slowly varying
    biased = VideoRotations(video.t0, video.t1, video.rotvec + bias, video.ok, video.start_s)
    est = match_rotations(biased, att)
    assert abs(est.offset_s - 1077.7) < 0.004


def test_a_flight_without_rotation_asks_for_the_offset():
    rng = np.random.default_rng(4)
    t = 1000.0 + np.arange(20000) / 200.0
    att = Attitude(t, np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1)))
    video = video_of(att, 1010.0, frames(20.0), rng, 0.0002)  # the measurement's noise only
    with pytest.raises(ConfigError, match=r"hardly rotates .*; give --time-offset SECONDS"):
        match_rotations(video, att)


def test_a_periodic_rotation_is_ambiguous():
    rng = np.random.default_rng(5)
    t = 1000.0 + np.arange(40000) / 200.0
    yaw = 0.3 * np.sin(2 * np.pi * (t - 1000.0) / 2.0)  # the same 2-second swing over and over
    att = Attitude(t, euler_quaternions(yaw, 0 * t, 0 * t))
    video = video_of(att, 1033.3, frames(10.0), rng, 0.001)
    with pytest.raises(ConfigError, match=r"another offset .* fits almost as well.*--time-offset"):
        match_rotations(video, att)


def test_a_log_shorter_than_the_video():
    rng = np.random.default_rng(6)
    att = random_attitude(15.0, rng)
    with pytest.raises(ConfigError, match=r"the video \(19\.96 s\) does not fit inside the log's attitude"):
        match_rotations(video_of(random_attitude(60.0, rng), 1001.0, frames(20.0), rng), att)


def test_a_video_that_runs_past_the_log_s_end_is_refused_not_placed_at_the_end():
    """The true offset would put the video's last 5 s after the log: every offset tried keeps the video inside, the
    best of them explains little, and the error says which offsets were tried."""
    rng = np.random.default_rng(9)
    full = random_attitude(80.0, rng)  # log times 1000 .. 1080; the video (20 s) starts at 1045
    video = video_of(full, 1045.0, frames(20.0), rng, 0.001)
    keep = full.t <= 1060.0  # the log stops at 1060
    cut = Attitude(full.t[keep], full.q[keep])
    with pytest.raises(ConfigError, match=r"offsets tried 1000\.00 \.\. 1040\.0\d s, those that keep the whole video"):
        match_rotations(video, cut)


def test_a_search_range_restricts_the_offsets():
    rng = np.random.default_rng(7)
    att = random_attitude(100.0, rng)
    video = video_of(att, 1030.0, frames(10.0), rng, 0.001)
    assert abs(match_rotations(video, att, search=(1025.0, 1035.0)).offset_s - 1030.0) < 0.002
    with pytest.raises(ConfigError, match="within the search range"):
        match_rotations(video, att, search=(1095.0, 1099.0))


def test_offset_of_a_video_rendered_from_a_logged_attitude():
    rng = np.random.default_rng(8)
    att = random_attitude(40.0, rng, hz=100.0, amp_deg=10.0)
    offset, size, focal = 1011.23, (36, 48), 24.0
    pts = frames(4.0)
    images = [render_sphere(q, size, focal) for q in attitude_at(att, offset + pts - pts[0])]
    rot = measure_video_rotations(((i, t, img) for i, (t, img) in enumerate(zip(pts, images))), focal, size[1])
    assert rot.ok.mean() > 0.9
    est = match_rotations(rot, att)
    assert abs(est.offset_s - offset) < 0.5 / FPS  # within half a frame
