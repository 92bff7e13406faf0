"""Fuzz tests of the split files: Mid-Air/SynthAir and TopAir split CSVs (through the dataset openers), the TopAir
AirSim recordings the TopAir split generator reads, and Aeroscapes ``ImageSets`` lists.

Allowed outcomes (tests/fuzzing.py): a dataset whose trajectories pass the checks below (and equal the written
rows when the file is unchanged), or a CosemdepthError naming the damaged file.
"""

from __future__ import annotations

import numpy as np
import pytest
from fuzzing import fuzz_settings, outcome, text_file_bytes, write
from hypothesis import given
from hypothesis import strategies as st

from cosemdepth.data.aeroscapes import open_aeroscapes
from cosemdepth.data.midair.dataset import open_midair
from cosemdepth.data.topair import open_topair
from cosemdepth.data.topair_splits import read_airsim_rec
from cosemdepth.errors import DatasetError

MIDAIR_COLUMNS = ("id", "camera_l", "disp", "semantic", "qw", "qx", "qy", "qz", "tx", "ty", "tz")
#: The original generator's CSVs have no semantic column: the reader derives it from camera_l.
ORIGINAL_COLUMNS = ("id", "camera_l", "disp", "qw", "qx", "qy", "qz", "tx", "ty", "tz")
TOPAIR_COLUMNS = ("id", "camera_l", "depth", "semantic", "qw", "qx", "qy", "qz", "tx", "ty", "tz")


@st.composite
def split_rows(draw, max_n: int = 4):
    """``(ids [n], quaternions [n, 4], translations [n, 3])`` of a valid split CSV (6-decimal values)."""
    n = draw(st.integers(1, max_n))
    start = draw(st.integers(-1, 3))
    ids = np.arange(start, start + n)
    q = np.array(draw(st.lists(st.tuples(*[st.floats(-1, 1)] * 4), min_size=n, max_size=n)))
    q[:, 0] += 2.0
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    t = np.array(draw(st.lists(st.tuples(*[st.floats(-100, 100)] * 3), min_size=n, max_size=n)))
    return ids, np.round(q, 6), np.round(t, 6)


def split_text(rows, columns, env: str = "env") -> str:
    ids, q, t = rows
    lines = ["\t".join(columns)]
    for i, qi, ti in zip(ids, q, t):
        name = f"{max(int(i), 0):06d}"
        paths = [f"{env}/color_left/trajectory_0000/{name}.JPEG", f"{env}/depth/{name}.PNG", f"{env}/seg/{name}.PNG"]
        paths = paths[: len(columns) - 8]
        lines.append("\t".join([str(i), *paths, *(f"{v:.6f}" for v in (*qi, *ti))]))
    return "\n".join(lines) + "\n"


def check_dataset(ds, truth) -> None:
    for traj in ds.trajectories:
        n = len(traj)
        assert n >= 1
        assert traj.rot.shape == (n, 4) and traj.trans.shape == (n, 3) and traj.ids.shape == (n,)
        assert np.isfinite(traj.rot).all() and np.isfinite(traj.trans).all()
        np.testing.assert_allclose(np.linalg.norm(traj.rot, axis=1), 1.0, atol=2e-3)
        assert all(isinstance(p, str) and p.strip() for p in traj.rgb)
        assert traj.reset[0]
    if truth is not None:
        ids, q, t = truth
        (traj,) = ds.trajectories
        np.testing.assert_array_equal(traj.ids, ids)
        np.testing.assert_allclose(traj.rot, q, atol=1e-7)
        np.testing.assert_allclose(traj.trans, t, atol=1e-5)


@fuzz_settings(max_examples=80)
@given(rows=split_rows(), data=st.data(), kind=st.sampled_from(("midair", "original", "topair")))
def test_fuzz_split_csv(tmp_path_factory, rows, data, kind):
    """A damaged Mid-Air or TopAir split CSV, opened as a dataset (the CSV is all that is read at open time)."""
    base = tmp_path_factory.getbasetemp() / "fuzz_splits"
    (base / "root" / "env" / "segmentation" / "trajectory_0000").mkdir(parents=True, exist_ok=True)
    topair = kind == "topair"
    text = split_text(rows, {"midair": MIDAIR_COLUMNS, "original": ORIGINAL_COLUMNS, "topair": TOPAIR_COLUMNS}[kind])
    raw = data.draw(text_file_bytes(text, separators="\t\n"))
    path = write(base / "splits" / "test_data" / "traj_0000.csv", raw)
    opener = open_topair if topair else open_midair
    outcome(
        lambda: opener(base / "root", base / "splits", "test", size=8),
        [path],
        lambda ds: check_dataset(ds, rows if raw == text.encode() else None),
    )


@st.composite
def airsim_rows(draw, max_n: int = 4):
    n = draw(st.integers(1, max_n))
    q = np.array(draw(st.lists(st.tuples(*[st.floats(-1, 1)] * 4), min_size=n, max_size=n)))
    q[:, 0] += 2.0
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    p = np.array(draw(st.lists(st.tuples(*[st.floats(-1e3, 1e3)] * 3), min_size=n, max_size=n)))
    return p, q


