"""A video + flight log as a streaming source: the frames' times on the log's clock, the motions from the log's poses
through the camera mount (hand-computed), frames outside the log, a log without positions, a video the log does not
cover, the options' checks, and the clock offset estimated from a video rendered from the logged attitude."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "data"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "flightlogs"))
from _rotation_signals import random_attitude, render_sphere  # noqa: E402
from _video_flights import LOG_START, RATE, SPEED, YAW_RATE, write_log, write_video  # noqa: E402
from _videos import write_pyav  # noqa: E402

from cosemdepth.data.quaternion import qmul  # noqa: E402
from cosemdepth.errors import ConfigError, DatasetError  # noqa: E402
from cosemdepth.flightlogs.geodetic import METRES_PER_DEGREE  # noqa: E402
from cosemdepth.flightlogs.timesync import attitude_at  # noqa: E402
from cosemdepth.geometry.mount import parse_mount  # noqa: E402
from cosemdepth.streaming import SOURCES  # noqa: E402
from cosemdepth.streaming.sources.video_log import VideoLogOptions  # noqa: E402


def options(tmp_path, **kw) -> VideoLogOptions:
    video = kw.pop("video", None) or write_video(tmp_path / "flight.mp4")
    log = kw.pop("log", None) or write_log(tmp_path / "flight.ulg")
    return VideoLogOptions(video=video, log=log, **{"hfov": 90.0, "time_offset": 10.0, **kw})


def test_times_names_and_motions_of_a_forward_camera(tmp_path):
    src = SOURCES["video"].from_options(options(tmp_path, frame_skip=2), 32)
    assert src.frame_size() == (32, 32) and src.total_frames() == 10
    batches = list(src.batches())
    assert [b.index[0] for b in batches] == list(range(0, 20, 2))
    assert [int(b.frame[0]) for b in batches] == list(range(10))
    assert [b.name[0] for b in batches] == [f"flight.mp4#{i:06d}" for i in range(0, 20, 2)]
    assert [b.meta[0]["pts_s"] for b in batches] == pytest.approx([i / 25 for i in range(0, 20, 2)])
    assert [b.meta[0]["log_time_s"] for b in batches] == pytest.approx([10.0 + i / 25 for i in range(0, 20, 2)])
    assert [bool(b.reset[0]) for b in batches] == [True] + [False] * 9
    assert all(bool(b.depth_ok[0]) for b in batches)
    # 64x48 frames, 90 degrees: f = 32 px, resized to 32x32: fx = 16, fy = 32 * 32 / 48
    np.testing.assert_allclose(batches[0].intrinsics[0].numpy(), [16, 32 * 32 / 48, 16, 16], rtol=1e-6)
    # between kept frames (0.08 s): the body moved SPEED * 0.08 north and yawed YAW_RATE * 0.08 right. In the
    # previous camera's optical axes (x right, y down, z forward) at heading psi: north = (-sin psi, 0, cos psi);
    # the yaw turns about +y (down)
    for prev, cur in zip(batches, batches[1:]):
        psi = YAW_RATE * (prev.meta[0]["log_time_s"] - LOG_START)
        d = SPEED * 0.08
        np.testing.assert_allclose(cur.trans[0].numpy(), [-np.sin(psi) * d, 0.0, np.cos(psi) * d], atol=1e-5)
        a = YAW_RATE * 0.08
        np.testing.assert_allclose(cur.rot[0].numpy(), [np.cos(a / 2), 0.0, np.sin(a / 2), 0.0], atol=1e-6)
    # the pose: optical -> NED, at log time 10 s: heading 1 rad, position 10 m north
    pose = batches[0].pose[0].double().numpy()
    np.testing.assert_allclose(pose[:3, 3], [10.0, 0.0, -10.0], atol=1e-4)
    np.testing.assert_allclose(pose[:3, 2], [np.cos(1.0), np.sin(1.0), 0.0], atol=1e-5)  # optical z = heading
    info = src.describe()
    assert info["time_offset_s"] == 10.0 and info["time_offset_confidence"] is None
    assert info["log"]["format"] == "ulog" and src.frames_outside_log == 0 and info["video"]["frames"] == 20
    assert src.min_baseline_m == 0.0


def test_a_camera_looking_down_moves_along_minus_y(tmp_path):
    def straight(t):
        return np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1)), np.stack([SPEED * t, 0 * t, 0 * t], -1)

    opts = options(tmp_path, log=write_log(tmp_path / "s.ulg", straight), camera_mount="down")
    batches = list(SOURCES["video"].from_options(opts, 32).batches(max_frames=3))
    assert len(batches) == 3
    # looking down with the image's top toward the front: forward is the image's up, optical -y
    np.testing.assert_allclose(batches[1].trans[0].numpy(), [0.0, -SPEED / 25, 0.0], atol=1e-6)
    np.testing.assert_allclose(batches[1].rot[0].numpy(), [1.0, 0.0, 0.0, 0.0], atol=1e-7)
    # a lever arm 1 m forward of the body: the camera is 1 m further north
    opts = options(tmp_path, log=write_log(tmp_path / "s.ulg", straight), camera_mount="down", lever_arm=(1, 0, 0))
    pose = next(iter(SOURCES["video"].from_options(opts, 32).batches())).pose[0].double().numpy()
    np.testing.assert_allclose(pose[:3, 3], [SPEED * 10.0 + 1.0, 0.0, 0.0], atol=1e-4)


def test_frames_before_the_log_are_resets_without_depth(tmp_path):
    src = SOURCES["video"].from_options(options(tmp_path, time_offset=LOG_START - 0.3), 32)
    batches = list(src.batches())
    outside = [not bool(b.depth_ok[0]) for b in batches]
    assert outside == [True] * 8 + [False] * 12  # frames at 4.70 .. 4.98 s lie before the log's first sample (5 s)
    assert (
        "outside the log (log time 4.700 s; the log covers 5.000 .. 19.990 s)"
        in batches[0].meta[0]["depth_invalid_reason"]
    )
    assert [bool(b.reset[0]) for b in batches[:10]] == [True] * 9 + [False]  # the first covered frame starts afresh
    assert batches[0].pose is None and batches[8].pose is not None
    assert src.frames_outside_log == 8
    assert src.report().endswith("; 8 frames outside the log (resets without depth)")


def test_a_video_the_log_does_not_cover(tmp_path):
    with pytest.raises(DatasetError, match=r"flight\.ulg: the log \(5\.000 \.\. 19\.990 s\) does not cover the video"):
        SOURCES["video"].from_options(options(tmp_path, time_offset=100.0), 32)


def test_a_log_without_positions_gives_labels_but_no_depth(tmp_path):
    opts = options(tmp_path, log=write_log(tmp_path / "att.ulg", positions=False))
    batches = list(SOURCES["video"].from_options(opts, 32).batches(max_frames=4))
    assert not any(bool(b.depth_ok[0]) for b in batches)
    assert "the log has no positions (attitude only)" in batches[1].meta[0]["depth_invalid_reason"]
    assert torch.all(batches[1].trans == 0) and not torch.allclose(batches[1].rot, torch.tensor([[1.0, 0, 0, 0]]))


def test_a_log_without_attitude_gives_labels_but_no_depth(tmp_path):
    """DJI subtitles without gimbal angles (most models): positions only, on the video's clock."""
    from cosemdepth.flightlogs.srt_writer import write_srt

    t = np.arange(20) / 25
    lat, lon = 46.5 + 1e-5 * np.arange(20), np.full(20, 6.5)
    write_srt(tmp_path / "flight.SRT", t, lat, lon, np.full(20, 12.0), np.full(20, 500.0), None)
    opts = options(tmp_path, log=tmp_path / "flight.SRT", time_offset="auto")
    src = SOURCES["video"].from_options(opts, 32)
    batches = list(src.batches())
    assert src.time_offset == 0.0 and len(batches) == 20 and src.frames_outside_log == 0
    # latitudes printed to 1e-6 degrees (0.111 m north; altitudes to 1 mm): depth only on 3 steps or more
    assert src.min_baseline_m == pytest.approx(3 * 1e-6 * METRES_PER_DEGREE)
    assert "no depth: the log has no attitude" in src.report() and "positions to" not in src.report()
    assert not any(bool(b.depth_ok[0]) for b in batches) and all(b.pose is None for b in batches)
    assert all("the log has no attitude (positions only)" in b.meta[0]["depth_invalid_reason"] for b in batches)
    assert all(torch.all(b.trans == 0) and torch.equal(b.rot, torch.tensor([[1.0, 0, 0, 0]])) for b in batches)


