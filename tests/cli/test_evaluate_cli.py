"""``cosemdepth evaluate``: outputs, and clear errors that leave no partial output behind."""

import json
import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
from _outputs import SIZE, _one_thread, data, leftovers, model_dir, tiny_midair, tiny_model, unwritable_folder  # noqa: E402 (some are pytest fixtures)

from cosemdepth.cli.main import main  # noqa: E402


def evaluate(model, root, *extra):
    return main(
        [
            "evaluate",
            "--model",
            str(model),
            "--dataset",
            "midair",
            "--root",
            str(root),
            "--split-dir",
            str(Path(root) / "splits"),
            "--size",
            str(SIZE),
            "--no-progress",
            *map(str, extra),
        ]
    )


def test_without_out_nothing_is_written(model_dir, data, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert evaluate(model_dir, data) == 0
    assert "| tiny |" in capsys.readouterr().out
    assert list(tmp_path.iterdir()) == []


def test_out_in_an_existing_folder_keeps_other_files(model_dir, data, tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    assert evaluate(model_dir, data, "--out", tmp_path, "--max-frames", 2) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        ".cosemdepth-output.json",
        "metrics.json",
        "metrics.md",
        "notes.txt",
    ]
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["protocol"]["frames_streamed"] == 2 and m["protocol"]["frames_evaluated"] == 1


def test_one_frame_trajectories_warn_that_there_is_no_depth(model_dir, tmp_path, capsys):
    one = tiny_midair(tmp_path / "one", frames=8)  # every trajectory of the split one row: every frame a reset
    assert evaluate(model_dir, one, "--out", tmp_path / "o") == 0
    err = capsys.readouterr().err
    assert "cosemdepth evaluate: warning: no depth was produced: all 2 frames are resets" in err
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert m["metrics"]["abs_rel"] is None and m["metrics"]["depth_frames"] == 0 and m["metrics"]["semantic_frames"]


def test_output_folder_that_is_a_file(model_dir, data, tmp_path, capsys):
    f = tmp_path / "out"
    f.write_text("mine")
    assert evaluate(model_dir, data, "--out", f) == 2
    assert "exists and is not a folder" in capsys.readouterr().err
    assert f.read_text() == "mine" and leftovers(tmp_path) == []
    assert evaluate(model_dir, data, "--out", f / "sub") == 2
    assert "is a file, not a folder" in capsys.readouterr().err


def test_unwritable_folder(model_dir, data, tmp_path, capsys):
    with unwritable_folder(tmp_path / "ro") as ro:
        assert evaluate(model_dir, data, "--out", ro) == 2
        assert "cannot write" in capsys.readouterr().err
        assert evaluate(model_dir, data, "--out", ro / "a" / "b") == 2
        assert "cannot write" in capsys.readouterr().err
        assert list(ro.iterdir()) == []


def test_missing_model_or_dataset_creates_nothing(model_dir, data, tmp_path, capsys):
    out = tmp_path / "a" / "b" / "out"
    assert evaluate(tmp_path / "nomodel", data, "--out", out) == 2
    assert "model folder not found" in capsys.readouterr().err
    assert evaluate(model_dir, tmp_path / "nodata", "--out", out) == 2
    assert "not found" in capsys.readouterr().err
    for command in ("evaluate", "predict"):
        assert (
            main([command, "--model", str(model_dir), "--dataset", "midair", "--root", str(data), "--out", str(out)])
            == 2
        )
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "split_dir" not in err  # one line naming the flag, not the Python argument
        assert (
            "--dataset midair needs --split-dir D, the folder of its split files (<split>_data/**/*.csv); "
            "write them with: cosemdepth splits midair ROOT D"
        ) in err
    assert list(tmp_path.iterdir()) == []


def test_bad_device(model_dir, data, tmp_path, capsys):
    import torch

    name = "mps" if torch.cuda.is_available() else "cuda"
    assert evaluate(model_dir, data, "--device", name, "--out", tmp_path / "o") == 2
    assert "not available" in capsys.readouterr().err
    assert evaluate(model_dir, data, "--device", "tpu9", "--out", tmp_path / "o") == 2
    assert "--device" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_corrupt_frame_mid_run_writes_nothing(model_dir, data, tmp_path, capsys):
    bad = tmp_path / "bad"
    shutil.copytree(data, bad)
    png = bad / "Kite_training/sunny/stereo_disparity/trajectory_0001/000004.PNG"
    png.write_bytes(b"not a png")
    out = tmp_path / "out"
    out.mkdir()
    assert evaluate(model_dir, bad, "--out", out) == 2
    assert "000004.PNG" in capsys.readouterr().err
    assert list(out.iterdir()) == [] and leftovers(tmp_path) == []


@pytest.mark.parametrize(
    "command, preset, expected", [("evaluate", None, "PASSIVE"), ("demo", "ACTIVE", "ACTIVE"), ("convert", None, None)]
)
def test_openmp_threads_sleep_while_waiting(command, preset, expected):
    """evaluate/predict/demo set OMP_WAIT_POLICY=PASSIVE before torch loads (unless the user chose a policy)."""
    import os
    import subprocess

    code = (
        "import os, sys\nfrom cosemdepth.cli.main import main\ntry:\n    main([sys.argv[1], '--help'])\n"
        "except SystemExit:\n    pass\nprint(os.environ.get('OMP_WAIT_POLICY'))"
    )
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if preset:
        env["OMP_WAIT_POLICY"] = preset
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[2] / "src")
    out = subprocess.run([sys.executable, "-c", code, command], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split("\n")[-2] == str(expected)


def test_semantic_only_dataset_aeroscapes(tmp_path, capsys):
    """M4Semantic with 12 classes on a tiny Aeroscapes: every image counts (each is its own reset), no depth."""
    import numpy as np
    from PIL import Image

    rng = np.random.default_rng(0)
    root = tmp_path / "aeroscapes"
    (root / "JPEGImages").mkdir(parents=True)
    (root / "SegmentationClass").mkdir()
    (root / "ImageSets").mkdir()
    names = [f"img{i}" for i in range(3)]
    for n in names:
        Image.fromarray(rng.integers(0, 255, (24, 40, 3), dtype=np.uint8)).save(root / "JPEGImages" / f"{n}.jpg")
        Image.fromarray(rng.integers(0, 12, (24, 40), dtype=np.uint8)).save(root / "SegmentationClass" / f"{n}.png")
    (root / "ImageSets" / "val.txt").write_text("\n".join(names) + "\n")
    sem = tiny_model(tmp_path / "sem", arch="m4semantic")  # 7 classes: refused
    assert main(["evaluate", "--model", str(sem), "--dataset", "aeroscapes", "--root", str(root)]) == 2
    assert "7 classes but the aeroscapes labels have 12" in capsys.readouterr().err

    import torch

    from cosemdepth import build_model, save_model

    torch.manual_seed(0)
    save_model(build_model(arch="m4semantic", levels=2, num_classes=12), tmp_path / "sem12")
    out = tmp_path / "out"
    assert (
        main(
            [
                "evaluate",
                "--model",
                str(tmp_path / "sem12"),
                "--dataset",
                "aeroscapes",
                "--root",
                str(root),
                "--size",
                "32x64",
                "--out",
                str(out),
                "--no-progress",
            ]
        )
        == 0
    )
    m = json.loads((out / "metrics.json").read_text())
    assert m["metrics"]["semantic_frames"] == 3 and "rmse" not in m["metrics"]
    assert m["protocol"]["reset_frames_excluded"] is False and m["dataset"]["split"] == "val"
    assert list(m["per_class_iou"])[:2] == ["background", "person"] and len(m["confusion_matrix"]) == 12
    assert sum(map(sum, m["confusion_matrix"])) == 3 * 32 * 64
