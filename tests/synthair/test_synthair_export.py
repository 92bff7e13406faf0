"""``cosemdepth synth --export``: the video and the logs of one flight, with a mounted camera and a time offset.
The libraries' readers (PyAV, pyulog, pymavlink) read what the project's writers wrote, and read_log reads the
body's exact poses back; the video shows the mounted camera's view at exact frame times."""

from __future__ import annotations

import csv
import json
from fractions import Fraction

import av
import h5py
import numpy as np
import pytest
import pyulog
from pymavlink import mavutil

from cosemdepth.cli.main import main
from cosemdepth.flightlogs import read_log
from cosemdepth.geometry.attitude import quat_to_matrix
from cosemdepth.geometry.mount import camera_poses, optical_to_camera_frd, parse_mount
from cosemdepth.synthair.climate import get_climate
from cosemdepth.synthair.export import BOOT_OFFSET_S, RATES, Truth
from cosemdepth.synthair.render import render_frame
from cosemdepth.synthair.writer import SynthConfig, generate, plan_flights

MOUNT = "down@0.3,0,0.1"
OFFSET = 0.2
FPS = 25


@pytest.fixture(scope="module")
def flight(world, tmp_path_factory):
    out = tmp_path_factory.mktemp("export") / "ds"
    cfg = SynthConfig(
        out=out,
        trajectories=1,
        frames=16,
        size=32,
        climates=("sunny",),
        camera_mount=MOUNT,
        export=("mp4", "ulog", "dataflash", "tlog", "srt"),
        time_offset=OFFSET,
        fps=str(FPS),
    )
    generate(cfg, progress=False)
    folder = out / "SynthAir/sunny/flight_export/trajectory_0000"
    rows = list(csv.DictReader(open(folder / "truth.csv")))
    truth = {
        k: np.array([[float(r[f"{k}{c}"]) for c in cols] for r in rows])
        for k, cols in (("body_q", "wxyz"), ("camera_q", "wxyz"))
    }
    for k in ("body", "camera"):
        truth[k] = np.array([[float(r[f"{k}_{c}"]) for c in "xyz"] for r in rows])
    for k in ("video_time_s", "log_time_s", "midair_frame"):
        truth[k] = np.array([float(r[k]) for r in rows])
    planned = plan_flights(cfg, world)["sunny"][0]
    return {"cfg": cfg, "out": out, "folder": folder, "truth": truth, "planned": planned}


def angle_deg(q1, q2):
    rel = np.transpose(quat_to_matrix(q1), (0, 2, 1)) @ quat_to_matrix(q2)
    return np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))


def test_the_export_is_recorded_and_the_frames_are_on_the_log_clock(flight):
    meta = json.loads((flight["out"] / "synthair.json").read_text())
    assert meta["export"]["formats"] == ["mp4", "ulog", "dataflash", "tlog", "srt"]
    assert meta["camera_mount"]["spec"] == MOUNT and meta["camera_mount"]["lever_arm_m"] == [0.3, 0.0, 0.1]
    export = json.loads((flight["folder"] / "export.json").read_text())
    t = flight["truth"]
    n = len(t["video_time_s"])
    assert export["frames"] == n == 11  # 0.2 s to 0.63 s of a 16-frame flight at 25 fps
    np.testing.assert_allclose(t["video_time_s"], np.arange(n) / FPS, atol=1e-12)
    np.testing.assert_allclose(t["log_time_s"], np.arange(n) / FPS + OFFSET + BOOT_OFFSET_S, atol=1e-9)
    assert export["video_start_log_time_s"] == OFFSET + BOOT_OFFSET_S
    # frame k is at flight time 0.2 + k / 25: Mid-Air frames 5 + k; the CSV frames rendered are 4, 8, 12
    assert t["midair_frame"].tolist() == [-1, -1, -1, 8, -1, -1, -1, 12, -1, -1, -1]


