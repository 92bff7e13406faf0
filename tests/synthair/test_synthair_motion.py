"""SynthAir motion profiles (``--motion``) and frame steps (``--frame-step``) on flights planned without rendering:
the warped timeline, hover, yaw in place, slow and fast flight, ramps, and the CSV rows at other frame steps."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from cosemdepth.data.midair.splits import Trajectory, relative_motions, trajectory_rows
from cosemdepth.data.quaternion import qmatrix
from cosemdepth.errors import ConfigError
from cosemdepth.synthair.motion import parse_motion, timeline
from cosemdepth.synthair.raymarch import surface_height
from cosemdepth.synthair.writer import SynthConfig, check_output_folder, plan_flights, rendered_frames

CAM_FROM_BODY = np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]])  # camera x = body y, y = body z, z = body x


def _flights(world, motion=None, frames=None, climates=("sunny",), trajectories=1, **kw):
    cfg = SynthConfig(
        out=Path("unused"), trajectories=trajectories, frames=frames, climates=climates, motion=motion, **kw
    )
    cfg.validate()
    return cfg, [p.flight for fl in plan_flights(cfg, world).values() for p in fl.values()]


def _rows(flight, frame_step=4):
    """CSV rows of a planned flight as arrays: (frame of each row, q [R, 4], t [R, 3])."""
    rows = trajectory_rows(Trajectory("SynthAir", "sunny", 0, 0), flight.attitude, flight.position, frame_step)
    frames = np.array([int(r["camera_l"][-11:-5]) for r in rows])
    q = np.array([[r["qw"], r["qx"], r["qy"], r["qz"]] for r in rows])
    t = np.array([[r["tx"], r["ty"], r["tz"]] for r in rows])
    return frames, q, t


def _angle_deg(q):
    return np.degrees(2 * np.arccos(np.clip(np.abs(q[..., 0]), 0.0, 1.0)))


# ----------------------------------------------------------------------------------------------------------------
# the grammar


def test_specs_parse_to_segments_with_a_canonical_form():
    p = parse_motion(" fly:20, hover:8,yaw:8,yaw:4@-30.5,fly*0.25:16,fly*2:4,ramp*0-1.5:10,fly*1:2")
    assert [(s.kind, s.frames, s.speed, s.degrees) for s in p.segments] == [
        ("fly", 20, (1.0, 1.0), 0.0),
        ("hover", 8, (0.0, 0.0), 0.0),
        ("yaw", 8, (0.0, 0.0), 90.0),
        ("yaw", 4, (0.0, 0.0), -30.5),
        ("fly", 16, (0.25, 0.25), 0.0),
        ("fly", 4, (2.0, 2.0), 0.0),
        ("ramp", 10, (0.0, 1.5), 0.0),
        ("fly", 2, (1.0, 1.0), 0.0),
    ]
    assert p.frames == 20 + 8 + 8 + 4 + 16 + 4 + 10 + 2
    assert p.spec == "fly:20,hover:8,yaw:8@90,yaw:4@-30.5,fly*0.25:16,fly*2:4,ramp*0-1.5:10,fly:2"
    assert parse_motion(p.spec) == p
    assert p.metadata()["segments"][:3] == [
        {"segment": "fly:20", "frames": [0, 20]},
        {"segment": "hover:8", "frames": [20, 28]},
        {"segment": "yaw:8@90", "frames": [28, 36]},
    ]


@pytest.mark.parametrize(
    "spec, bad",
    [
        ("fly:20,hover", "hover"),
        ("fly:20,hover:0", "hover:0"),
        ("fly*0:10", "fly*0:10"),
        ("fly*-1:10", "fly*-1:10"),
        ("fly*11:10", "fly*11:10"),
        ("walk:5", "walk:5"),
        ("fly:20,,fly:3", "''"),
        ("yaw:2@-200", "yaw:2@-200"),
        ("ramp*1:10", "ramp*1:10"),
        ("ramp*1-20:10", "ramp*1-20:10"),
        ("fly:2.5", "fly:2.5"),
        ("yaw:4@nan", "yaw:4@nan"),
    ],
)
def test_bad_specs_name_the_option_and_the_segment(spec, bad):
    with pytest.raises(ConfigError) as e:
        parse_motion(spec)
    msg = str(e.value)
    assert msg.startswith("--motion: bad segment ") and bad in msg and "\n" not in msg
    with pytest.raises(ConfigError, match="--motion"):
        parse_motion("  ")


def test_frames_must_match_the_segments_when_both_are_given():
    assert SynthConfig(out=Path("x"), motion="fly:10,hover:6").frames == 16
    assert SynthConfig(out=Path("x"), motion="fly:10,hover:6", frames=16).frames == 16
    assert SynthConfig(out=Path("x")).frames == 200
    with pytest.raises(ConfigError, match=r"--frames 20 does not match --motion 'fly:10,hover:6'.* 16 frames"):
        SynthConfig(out=Path("x"), motion="fly:10,hover:6", frames=20)


def test_timeline_is_the_integral_of_the_speed_multiplier():
    """Hand-computed progress (in 100 Hz samples) of fly*0.5:1, hover:1, ramp*0-1:1, yaw:1@90, fly:1."""
    tl = timeline(parse_motion("fly*0.5:1,hover:1,ramp*0-1:1,yaw:1@90,fly:1"))
    ramp = [2 + u * u / 8 for u in range(4)]  # tau0 + u^2 / (2 L) with L = 4 samples
    np.testing.assert_allclose(tl.tau, [0, 0.5, 1, 1.5, 2, 2, 2, 2, *ramp, 4, 4, 4, 4, 4, 5, 6, 7])
    np.testing.assert_allclose(np.degrees(tl.yaw), [0] * 12 + [0, 22.5, 45, 67.5] + [90] * 4)
    assert tl.turns == ((4.0, math.pi / 2),)
    assert tl.base_samples == 8 and tl.base_frames == 2


# ----------------------------------------------------------------------------------------------------------------
# flights


def test_without_a_profile_and_with_plain_fly_the_flight_is_the_normal_one(world):
    _, (plain,) = _flights(world, frames=24)
    _, (fly,) = _flights(world, motion="fly:24")
    for name in ("attitude", "position", "velocity", "acceleration", "angular_velocity"):
        assert np.array_equal(getattr(plain, name), getattr(fly, name)), name


def test_half_speed_flies_the_base_flight_at_half_the_frame_times(world):
    """fly*0.5: camera frame k (sample 4k) is where the base flight (same seed) is at time k/2, i.e. sample 2k;
    the samples between are on the base path, at half its velocity."""
    cfg, (slow,) = _flights(world, motion="fly*0.5:40")
    tl = timeline(cfg.motion_profile)
    assert tl.base_frames == 21  # samples up to tau = 0.5 * 159 = 79.5 -> 81 samples
    _, (base,) = _flights(world, frames=tl.base_frames)
    assert len(slow) == 160
    k = np.arange(40)
    assert np.array_equal(slow.position[4 * k], base.position[2 * k])
    assert np.array_equal(slow.attitude[4 * k], base.attitude[2 * k])
    # half-integer progress: between the two base samples, close to their mean (a smooth path, 6-13 cm apart)
    mid = 0.5 * (base.position[2 * k[:-1]] + base.position[2 * k[:-1] + 1])
    assert np.abs(slow.position[4 * k[:-1] + 1] - mid).max() < 1e-3
    np.testing.assert_allclose(slow.velocity[2:158:2], 0.5 * base.velocity[1:79], rtol=0, atol=5e-3)
    np.testing.assert_allclose(np.linalg.norm(slow.attitude, axis=1), 1.0, atol=1e-12)


def test_a_hover_holds_position_and_attitude_exactly(world):
    """fly:12, hover:8, fly:12: frames 12..20 are one pose; the CSV rows inside have zero translation and the
    identity rotation; the 100 Hz records are still and the velocity is zero there."""
    _, (f,) = _flights(world, motion="fly:12,hover:8,fly:12")
    still = slice(48, 81)  # samples 4 * 12 .. 4 * 20
    assert (f.position[still] == f.position[48]).all() and (f.attitude[still] == f.attitude[48]).all()
    inside = slice(49, 80)
    assert (f.velocity[inside] == 0).all() and (f.acceleration[inside.start + 1 : inside.stop - 1] == 0).all()
    assert (f.angular_velocity[inside] == 0).all()
    frames, q, t = _rows(f)
    hover = (frames > 12) & (frames <= 20)
    assert list(frames[hover]) == [16, 20]
    assert (t[hover] == 0).all() and (q[hover] == [1, 0, 0, 0]).all()
    assert (np.linalg.norm(t[~hover], axis=1) > 0.2).all()  # the flight moves before and after


def test_a_yaw_turns_in_place_about_the_world_vertical_at_a_constant_rate(world):
    """fly:12, yaw:8@60, fly:20 with frame step 2: the rows inside the yaw have zero translation and rotate by
    60 / 8 * 2 = 15 degrees each, about the world vertical (+z down) seen from the camera; the flight then goes on
    in the new direction: its horizontal velocity is the base flight's turned by 60 degrees."""
    cfg, (f,) = _flights(world, motion="fly:12,yaw:8@60,fly:20", frame_step=2)
    frames, q, t = _rows(f, frame_step=2)
    yaw = (frames > 12) & (frames <= 20)
    assert list(frames[yaw]) == [14, 16, 18, 20]
    assert (t[yaw] == 0).all()
    np.testing.assert_allclose(_angle_deg(q[yaw]), 60 / 8 * 2, atol=1e-6)
    for frame, qr in zip(frames[yaw], q[yaw]):
        a = 4 * (frame - 2)  # the row's previous frame
        down_in_camera = CAM_FROM_BODY @ qmatrix(f.attitude[a]).T @ np.array([0.0, 0.0, 1.0])
        axis = qr[1:] / np.linalg.norm(qr[1:]) * np.sign(qr[0])
        np.testing.assert_allclose(axis, down_in_camera, atol=1e-6)  # positive turn about +z down: to the right
    # the body angular velocity during the turn: 60 degrees over 8 frames (0.32 s) about the vertical
    rate = np.linalg.norm(f.angular_velocity[50:78], axis=1)
    np.testing.assert_allclose(rate, math.radians(60) / 0.32, rtol=1e-3)
    # after the turn: the base path (same seed), turned by 60 degrees about the point where the drone turned
    tl = timeline(cfg.motion_profile)
    _, (base,) = _flights(world, frames=tl.base_frames)
    c, s = math.cos(math.radians(60)), math.sin(math.radians(60))
    turn = np.array([[c, -s], [s, c]])
    after = np.arange(84, 4 * 40 - 2)  # samples of the last fly segment (tau integral: 48 + j - 80)
    tau = (after - 32).astype(int)
    np.testing.assert_allclose(f.velocity[after, :2], base.velocity[tau, :2] @ turn.T, atol=1e-6)
    pivot = base.position[48, :2]
    np.testing.assert_allclose(f.position[after, :2], (base.position[tau, :2] - pivot) @ turn.T + pivot, atol=1e-9)
    forward = qmatrix(f.attitude[after])[:, :, 0]
    assert ((f.velocity[after] * forward).sum(1) > 0).all()  # flying forwards again


