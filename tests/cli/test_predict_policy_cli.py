"""``predict --flight`` / ``view`` with the streaming policy: the summary line names the held frames and the baseline,
a 1-frame flight says that it produced no depth, and the policy flags are checked before anything runs."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
from _outputs import (  # noqa: E402, F401 (pytest fixtures)
    _one_thread,
    leftovers,  # noqa: E402
    model_dir,
)

from cosemdepth.cli.main import main  # noqa: E402


def flight(folder: Path, z) -> tuple[Path, Path]:
    """One image per camera position ``z[i]`` metres forward (TUM poses, no rotation)."""
    images = folder / "images"
    images.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(len(z)):
        Image.fromarray(rng.integers(0, 255, (16, 16, 3), dtype=np.uint8)).save(images / f"{i:04d}.png")
    poses = folder / "poses.txt"
    poses.write_text("".join(f"{0.1 * i:.1f} 0 0 {v} 0 0 0 1\n" for i, v in enumerate(z)))
    return images, poses


def predict(model_dir, images, poses, out, *extra):
    return main(
        [
            "predict",
            "--model",
            str(model_dir),
            "--flight",
            "--images",
            str(images),
            "--poses",
            str(poses),
            "--hfov",
            "90",
            "--out",
            str(out),
            "--video",
            "none",
            "--no-progress",
            *map(str, extra),
        ]
    )


def test_a_hover_is_held_and_the_summary_says_so(model_dir, tmp_path, capsys):
    # forward 0.5 m per frame, then a hover of 3 frames, then forward again
    images, poses = flight(tmp_path / "f", [0, 0.5, 1.0, 1.0, 1.0, 1.0, 1.5])
    out = tmp_path / "out"
    assert predict(model_dir, images, poses, out, "--policy", "baseline", "--min-baseline", 0.3) == 0
    printed = capsys.readouterr().out
    man = json.loads((out / "predictions.json").read_text())
    assert [f["status"] for f in man["frames"]] == [
        "reset",
        "estimated",
        "estimated",
        "held",
        "held",
        "held",
        "estimated",
    ]
    assert "3 frames held: the camera moved less than 0.30 m from its reference frame" in printed
    assert "depth (policy baseline): 3 frames estimated, 1 reset (no depth)" in printed
    assert man["policy"] == {**man["policy"], "mode": "baseline", "min_baseline_m": 0.3}
    # every held frame carries the last estimate (no motion since): the same depth values and mask
    last = np.load(out / man["frames"][2]["files"]["depth"])
    for f in man["frames"][3:6]:
        np.testing.assert_array_equal(np.load(out / f["files"]["depth"]), last)


def test_a_model_without_training_motion_streams_every_frame_by_default(model_dir, tmp_path, capsys):
    images, poses = flight(tmp_path / "f", [0, 0.5, 0.5, 1.0])
    out = tmp_path / "out"
    assert predict(model_dir, images, poses, out) == 0
    man = json.loads((out / "predictions.json").read_text())
    assert man["policy"]["mode"] == "every-frame"
    # the hover frame is estimated with no translation: none of its pixels is valid
    assert [f["status"] for f in man["frames"]] == ["reset", "estimated", "estimated", "estimated"]
    assert man["frames"][2]["valid_fraction"] == 0.0


def test_a_one_frame_flight_says_it_produced_no_depth(model_dir, tmp_path, capsys):
    images, poses = flight(tmp_path / "f", [0])
    out = tmp_path / "out"
    assert predict(model_dir, images, poses, out) == 0
    err = capsys.readouterr().err
    assert "warning: no depth was produced: the input has 1 frame" in err
    man = json.loads((out / "predictions.json").read_text())
    assert man["frames_by_status"] == {"reset": 1} and man["frames"][0]["valid_fraction"] == 0.0


def test_a_hover_under_the_every_frame_policy_warns_that_no_depth_is_valid(model_dir, tmp_path, capsys):
    images, poses = flight(tmp_path / "f", [1.0, 1.0, 1.0])
    assert predict(model_dir, images, poses, tmp_path / "out", "--policy", "every-frame") == 0
    err = capsys.readouterr().err
    assert "cosemdepth predict: warning: no valid depth: not one pixel of the 2 frames with depth is valid" in err


def test_bad_policy_flags_fail_with_one_line_and_write_nothing(model_dir, tmp_path, capsys):
    images, poses = flight(tmp_path / "f", [0, 1])
    out = tmp_path / "out"
    for extra, message in (
        (["--policy", "every-frame", "--min-baseline", 1], "--min-baseline applies to --policy"),
        (["--min-baseline", -1], "--min-baseline must be a number of metres >= 0"),
        (["--policy", "baseline"], "baseline-aware streaming needs a minimum baseline"),
    ):
        assert predict(model_dir, images, poses, out, *extra) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
        assert not out.exists() and leftovers(tmp_path) == []
    rc = main(
        [
            "view",
            "--model",
            str(model_dir),
            "--flight",
            "--images",
            str(images),
            "--poses",
            str(poses),
            "--hfov",
            "90",
            "--rrd",
            str(tmp_path / "a.rrd"),
            "--invalid",
            "nan",
        ]
    )
    assert rc == 2 and "--invalid does not apply to view" in capsys.readouterr().err