def test_gps_positions_say_the_shortest_baseline_with_depth(tmp_path):
    from cosemdepth.flightlogs.srt_writer import write_srt

    t = np.arange(20) / 25
    lat, lon = 46.5 + 1e-5 * np.arange(20), np.full(20, 6.5)
    angles = np.zeros((20, 3))  # yaw, pitch, roll of the camera: north, level
    write_srt(tmp_path / "flight.SRT", t, lat, lon, np.full(20, 12.0), np.full(20, 500.0), angles)
    src = SOURCES["video"].from_options(options(tmp_path, log=tmp_path / "flight.SRT", time_offset="auto"), 32)
    step = 1e-6 * METRES_PER_DEGREE  # 6 printed decimals of latitude: 0.111 m
    assert src.min_baseline_m == pytest.approx(3 * step)
    assert f"positions to {step:.3g} m: no depth on a baseline under {3 * step:.3g} m" in src.report()


@pytest.mark.parametrize(
    "change, message",
    [
        ({"time_offset": "soon"}, r"--time-offset must be seconds or 'auto', got 'soon'"),
        ({"time_offset": float("nan")}, r"--time-offset must be a finite number"),
        ({"hfov": None}, r"exactly one of --intrinsics FX FY CX CY, --hfov DEG and --calibration FILE"),
        ({"log_format": "csv"}, r"--log-format must be one of ulog, dataflash, tlog, srt"),
        ({"camera_mount": "sideways"}, r"--camera-mount 'sideways'"),
        ({"camera_mount": "down@0,0,1", "lever_arm": (1, 0, 0)}, r"--lever-arm: the mount 'down@0,0,1' already"),
        ({"frame_skip": 0}, r"--frame-skip must be a positive integer"),
    ],
)
def test_options_are_checked_when_made(tmp_path, change, message):
    with pytest.raises(ConfigError, match=message):
        options(tmp_path, **change)
    with pytest.raises(ConfigError, match=r"--images frames: not a video file name"):
        VideoLogOptions(video=Path("frames"), log=Path("x.ulg"), hfov=90.0)