def test_turned_flights_keep_their_clearance(world):
    """The height above the surface is computed over the turned path: the camera stays above everything."""
    _, flights = _flights(world, motion="fly:20,yaw:10@120,fly:40,yaw:6@-90,fly:24", trajectories=4)
    for f in flights:
        s = surface_height(world, torch.tensor(f.position[:, :2].T, dtype=torch.float32)).double().numpy()
        assert (-f.position[:, 2] - s).min() > 0.2, f.mode


def test_slow_and_fast_segments_scale_the_per_row_translation(world):
    _, (f,) = _flights(world, motion="fly:20,fly*0.25:20,fly*2:20")
    frames, _, t = _rows(f)
    step = np.linalg.norm(t, axis=1)
    normal, slow, fast = step[frames <= 20], step[(frames > 20) & (frames <= 40)], step[frames > 40]
    assert len(normal) == 5 and len(slow) == 5 and len(fast) == 4
    assert 0.2 < slow.mean() / normal.mean() < 0.3 and 1.7 < fast.mean() / normal.mean() < 2.3


def test_a_ramp_speeds_up_monotonically_at_the_multiplier_s_rate(world):
    """ramp*0.25-2:40 after fly:8: the speed is the base speed times 0.25 + 1.75 u / 160 (u samples into the
    ramp), and the per-row translation grows from row to row."""
    cfg, (f,) = _flights(world, motion="fly:8,ramp*0.25-2:40,fly*2:8")
    tl = timeline(cfg.motion_profile)
    _, (base,) = _flights(world, frames=tl.base_frames)
    frames, _, t = _rows(f)
    step = np.linalg.norm(t, axis=1)
    inside = step[(frames > 8) & (frames <= 48)]
    assert len(inside) == 10 and (np.diff(inside) > 0).all()
    u = np.arange(4, 157)
    multiplier = 0.25 + 1.75 * u / 160
    base_speed = np.linalg.norm(base.velocity, axis=1)
    expected = multiplier * np.interp(tl.tau[32 + u], np.arange(len(base_speed)), base_speed)
    np.testing.assert_allclose(np.linalg.norm(f.velocity[32 + u], axis=1), expected, rtol=0.01)


