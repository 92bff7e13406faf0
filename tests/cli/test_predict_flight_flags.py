"""``predict --flight`` with the flags that apply to it: --match, --stamp-unit, --max-pose-gap, --skip-unposed work
as documented, and what was matched is in the summary line and ``predictions.json``."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
from _outputs import (  # noqa: E402, F401 (pytest fixtures)
    _one_thread,
    leftovers,  # noqa: E402
    model_dir,
)

from cosemdepth.cli.main import main  # noqa: E402


def flight(folder: Path, stems, stamps) -> tuple[Path, Path]:
    """Images named ``stems`` and a TUM pose file at ``stamps`` (pose i at (0, 0, 0.1 i), no rotation)."""
    images = folder / "images"
    images.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for s in stems:
        Image.fromarray(rng.integers(0, 255, (16, 16, 3), dtype=np.uint8)).save(images / f"{s}.png")
    poses = folder / "poses.txt"
    poses.write_text("".join(f"{t} 0 0 {0.1 * i} 0 0 0 1\n" for i, t in enumerate(stamps)))
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


def manifest(out: Path) -> dict:
    return json.loads((out / "predictions.json").read_text())


def test_frame_numbers_with_stamps_from_zero(model_dir, tmp_path, capsys):
    images, poses = flight(tmp_path / "f", [f"{k:06d}" for k in range(4)], [f"{0.04 * k:.2f}" for k in range(4)])
    assert predict(model_dir, images, poses, tmp_path / "o") == 0
    line = capsys.readouterr().out
    assert (
        "flight: 4 of 4 images matched to poses by order (auto: image names are zero-padded frame numbers; one "
        "pose per image)"
    ) in line
    info = manifest(tmp_path / "o")["dataset"]["pose_matching"]
    assert (info["match"], info["chosen_by"], info["posed"]) == ("order", "auto", 4)


def test_index_and_skip_unposed(model_dir, tmp_path, capsys):
    images, poses = flight(
        tmp_path / "f", ["000000", "000002", "000004", "000009"], [f"{0.04 * k:.2f}" for k in range(8)]
    )
    assert predict(model_dir, images, poses, tmp_path / "o") == 2
    assert "pass --match index" in capsys.readouterr().err
    assert predict(model_dir, images, poses, tmp_path / "o", "--match", "index") == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(
        "000009.png: frame number 9 has no pose: " + str(poses) + " has 8 pose rows, numbered from 0 "
        "(--match index); --skip-unposed leaves such images out"
    )
    assert predict(model_dir, images, poses, tmp_path / "o", "--match", "index", "--skip-unposed") == 0
    man = manifest(tmp_path / "o")
    assert man["frames_written"] == 3 and man["dataset"]["pose_matching"]["skipped"] == 1
    assert [Path(f["source"]).stem for f in man["frames"]] == ["000000", "000002", "000004"]
    assert "1 skipped without a pose (first: 000009.png)" in capsys.readouterr().out
    # no interpolation with order or index: --max-pose-gap does not apply
    assert predict(model_dir, images, poses, tmp_path / "o", "--match", "index", "--max-pose-gap", "1") == 2
    assert "--max-pose-gap does not apply to --match index" in capsys.readouterr().err


def test_max_pose_gap_and_skip_unposed_work_for_flights(model_dir, tmp_path, capsys):
    # poses at 0, 0.1, 0.4, 0.5 s: the images at 0.2 and 0.3 s lie in a 0.3 s gap
    images, poses = flight(tmp_path / "f", ["0.0", "0.1", "0.2", "0.3", "0.5"], ["0.0", "0.1", "0.4", "0.5"])
    out = tmp_path / "o"
    assert predict(model_dir, images, poses, out) == 2
    assert "0.2.png: no pose for timestamp 0.200000" in capsys.readouterr().err
    assert predict(model_dir, images, poses, out, "--max-pose-gap", "0.2") == 2
    assert "interpolation only across gaps <= 0.2 s: --max-pose-gap, or --skip-unposed" in capsys.readouterr().err
    assert not out.exists() and leftovers(tmp_path) == []
    assert predict(model_dir, images, poses, out, "--max-pose-gap", "0.3") == 0
    assert manifest(out)["frames_written"] == 5 and manifest(out)["dataset"]["pose_matching"]["max_pose_gap_s"] == 0.3
    capsys.readouterr()
    assert predict(model_dir, images, poses, out, "--skip-unposed") == 0
    man = manifest(out)
    assert man["frames_written"] == 3 and man["dataset"]["pose_matching"]["skipped"] == 2
    assert "3 of 5 images matched to poses by stamp" in capsys.readouterr().out


def test_nanosecond_stamps(model_dir, tmp_path, capsys):
    # image names and pose stamps in ns counted from 0, each image between two poses 10 ms apart
    images, poses = flight(
        tmp_path / "f", [k * 40_000_000 + 5_000_000 for k in range(3)], [i * 10_000_000 for i in range(12)]
    )
    assert predict(model_dir, images, poses, tmp_path / "o") == 2
    assert capsys.readouterr().err.strip().endswith("pass --stamp-unit ns")
    assert predict(model_dir, images, poses, tmp_path / "o", "--stamp-unit", "ns") == 0
    info = manifest(tmp_path / "o")["dataset"]["pose_matching"]
    assert info["image_stamp_unit"] == {"unit": "ns", "how": "given"} and info["posed"] == 3
    assert predict(model_dir, images, poses, tmp_path / "o", "--stamp-unit", "hours") == 2
    assert "--stamp-unit must be one of auto, s, ms, us, ns" in capsys.readouterr().err


@pytest.mark.parametrize("flag", [["--image-topic", "/cam"], ["--ignore-distortion"], ["--root", "r"]])
def test_flags_of_other_sources_are_refused(model_dir, tmp_path, capsys, flag):
    images, poses = flight(tmp_path / "f", ["0.0"], ["0.0"])
    assert predict(model_dir, images, poses, tmp_path / "o", *flag) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"cosemdepth predict: error: {flag[0]} does not apply to --flight (only to --")
    assert not (tmp_path / "o").exists()