@fuzz_settings(max_examples=50)
@given(rows=airsim_rows(), data=st.data())
def test_fuzz_airsim_recording(tmp_path_factory, rows, data):
    p, q = rows
    lines = ["VehicleName\tTimeStamp\tPOS_X\tPOS_Y\tPOS_Z\tQ_W\tQ_X\tQ_Y\tQ_Z\tImageFile"]
    for k, (pk, qk) in enumerate(zip(p, q)):
        lines.append("\t".join(["Drone1", str(1000 + k), *(repr(float(v)) for v in (*pk, *qk)), f"img_{k}.png"]))
    text = "\n".join(lines) + "\n"
    raw = data.draw(text_file_bytes(text, separators="\t\n"))
    path = write(tmp_path_factory.getbasetemp() / "fuzz_airsim" / "Africa_1" / "airsim_rec.txt", raw)

    def check(result) -> None:
        pos, quat = result
        n = len(pos)
        assert n >= 1 and pos.shape == (n, 3) and quat.shape == (n, 4)
        assert np.isfinite(pos).all() and np.isfinite(quat).all()
        np.testing.assert_allclose(np.linalg.norm(quat, axis=1), 1.0, atol=1e-9)
        if raw == text.encode():
            np.testing.assert_array_equal(pos, p)
            np.testing.assert_allclose(quat, q, atol=1e-15)

    outcome(lambda: read_airsim_rec(path), [path], check)


@fuzz_settings(max_examples=40)
@given(
    names=st.lists(st.from_regex(r"[0-9]{6}_[0-9]{3}", fullmatch=True), min_size=1, max_size=4, unique=True),
    data=st.data(),
)
def test_fuzz_aeroscapes_imagesets(tmp_path_factory, names, data):
    root = tmp_path_factory.getbasetemp() / "fuzz_aeroscapes"
    root.mkdir(exist_ok=True)
    text = "\n".join(names) + "\n"
    raw = data.draw(text_file_bytes(text, separators="\n"))
    path = write(root / "ImageSets" / "val.txt", raw)

    def check(ds) -> None:
        (traj,) = ds.trajectories
        assert len(traj) >= 1 and traj.reset.all()
        for rgb, sem in zip(traj.rgb, traj.semantic):
            assert rgb.endswith(".jpg") and sem.endswith(".png")
            assert "\n" not in rgb and rgb.rsplit("/", 1)[-1][:-4].strip()
        if raw == text.encode():
            assert [r.rsplit("/", 1)[-1][:-4] for r in traj.rgb] == names

    outcome(lambda: open_aeroscapes(root, split="val", size=8), [path], check)


ONE_ROW = (np.array([0]), np.array([[1.0, 0, 0, 0]]), np.zeros((1, 3)))


@pytest.mark.parametrize(
    "column, bad",
    [
        ("id", "99999999999999999999"),  # OverflowError building the int64 id array
        ("id", "-99999999999999999999"),
        ("qw", "1e300"),  # OverflowError squaring it for the norm
        ("tx", "1e39"),  # finite float64, infinite in the dataset's float32 arrays
        ("tx", "-1e300"),
        ("camera_l", "a" * 200_000),  # _csv.Error: field larger than field limit
    ],
)
def test_split_csv_regressions(tmp_path, column, bad):
    """Found by the fuzzer: each of these escaped as a non-project exception or gave an infinite motion."""
    header, row = split_text(ONE_ROW, MIDAIR_COLUMNS).splitlines()
    fields = row.split("\t")
    fields[MIDAIR_COLUMNS.index(column)] = bad
    path = write(tmp_path / "splits" / "test_data" / "traj_0000.csv", f"{header}\n{chr(9).join(fields)}\n".encode())
    (tmp_path / "root").mkdir()
    with pytest.raises(DatasetError) as e:
        open_midair(tmp_path / "root", tmp_path / "splits", "test", size=8)
    assert str(path) in str(e.value)


def test_airsim_recording_field_over_csv_limit(tmp_path):
    """Found by the fuzzer: _csv.Error escaped from the AirSim recording reader."""
    header = b"POS_X\tPOS_Y\tPOS_Z\tQ_W\tQ_X\tQ_Y\tQ_Z\n"
    path = write(tmp_path / "airsim_rec.txt", header + b"1" * 200_000 + b"\t0\t0\t1\t0\t0\t0\n")
    with pytest.raises(DatasetError) as e:
        read_airsim_rec(path)
    assert str(path) in str(e.value)


def test_topair_generator_far_positions(tmp_path):
    """Found with the Mid-Air generator's fuzzing, same cause: positions near 1e308 (finite) gave motions that
    overflow, written to the split CSV as inf, which the split CSV reader then refuses."""
    from cosemdepth.data.topair_splits import generate_topair_splits

    lines = ["POS_X\tPOS_Y\tPOS_Z\tQ_W\tQ_X\tQ_Y\tQ_Z", "-1e308\t0\t0\t1\t0\t0\t0", "1e308\t0\t0\t1\t0\t0\t0"]
    path = write(tmp_path / "root" / "Africa_1" / "airsim_rec.txt", ("\n".join(lines) + "\n").encode())
    with pytest.raises(DatasetError, match="float32") as e:
        generate_topair_splits(tmp_path / "root", tmp_path / "out")
    assert str(path) in str(e.value)


def test_split_csv_path_too_long(tmp_path):
    """Found by the fuzzer: a camera_l path longer than the file system allows made the semantic-path derivation
    (CSVs without a semantic column) raise OSError (ENAMETOOLONG)."""
    text = split_text(ONE_ROW, ORIGINAL_COLUMNS).replace("color_left/", "color_left/" + "x" * 5000 + "/")
    write(tmp_path / "splits" / "test_data" / "traj_0000.csv", text.encode())
    (tmp_path / "root").mkdir()
    ds = open_midair(tmp_path / "root", tmp_path / "splits", "test", size=8)
    assert ds.trajectories[0].semantic is None  # the derived folder does not exist: no labels, as for a short path
