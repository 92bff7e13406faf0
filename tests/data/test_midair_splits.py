"""Split CSVs: motion convention (design 2.2/10.3), the split rules (10.4), the `splits` CLI, CSV validation."""

from __future__ import annotations

import numpy as np
import pytest
from _writers import read_split_rows, rot_from_quat, write_midair

from cosemdepth.cli.main import main
from cosemdepth.data.midair.splits import generate_splits, read_csv
from cosemdepth.errors import DatasetError

HEADER = ["id", "camera_l", "disp", "semantic", "qw", "qx", "qy", "qz", "tx", "ty", "tz"]

# camera axes (x right, y down, z forward) from NED body axes (x forward, y right, z down)
BODY_TO_CAMERA = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])


def camera_coords(world_points: np.ndarray, att: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """World points [N,3] -> camera coordinates of the body with attitude ``att`` (body->world) at ``pos``."""
    r = rot_from_quat(att)
    body = (world_points - pos) @ r  # R^T (X - p) for each row
    return body @ BODY_TO_CAMERA.T


def test_csv_motion_maps_current_camera_points_to_previous_camera(tmp_path):
    truth = write_midair(tmp_path / "root", {("Kite_training", "sunny"): [0, 1]}, frames=24, images=False)
    written = generate_splits(tmp_path / "root", tmp_path / "splits")
    csv_path = tmp_path / "splits" / "test_data" / "Kite_training" / "sunny" / "traj_0000.csv"
    assert written["test"] == [csv_path]
    att, pos = truth.groundtruth[("Kite_training", "sunny", 0)]
    rows = read_split_rows(csv_path)
    assert len(rows) == (4 * 24 - 16) // 16 == 5
    rng = np.random.default_rng(1)
    world = pos[0] + rng.uniform(-30, 30, (50, 3))
    for k, row in enumerate(rows):
        assert int(row["id"]) == k
        assert row["camera_l"] == f"Kite_training/sunny/color_left/trajectory_0000/{4 * (k + 1):06d}.JPEG"
        a, b = 16 * k, 16 * k + 16  # ground-truth samples of frames 4k and 4k + 4
        x_prev = camera_coords(world, att[a], pos[a])
        x_curr = camera_coords(world, att[b], pos[b])
        q = np.array([float(row[c]) for c in ("qw", "qx", "qy", "qz")])
        t = np.array([float(row[c]) for c in ("tx", "ty", "tz")])
        np.testing.assert_allclose(x_curr @ rot_from_quat(q).T + t, x_prev, atol=2e-4)
        # the motion is mostly forward (+z in camera axes) for this flight going north
        assert t[2] > 0.5


def test_cli_writes_authors_format_numbered_in_sorted_order(tmp_path, capsys):
    layout = {
        ("Kite_training", "sunny"): [0, 1, 2, 3, 4, 5, 6],
        ("Kite_training", "sunset"): [1009, 1000, 1003],
    }
    write_midair(tmp_path / "root", layout, frames=20, images=False)
    out = tmp_path / "out"
    assert main(["splits", "midair", str(tmp_path / "root"), str(out)]) == 0
    files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*.csv"))
    assert files == [
        "test_data/Kite_training/sunny/traj_0000.csv",
        "test_data/Kite_training/sunny/traj_0003.csv",
        "test_data/Kite_training/sunset/traj_0000.csv",
        "train_data/Kite_training/sunny/traj_0001.csv",
        "train_data/Kite_training/sunny/traj_0002.csv",
        "train_data/Kite_training/sunny/traj_0004.csv",
        "train_data/Kite_training/sunny/traj_0005.csv",
        "train_data/Kite_training/sunset/traj_0001.csv",
        "val_data/Kite_training/sunny/traj_0006.csv",
        "val_data/Kite_training/sunset/traj_0002.csv",
    ]
    # sunset index 2 is trajectory 1009 (sorted order), one of the paper's validation trajectories
    rows = read_split_rows(out / "val_data/Kite_training/sunset/traj_0002.csv")
    assert rows[0]["camera_l"] == "Kite_training/sunset/color_left/trajectory_1009/000004.JPEG"
    assert rows[0]["disp"] == "Kite_training/sunset/stereo_disparity/trajectory_1009/000004.PNG"
    assert rows[0]["semantic"] == "Kite_training/sunset/segmentation/trajectory_1009/000004.PNG"
    lines = (out / "test_data/Kite_training/sunny/traj_0000.csv").read_text().splitlines()
    assert lines[0].split("\t") == HEADER
    assert len(lines) == 1 + 4
    fields = lines[1].split("\t")
    assert fields[0] == "0" and all(len(f.split(".")[1]) == 6 for f in fields[4:])
    assert "10 CSV files" in capsys.readouterr().out
    # a CSV that this command did not write in OUT_DIR (readers would mix it in): refused, naming it, and kept
    stale = out / "test_data/Kite_training/sunny/traj_0009.csv"
    stale.write_text("stale")
    assert main(["splits", "midair", str(tmp_path / "root"), str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{stale}: not written by cosemdepth" in err and stale.read_text() == "stale"
    assert len(list(out.rglob("*.csv"))) == 11
    # nothing written into the dataset
    assert not list((tmp_path / "root").rglob("*.csv"))


def test_cli_synthair_defaults_to_root_splits_with_generic_rule(tmp_path):
    layout = {("Synth_world", "foggy"): [0, 1, 2, 3, 4, 5, 6]}
    write_midair(tmp_path / "root", layout, frames=20, images=False)
    assert main(["splits", "synthair", str(tmp_path / "root")]) == 0
    files = sorted(p.relative_to(tmp_path / "root" / "splits").as_posix() for p in (tmp_path / "root").rglob("*.csv"))
    # indices 0, 3, 6 are test; the last of them goes to validation
    assert files == [
        "test_data/Synth_world/foggy/traj_0000.csv",
        "test_data/Synth_world/foggy/traj_0003.csv",
        "train_data/Synth_world/foggy/traj_0001.csv",
        "train_data/Synth_world/foggy/traj_0002.csv",
        "train_data/Synth_world/foggy/traj_0004.csv",
        "train_data/Synth_world/foggy/traj_0005.csv",
        "val_data/Synth_world/foggy/traj_0006.csv",
    ]


def test_cli_single_split_rule_puts_every_trajectory_in_that_split(tmp_path):
    # a world used only for training: its rows are those the generic rule spreads over train/val/test
    layout = {("Synth_world", "foggy"): [0, 1, 2, 3], ("Synth_world", "sunny"): [0, 1]}
    write_midair(tmp_path / "root", layout, frames=20, images=False)
    assert main(["splits", "synthair", str(tmp_path / "root"), str(tmp_path / "generic")]) == 0
    assert main(["splits", "synthair", str(tmp_path / "root"), str(tmp_path / "all"), "--rule", "train"]) == 0
    generic = sorted(p.name for p in (tmp_path / "generic").rglob("*.csv"))
    every = sorted(p.relative_to(tmp_path / "all").as_posix() for p in (tmp_path / "all").rglob("*.csv"))
    assert every == sorted(
        f"train_data/Synth_world/{c}/traj_{i:04d}.csv" for (_, c), ids in layout.items() for i in ids
    )
    assert len(every) == len(generic) == 6
    for p in (tmp_path / "generic").rglob("*.csv"):  # the same rows, only the split differs
        clim, name = p.parent.name, p.name
        assert read_split_rows(p) == read_split_rows(tmp_path / "all" / "train_data" / "Synth_world" / clim / name)
    assert main(["splits", "synthair", str(tmp_path / "root"), str(tmp_path / "t"), "--rule", "test"]) == 0
    assert {p.parent.parent.parent.name for p in (tmp_path / "t").rglob("*.csv")} == {"test_data"}


def test_cli_midair_without_out_dir_is_a_user_error(tmp_path, capsys):
    write_midair(tmp_path / "root", {("Kite_training", "sunny"): [0]}, images=False)
    assert main(["splits", "midair", str(tmp_path / "root")]) == 2
    assert "OUT_DIR" in capsys.readouterr().err


def test_cli_missing_root_is_a_user_error(tmp_path, capsys):
    assert main(["splits", "midair", str(tmp_path / "nope"), str(tmp_path / "out")]) == 2
    assert "nope" in capsys.readouterr().err


GOOD_ROW = "0\ta.JPEG\ta.PNG\ts.PNG\t1.000000\t0.000000\t0.000000\t0.000000\t0.1\t0.2\t1.5"


def write_text(path, *lines):
    path.write_text("\n".join(lines) + "\n")
    return path


def test_read_csv_parses_types(tmp_path):
    p = write_text(tmp_path / "t.csv", "\t".join(HEADER), GOOD_ROW)
    (row,) = read_csv(p)
    assert row["id"] == 0 and row["tz"] == 1.5 and row["camera_l"] == "a.JPEG"


@pytest.mark.parametrize(
    "bad_row, message",
    [
        (GOOD_ROW.replace("1.000000", "nan"), r"t\.csv:3: column qw is nan"),
        (GOOD_ROW.replace("\t0.1\t", "\tinf\t"), r"t\.csv:3: column tx is inf"),
        (GOOD_ROW.replace("1.000000", "0.900000"), r"t\.csv:3: quaternion .* not unit \(norm 0\.900000\)"),
        (GOOD_ROW.rsplit("\t", 2)[0], r"t\.csv:3: .*wrong number of fields"),
        (GOOD_ROW.replace("\t0.2\t", "\t0.2x\t"), r"t\.csv:3: malformed number '0\.2x' in column ty"),
        (GOOD_ROW.replace("a.JPEG", ""), r"t\.csv:3: empty camera_l"),
        ("x" + GOOD_ROW, r"t\.csv:3: malformed id"),
    ],
)
def test_read_csv_rejects_bad_rows_naming_file_and_line(tmp_path, bad_row, message):
    p = write_text(tmp_path / "t.csv", "\t".join(HEADER), GOOD_ROW, bad_row)
    with pytest.raises(DatasetError, match=message):
        read_csv(p)


def test_read_csv_truncated_mid_row(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("\t".join(HEADER) + "\n" + GOOD_ROW + "\n" + GOOD_ROW[:25])
    with pytest.raises(DatasetError, match=r"t\.csv:3: .*truncated"):
        read_csv(p)


def test_read_csv_missing_empty_and_headerless(tmp_path):
    with pytest.raises(DatasetError, match=r"nope\.csv: split CSV not found"):
        read_csv(tmp_path / "nope.csv")
    with pytest.raises(DatasetError, match=r"e\.csv: empty split CSV"):
        read_csv(write_text(tmp_path / "e.csv", ""))
    with pytest.raises(DatasetError, match=r"h\.csv: .*no data rows"):
        read_csv(write_text(tmp_path / "h.csv", "\t".join(HEADER)))
    with pytest.raises(DatasetError, match=r"c\.csv: .*lacks column\(s\) \['qz'\]"):
        read_csv(write_text(tmp_path / "c.csv", "\t".join(h for h in HEADER if h != "qz")))


def test_generator_rejects_non_unit_attitude(tmp_path):
    import h5py

    write_midair(tmp_path / "root", {("Kite_training", "sunny"): [0]}, images=False)
    h5_path = tmp_path / "root/Kite_training/sunny/sensor_records.hdf5"
    with h5py.File(h5_path, "r+") as h5:
        h5["trajectory_0000/groundtruth/attitude"][7] = [2.0, 0.0, 0.0, 0.0]
    with pytest.raises(DatasetError, match=r"sensor_records\.hdf5.*attitude\[7\] is not a unit quaternion"):
        generate_splits(tmp_path / "root", tmp_path / "out")
