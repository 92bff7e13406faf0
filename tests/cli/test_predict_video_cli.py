"""``predict --flight --images VIDEO --log FILE``: outputs named by the frame's index, each frame's presentation and
log times and the clock offset in predictions.json, frames outside the log, a log without positions, rotation
metadata, and bad input (one line, exit 2, nothing written)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "streaming"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "data"))
from _outputs import _one_thread, model_dir  # noqa: E402, F401 (pytest fixtures)
from _video_flights import LOG_START, write_log, write_video  # noqa: E402
from _videos import with_rotation  # noqa: E402

from cosemdepth.cli.main import main  # noqa: E402


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    d = tmp_path_factory.mktemp("flight")
    return write_video(d / "clip.mp4", n=12), write_log(d / "log.ulg")


def predict(model_dir, video, log, out, *extra) -> int:
    argv = ["predict", "--model", str(model_dir), "--flight", "--images", str(video)]
    argv += [] if log is None else ["--log", str(log)]
    return main([*argv, "--hfov", "90", "--out", str(out), "--video", "none", "--no-progress", *map(str, extra)])


def manifest(out: Path) -> dict:
    return json.loads((out / "predictions.json").read_text())


def test_outputs_are_named_by_the_frame_index_with_their_times(model_dir, flight, tmp_path, capsys):
    video, log = flight
    out = tmp_path / "out"
    assert predict(model_dir, video, log, out, "--time-offset", "10.5", "--frame-skip", "3") == 0
    printed = capsys.readouterr().out
    assert "; video: 4 frames, clock offset 10.500 s (given)" in printed
    m = manifest(out)
    assert [Path(f["files"]["depth"]).name for f in m["frames"]] == [
        "000000.npy",
        "000003.npy",
        "000006.npy",
        "000009.npy",
    ]
    assert all((out / f["files"]["depth"]).is_file() and (out / f["files"]["labels"]).is_file() for f in m["frames"])
    assert [f["frame"] for f in m["frames"]] == [0, 1, 2, 3]
    assert [f["pts_s"] for f in m["frames"]] == pytest.approx([0.0, 0.12, 0.24, 0.36])
    assert [f["log_time_s"] for f in m["frames"]] == pytest.approx([10.5, 10.62, 10.74, 10.86])
    run = m["run"]
    assert run["time_offset_s"] == 10.5 and run["time_offset_confidence"] is None
    assert run["log_format"] == "ulog" and run["camera_mount"] == "forward" and run["frame_skip"] == 3
    assert m["dataset"]["video"]["frames"] == 12 and m["dataset"]["time_offset"]["method"] == "given (--time-offset)"


def test_frames_before_the_log_are_resets_without_depth(model_dir, flight, tmp_path, capsys):
    video, log = flight
    out = tmp_path / "out"
    assert predict(model_dir, video, log, out, "--time-offset", LOG_START - 0.2, "--policy", "every-frame") == 0
    assert "; 5 frames outside the log (resets without depth)" in capsys.readouterr().out
    frames = manifest(out)["frames"]
    assert [f["status"] for f in frames[:6]] == ["reset"] * 6  # 5 outside, then the first covered frame
    assert all(f["valid_fraction"] == 0 for f in frames[:6]) and frames[6]["status"] == "estimated"
    assert frames[0]["depth_invalid_reason"].startswith("outside the log (log time 4.800 s")
    assert "depth_invalid_reason" not in frames[6]


def test_a_log_without_positions_gives_labels_and_no_depth(model_dir, flight, tmp_path, capsys):
    video, _ = flight
    log = write_log(tmp_path / "attitude.ulg", positions=False)
    out = tmp_path / "out"
    assert predict(model_dir, video, log, out, "--time-offset", "10", "--policy", "every-frame") == 0
    printed = capsys.readouterr()
    assert "no depth: the log has no positions (attitude only)" in printed.out
    assert printed.err.strip() == (
        "cosemdepth predict: warning: no depth was produced: the log has no positions (attitude only): the camera's "
        "translation between frames is unknown"
    )
    frames = manifest(out)["frames"]
    assert {f["status"] for f in frames} == {"reset"} and all(f["valid_fraction"] == 0 for f in frames)
    assert all((out / f["files"]["labels"]).is_file() for f in frames)


def test_rotation_metadata_turns_the_frames(model_dir, flight, tmp_path):
    video, log = flight
    turned = with_rotation(video, tmp_path / "portrait.mp4", 90)
    out = tmp_path / "out"
    assert predict(model_dir, turned, log, out, "--time-offset", "10", "--size", "32x24", "--max-frames", "2") == 0
    m = manifest(out)
    assert m["dataset"]["video"]["size"] == [64, 48] and m["dataset"]["video"]["rotation_deg"] == 90
    assert np.load(out / m["frames"][0]["files"]["depth"]).shape == (32, 24)


@pytest.mark.parametrize(
    "extra, log, message",
    [
        ((), None, "--images {video} is a video: give the flight controller's log with --log FILE"),
        (("--poses", "p.txt"), "log", "--poses applies to a folder of images with a pose file, not to a video"),
        (("--time-offset", "soon"), "log", "--time-offset must be seconds or 'auto', got 'soon'"),
        (("--time-offset", "100"), "log", "{log}: the log (5.000 .. 19.990 s) does not cover the video"),
        (("--camera-mount", "sideways"), "log", "--camera-mount 'sideways': not forward, down, R,P,Y"),
        (("--log-format", "tlog"), "log", "{log}: not a tlog log (its content is that of a ulog log)"),
        (("--calibration", "cam.yaml"), "log", "exactly one of --intrinsics FX FY CX CY, --hfov DEG and --calibration"),
        (("--jpeg-idct", "accurate"), "log", "--jpeg-idct applies to JPEG images, not to a video"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(model_dir, flight, tmp_path, capsys, extra, log, message):
    video, log_path = flight
    out = tmp_path / "out"
    assert predict(model_dir, video, None if log is None else log_path, out, *extra) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message.format(video=video, log=log_path) in err[0], err
    assert not out.exists()


def test_a_flight_that_does_not_turn_asks_for_the_offset(model_dir, tmp_path, capsys):
    video = write_video(tmp_path / "still.mp4", n=40)  # a pattern moving sideways: no rotation in the log to match

    def still(t):
        return np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1)), np.zeros((len(t), 3))

    log = write_log(tmp_path / "still.ulg", still)
    out = tmp_path / "out"
    assert predict(model_dir, video, log, out) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "cannot find the clock offset of" in line and line.endswith(
        "give --time-offset SECONDS (the log time of the video's first frame)"
    )
    assert not out.exists()


def test_log_flags_do_not_apply_to_a_folder(model_dir, tmp_path, capsys):
    images = tmp_path / "images"
    images.mkdir()
    argv = ["predict", "--model", str(model_dir), "--flight", "--images", str(images), "--poses", "p.txt"]
    assert main([*argv, "--hfov", "90", "--out", str(tmp_path / "o"), "--log", "x.ulg"]) == 2
    assert capsys.readouterr().err.strip() == (
        "cosemdepth predict: error: --log applies to a video (--images VIDEO with --log), not to a folder of images"
    )


def test_a_truncated_video(model_dir, flight, tmp_path, capsys):
    video, log = flight
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(video.read_bytes()[:2000])
    assert predict(model_dir, cut, log, tmp_path / "out", "--time-offset", "10") == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"{cut}: cannot read the video" in line