def test_the_offset_is_estimated_from_a_video_of_the_logged_attitude(tmp_path):
    """The body wanders in attitude; a camera pitched down 30 degrees films a textured sphere; the video starts 7.37 s
    into the log (``auto``): the estimate is within a millisecond-scale of the truth."""
    rng = np.random.default_rng(0)
    att = random_attitude(25.0, rng, hz=RATE, t0=LOG_START, amp_deg=10.0)
    mount = parse_mount("0,-30,0")
    offset, fps, n, size, focal = LOG_START + 7.37, 25.0, 100, (48, 64), 32.0
    pts = np.arange(n) / fps
    q_body = attitude_at(att, offset + pts)
    from cosemdepth.geometry.attitude import matrix_to_quat

    q_cam = qmul(q_body, matrix_to_quat(mount.R_body_optical))  # optical -> NED
    frames = []
    for q in q_cam:
        img = render_sphere(q, size, focal)
        frames.append(np.repeat(np.clip(128 + 30 * img, 0, 255).astype(np.uint8)[..., None], 3, axis=2))
    # the camera's clock (creation_time, whole seconds) says the video started 0.63 s after the truth
    boot = 1_796_637_600.0
    tag = {"creation_time": "2026-12-07T10:00:13Z"}  # boot + 13 s; the truth is boot + 12.37 s
    video = write_pyav(tmp_path / "sphere.mp4", frames, pts, metadata=tag)

    def log_q(t):
        return attitude_at(att, t), np.zeros((len(t), 3))

    log = write_log(tmp_path / "wander.ulg", log_q, end=LOG_START + 24.9, utc_at_boot=boot)
    opts = VideoLogOptions(video=video, log=log, hfov=90.0, camera_mount="0,-30,0")
    src = SOURCES["video"].from_options(opts, None)
    assert abs(src.time_offset - offset) < 0.01  # a quarter of a frame
    assert src.confidence > 0.5
    info = src.describe()
    assert info["time_offset"]["method"].startswith("image rotation") and info["time_offset_s"] == src.time_offset
    assert info["time_offset"]["creation_time_offset_s"] == pytest.approx(13.0, abs=1e-3)  # recorded as a check
    assert info["time_offset"]["creation_time_difference_s"] == pytest.approx(-0.63, abs=0.01)
    # the wrong mount (forward instead of pitched down) rotates the log's rates into other axes: a worse fit
    wrong = SOURCES["video"].from_options(
        VideoLogOptions(video=video, log=log, hfov=90.0, camera_mount="forward"), None
    )
    assert wrong.describe()["time_offset"]["fit"] < info["time_offset"]["fit"]


def test_a_calibrated_video_is_undistorted_with_its_source_mask(tmp_path):
    """``calibration``: each decoded frame goes through the calibration's Undistorter (the same remap as a flight
    of images), the intrinsics are the rectified pinhole's, the pixels without a source are marked, and the
    description records the rectified camera; a calibration with --hfov is refused."""
    from cosemdepth.camera import Calibration, Undistorter
    from cosemdepth.camera.writers import ros_yaml
    from cosemdepth.data.video import open_video

    # a 64x48 video (write_video's frames), a strong barrel lens calibrated at 128x96 (scaled: same aspect ratio)
    cal = Calibration((96, 128), 64.0, 64.0, 64.0, 48.0, "radtan", (-0.3, 0.08, 0.0, 0.0, 0.0))
    path = tmp_path / "camera_info.yaml"
    path.write_text(ros_yaml(cal), encoding="utf-8")
    src = SOURCES["video"].from_options(options(tmp_path, hfov=None, calibration=path), (24, 32))
    batches = list(src.batches(max_frames=3))
    expected = Undistorter(cal.for_image_size((48, 64), "the video's frames"), size=(24, 32))
    np.testing.assert_allclose(batches[0].intrinsics[0].numpy(), expected.intrinsics.numpy())
    frames = [f.image for f in open_video(tmp_path / "flight.mp4").frames(1)][:3]
    for b, image in zip(batches, frames):
        rgb, valid = expected(image)
        torch.testing.assert_close(b.rgb[0], rgb)
        assert b.source_valid.shape == (1, 1, 24, 32) and torch.equal(b.source_valid[0, 0], valid)
    info = src.describe()["calibration"]
    assert info["size"] == [24, 32] and info["calibration"]["model"] == "radtan"
    with pytest.raises(ConfigError, match="exactly one of --intrinsics FX FY CX CY, --hfov DEG and --calibration"):
        options(tmp_path, calibration=path)
