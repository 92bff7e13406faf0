"""scripts/demo_motion_stats.py: the split CSVs it derives from the flight planner alone are those that
``cosemdepth synth`` + ``cosemdepth splits --rule train`` write (so the shipped weights' motion statistics are those
of their training windows)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from cosemdepth.cli.main import main
from cosemdepth.data import open_dataset

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "demo_motion_stats.py"


def _script():
    spec = importlib.util.spec_from_file_location("demo_motion_stats_script", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_csvs_without_rendering_are_those_of_synth_and_splits(world, tmp_path, capsys):
    data, splits, derived = tmp_path / "ds", tmp_path / "splits", tmp_path / "derived"
    assert (
        main(
            [
                "synth",
                "--out",
                str(data),
                "--trajectories",
                "2",
                "--frames",
                "24",
                "--size",
                "16",
                "--seed",
                "0",
                "--climates",
                "sunny",
                "cloudy",
                "--no-progress",
            ]
        )
        == 0
    )
    assert main(["splits", "synthair", str(data), str(splits), "--rule", "train"]) == 0
    _script().world_trajectories(0, derived, trajectories=2, frames=24, climates=("sunny", "cloudy"))

    written = sorted(p.relative_to(splits) for p in splits.rglob("*.csv"))
    assert written == sorted(p.relative_to(derived) for p in derived.rglob("*.csv")) and len(written) == 4
    for rel in written:
        assert (derived / rel).read_bytes() == (splits / rel).read_bytes(), rel

    # and the training windows of both give the same per-step translations (4-row chunks, rows 1-3 of each)
    def steps(split_dir):
        return open_dataset(
            "synthair", data, split_dir=split_dir, split="train", seq_len=4, size=16, mode="train", db_seq_len=4
        ).step_translations()

    a = steps(splits)
    assert len(a) == 4 * 3  # 4 trajectories of 5 rows: one chunk each, its rows 1..3
    np.testing.assert_array_equal(a, steps(derived))