def test_the_camera_is_the_mount_on_the_body_by_hand(flight):
    t = flight["truth"]
    r_body, r_cam = quat_to_matrix(t["body_q"]), quat_to_matrix(t["camera_q"])
    np.testing.assert_allclose(r_cam[:, :, 2], r_body[:, :, 2], atol=1e-12)  # looks along the body's down axis
    np.testing.assert_allclose(r_cam[:, :, 1], -r_body[:, :, 0], atol=1e-12)  # image down = the body's back
    lever = np.einsum("nij,j->ni", r_body, [0.3, 0.0, 0.1])
    np.testing.assert_allclose(t["camera"], t["body"] + lever, atol=1e-9)


def test_the_midair_tree_is_rendered_from_the_camera(flight):
    t = flight["truth"]
    with h5py.File(flight["out"] / "SynthAir/sunny/sensor_records.hdf5") as h5:
        att = h5["trajectory_0000/groundtruth/attitude"][:]
        pos = h5["trajectory_0000/groundtruth/position"][:]
    for k in np.flatnonzero(t["midair_frame"] >= 0):
        n = int(t["midair_frame"][k])
        cam_frd = optical_to_camera_frd(t["camera_q"][k : k + 1])
        assert angle_deg(att[4 * n : 4 * n + 1], cam_frd)[0] < 1e-6
        np.testing.assert_allclose(pos[4 * n], t["camera"][k], atol=1e-9)


def test_the_video_has_exact_frame_times_and_shows_the_mounted_camera_s_view(flight, world):
    t = flight["truth"]
    with av.open(str(flight["folder"] / "video.mp4")) as c:
        stream = c.streams.video[0]
        assert stream.codec_context.name == "h264" and (stream.width, stream.height) == (32, 32)
        frames = [(f.pts * f.time_base, f.to_ndarray(format="rgb24")) for f in c.decode(video=0)]
    assert [ts for ts, _ in frames] == [Fraction(k, FPS) for k in range(len(t["video_time_s"]))]
    climate = get_climate("sunny").with_sun_azimuth(flight["planned"].sun_azimuth)
    for k in (0, 6):
        q_frd = optical_to_camera_frd(t["camera_q"][k : k + 1])[0]
        mounted = render_frame(world, climate, q_frd, t["camera"][k], 32, 32).rgb.astype(float)
        forward = render_frame(world, climate, t["body_q"][k], t["body"][k], 32, 32).rgb.astype(float)
        err = np.abs(frames[k][1] - mounted).mean()
        assert err < 4.0  # H.264 at this size
        assert np.abs(frames[k][1] - forward).mean() > 4 * err  # not the unmounted view


def test_the_libraries_read_the_logs(flight):
    folder = flight["folder"]
    duration = Truth(flight["planned"].flight).duration
    ulog = pyulog.ULog(str(folder / "flight.ulg"))
    assert not ulog.file_corruption
    counts = {d.name: len(d.data["timestamp"]) for d in ulog.data_list}
    for name, rate in RATES["ulog"].items():
        assert abs(counts[name] - rate * duration) <= 1.5, name
    for path, kinds in (
        (folder / "flight.bin", ("ATT", "XKF1", "POS", "GPS")),
        (folder / "flight.tlog", ("ATTITUDE",)),
    ):
        log = mavutil.mavlink_connection(str(path))
        seen = {}
        while (m := log.recv_match(type=list(kinds))) is not None:
            seen[m.get_type()] = seen.get(m.get_type(), 0) + 1
        assert set(seen) == set(kinds), path
    assert seen["ATTITUDE"] == pytest.approx(RATES["tlog"]["ATTITUDE"] * duration, abs=1.5)