# ----------------------------------------------------------------------------------------------------------------
# frame steps


def test_frame_step_2_gives_twice_the_rows_at_half_the_translation(world):
    """Step 2: rows at frames 2, 4, ..., each holding the motion between frames 2 apart; two consecutive rows
    compose into the step-4 row (X_a = R1 X_b + t1, X_b = R2 X_c + t2 -> X_a = R1 R2 X_c + R1 t2 + t1)."""
    _, (f,) = _flights(world, frames=40)
    f4, q4, t4 = _rows(f, 4)
    f2, q2, t2 = _rows(f, 2)
    assert list(f4) == list(range(4, 40, 4)) and list(f2) == list(range(2, 40, 2))
    assert len(f2) == 19 and len(f4) == 9
    ratio = np.linalg.norm(t2, axis=1)[1::2][: len(t4)] / np.linalg.norm(t4, axis=1)
    assert (0.4 < ratio).all() and (ratio < 0.6).all()
    r2 = qmatrix(q2)
    for k in range(len(f4)):
        a, b = 2 * k, 2 * k + 1
        np.testing.assert_allclose(r2[a] @ r2[b], qmatrix(q4[k]), atol=2e-6)
        np.testing.assert_allclose(r2[a] @ t2[b] + t2[a], t4[k], atol=2e-6)
    # against the 100 Hz records directly: row k joins samples 8k and 8k + 8
    q, t = relative_motions(f.attitude, f.position, stride=8)
    np.testing.assert_allclose(q, q2, atol=1e-12)
    np.testing.assert_allclose(t, t2, atol=1e-12)


