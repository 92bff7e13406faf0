"""``cosemdepth synth``: the command line, its output and its errors."""

from __future__ import annotations

import json

import pytest

from cosemdepth.cli.main import main


def test_synth_writes_a_dataset_and_says_where_the_splits_are(world, tmp_path, capsys):
    out = tmp_path / "ds"
    rc = main(
        [
            "synth",
            "--out",
            str(out),
            "--trajectories",
            "1",
            "--frames",
            "12",
            "--size",
            "16",
            "--seed",
            "0",
            "--climates",
            "sunny",
            "cloudy",
        ]
    )
    assert rc == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out.splitlines()[0])
    assert summary["frames_rendered"] == summary["frames_total"] == 4  # 2 climates x CSV rows (frames 4, 8)
    assert f"split CSVs: {out / 'splits'}" in captured.out
    assert "synthair" in captured.err  # the progress bar
    assert (out / "splits/test_data/SynthAir/sunny/traj_0000.csv").is_file()
    assert (out / "splits/test_data/SynthAir/cloudy/traj_0000.csv").is_file()
    assert (out / "SynthAir/cloudy/color_left/trajectory_3000/000008.JPEG").is_file()
    meta = json.loads((out / "synthair.json").read_text())
    assert meta["seed"] == 0 and meta["size"] == 16 and meta["climates"] == ["sunny", "cloudy"]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--size", "8"], "--size must be an integer in [16, 4096]"),
        (["--frames", "7"], "--frames must be an integer in [8, 1000000]"),
        (["--frames", str(10**12)], "--frames must be an integer in [8, 1000000]"),  # the message states both ends
        (["--workers", "100000"], "--workers 100000: more worker processes than this machine can run"),
        (["--trajectories", "0"], "--trajectories must be in [1, 1000]"),
        (["--climates", "rainy"], "unknown climate(s) ['rainy']"),
        (["--seed", "-3"], "--seed must be a non-negative integer"),
        (["--motion", "fly:10,hover"], "--motion: bad segment 'hover' in 'fly:10,hover'"),
        (["--motion", "fly*0:10"], "--motion: bad segment 'fly*0:10'"),
        (["--frames", "20", "--motion", "fly:10,hover:4"], "--frames 20 does not match --motion 'fly:10,hover:4'"),
        (["--frame-step", "0"], "--frame-step must be an integer in [1, 250]"),
        (["--frames", "12", "--frame-step", "8"], "--frames must be an integer in [16, 1000000]"),
    ],
)
def test_bad_arguments_give_a_clear_error_and_exit_status_2(tmp_path, capsys, argv, message):
    out = tmp_path / "ds"
    rc = main(["synth", "--out", str(out), "--no-progress", *argv])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith("cosemdepth synth: error: ") and message in err
    assert not out.exists()


def test_an_output_path_that_is_a_file_or_holds_something_else_is_refused(tmp_path, capsys):
    f = tmp_path / "file.txt"
    f.write_text("keep me")
    assert main(["synth", "--out", str(f), "--frames", "8", "--size", "16", "--no-progress"]) == 2
    assert "exists and is not a folder" in capsys.readouterr().err
    assert f.read_text() == "keep me"
    d = tmp_path / "photos"
    d.mkdir()
    (d / "a.jpg").write_bytes(b"x")
    assert main(["synth", "--out", str(d), "--frames", "8", "--size", "16", "--no-progress"]) == 2
    assert "not empty" in capsys.readouterr().err
    assert sorted(p.name for p in d.iterdir()) == ["a.jpg"]


def test_out_is_required(capsys):
    with pytest.raises(SystemExit) as e:
        main(["synth", "--size", "16"])
    assert e.value.code == 2
    assert "--out" in capsys.readouterr().err