@pytest.mark.parametrize(
    "name, angle_tol, pos_tol",
    [("flight.ulg", 1e-5, 2e-5), ("flight.bin", 0.01, 1e-4), ("flight.tlog", 1e-4, 1e-4)],
)
def test_read_log_gives_the_exact_body_poses_at_the_log_s_samples(flight, name, angle_tol, pos_tol):
    """At its own sample times each log holds the trajectory's pose to the format's precision (float32, the
    DataFlash's centidegrees); the positions are metres from the flight's start (the estimator's origin)."""
    log = read_log(flight["folder"] / name)
    truth = Truth(flight["planned"].flight)
    origin = np.array(json.loads((flight["folder"] / "export.json").read_text())["origin_ned"])
    q, _ = truth.body(log.attitude.t - BOOT_OFFSET_S)
    assert angle_deg(log.attitude.v, q).max() < angle_tol
    _, p = truth.body(log.position.t - BOOT_OFFSET_S)
    np.testing.assert_allclose(log.position.v, p - origin, atol=pos_tol)
    # the samples are not on the frames' grid
    phase = np.mod(log.attitude.t - OFFSET - BOOT_OFFSET_S, 1 / FPS)
    assert np.ptp(phase) > 0.5 / FPS


@pytest.mark.parametrize("name", ["flight.ulg", "flight.bin", "flight.tlog"])
def test_the_video_frames_poses_from_the_log_and_the_mount(flight, name):
    """What predict --flight does: the log's poses at the frames' log times, the mount applied: the camera of
    every video frame, within the interpolation between samples."""
    t = flight["truth"]
    log = read_log(flight["folder"] / name)
    q, p, ok = log.pose_at(t["log_time_s"])
    assert ok.all()
    mount = parse_mount(MOUNT)
    q_cam, p_cam = camera_poses(q, p, mount.R_body_optical, mount.lever_arm)
    assert angle_deg(q_cam, t["camera_q"]).max() < 0.05
    origin = np.array(json.loads((flight["folder"] / "export.json").read_text())["origin_ned"])
    np.testing.assert_allclose(p_cam, t["camera"] - origin, atol=0.01)


def test_the_srt_gives_the_camera_s_attitude_and_the_positions(flight):
    t = flight["truth"]
    log = read_log(flight["folder"] / "video.SRT")
    q, p, ok = log.pose_at(t["video_time_s"])
    g, ok_g = log.gimbal_at(t["video_time_s"])
    assert ok.all() and ok_g.all()
    q_cam, _ = camera_poses(q, p, parse_mount("forward").R_body_optical, gimbal_q=g)  # the mount is replaced
    assert angle_deg(q_cam, t["camera_q"]).max() < 0.1  # angles printed to 0.1 degree
    np.testing.assert_allclose(p, t["body"] - t["body"][0], atol=0.1 + 0.02)  # 1e-6 degrees, mm altitudes
    assert log.position_resolution_m == pytest.approx(0.11132, rel=1e-3)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--fps", "30"], "--fps applies only with --export"),
        (["--time-offset", "1"], "--time-offset applies only with --export"),
        (["--export", "mp4,mkv"], "--export: unknown format(s) ['mkv']"),
        (["--export", "mp4", "--size", "17"], "--export mp4 needs an even --size"),
        (["--export", "ulog", "--frames", "16", "--time-offset", "0.7"], "--time-offset 0.7 leaves fewer than 2"),
        (["--export", "ulog", "--fps", "fast"], "--fps must be a frame rate such as 25"),
        (["--camera-mount", "sideways"], "--camera-mount 'sideways': not forward, down, R,P,Y"),
    ],
)
def test_bad_export_arguments_are_one_line_errors(tmp_path, capsys, argv, message):
    out = tmp_path / "ds"
    assert main(["synth", "--out", str(out), "--no-progress", "--size", "16", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cosemdepth synth: error: ") and message in err and err.count("\n") == 1
    assert not out.exists()


def test_the_default_set_records_no_mount_and_no_export(tmp_path):
    meta = SynthConfig(out=tmp_path).metadata()
    assert "camera_mount" not in meta and "export" not in meta