def test_frame_step_sets_the_rendered_frames_and_the_minimum_length():
    cfg = SynthConfig(out=Path("x"), frames=24, frame_step=8)  # floor(24 / 8) - 1 rows, as Mid-Air's rule
    assert rendered_frames(cfg) == [8, 16]
    assert rendered_frames(SynthConfig(out=Path("x"), frames=9, frame_step=3)) == [3, 6]
    with pytest.raises(ConfigError, match=r"--frames must be an integer in \[16, 1000000\].*frames 0 and 8"):
        SynthConfig(out=Path("x"), frames=12, frame_step=8).validate()
    for bad in (0, -2, 2.0, 251):
        with pytest.raises(ConfigError, match="--frame-step"):
            SynthConfig(out=Path("x"), frames=40, frame_step=bad).validate()


def test_the_metadata_records_motion_and_frame_step_and_resuming_compares_them(tmp_path):
    plain = SynthConfig(out=tmp_path / "ds", frames=16, size=16)
    assert "motion" not in plain.metadata() and "frame_step" not in plain.metadata()
    cfg = SynthConfig(out=tmp_path / "ds", size=16, motion="fly:8,hover:8", frame_step=2)
    meta = cfg.metadata()
    assert meta["frame_step"] == 2 and meta["frames"] == 16
    assert meta["motion"] == {
        "spec": "fly:8,hover:8",
        "segments": [{"segment": "fly:8", "frames": [0, 8]}, {"segment": "hover:8", "frames": [8, 16]}],
    }
    import json

    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "synthair.json").write_text(json.dumps(meta))
    assert check_output_folder(cfg) is True
    with pytest.raises(ConfigError, match="different frame_step, motion"):
        check_output_folder(plain)


# ----------------------------------------------------------------------------------------------------------------
# end to end: the command, the files, the Mid-Air reader


def test_synth_writes_a_profile_at_another_frame_step_that_the_reader_streams(world, tmp_path, capsys):
    """fly:8, hover:4, yaw:4@40, fly*0.5:8 at frame step 2 (16 px): 11 rows at frames 2, 4, ..., 22; the hover
    frames are one image, the yaw rows turn by 40 / 4 * 2 = 20 degrees in place; every row the Mid-Air reader
    streams is the relative pose of the two frames it joins, from the 100 Hz records."""
    import h5py

    from cosemdepth.cli.main import main
    from cosemdepth.data import open_dataset

    out = tmp_path / "ds"
    spec = "fly:8,hover:4,yaw:4@40,fly*0.5:8"
    assert (
        main(
            [
                "synth",
                "--out",
                str(out),
                "--trajectories",
                "1",
                "--size",
                "16",
                "--climates",
                "sunny",
                "--motion",
                spec,
                "--frame-step",
                "2",
                "--no-progress",
            ]
        )
        == 0
    )
    capsys.readouterr()
    meta = json.loads((out / "synthair.json").read_text())
    assert meta["frames"] == 24 and meta["frame_step"] == 2 and meta["motion"]["spec"] == spec
    color = out / "SynthAir/sunny/color_left/trajectory_0000"
    assert sorted(p.name for p in color.iterdir()) == [f"{k:06d}.JPEG" for k in range(2, 24, 2)]
    hover = [(color / f"{k:06d}.JPEG").read_bytes() for k in (8, 10, 12)]
    assert hover[0] == hover[1] == hover[2] != (color / "000014.JPEG").read_bytes()
    with h5py.File(out / "SynthAir/sunny/sensor_records.hdf5", "r") as h5:
        att = h5["trajectory_0000/groundtruth/attitude"][()]
        pos = h5["trajectory_0000/groundtruth/position"][()]
        vel = h5["trajectory_0000/groundtruth/velocity"][()]
        listed = [v.decode() for v in h5["trajectory_0000/camera_data/color_left"][()]]
    assert att.shape == (96, 4) and listed == [f"color_left/trajectory_0000/{k:06d}.JPEG" for k in range(2, 24, 2)]
    assert (vel[33:48] == 0).all() and (pos[32:65] == pos[32]).all()  # hover and yaw: frames 8 .. 16
    ds = open_dataset("synthair", out, split_dir=out / "splits", split="test", seq_len=1, size=128)
    assert len(ds) == 11
    rot = qmatrix(att)
    for k in range(len(ds)):
        item = ds[k]
        a, b = 8 * k, 8 * k + 8  # frames 2k and 2k + 2
        r_cam = CAM_FROM_BODY @ rot[a].T @ rot[b] @ CAM_FROM_BODY.T
        t_cam = CAM_FROM_BODY @ rot[a].T @ (pos[b] - pos[a])
        np.testing.assert_allclose(qmatrix(item["rot"][0].double().numpy()), r_cam, atol=1e-5)
        np.testing.assert_allclose(item["trans"][0].double().numpy(), t_cam, atol=1e-5)
        assert item["rgb"].shape == (1, 3, 128, 128)
        frame = 2 * (k + 1)
        if 8 < frame <= 16:
            assert (item["trans"][0] == 0).all()
            assert abs(_angle_deg(item["rot"][0].double().numpy()) - (20.0 if frame > 12 else 0.0)) < 1e-3
        else:
            assert item["trans"][0].norm() > 0.05
