"""Fuzz tests of the Mid-Air split generator's input, ``sensor_records.hdf5``.

Files are written with h5py in the right layout and in wrong ones (missing or misplaced groups, wrong shapes and
dtypes, NaN/inf, non-unit quaternions, values near 1e308, a huge declared size with no data behind it), then
possibly truncated or bit-flipped. Allowed outcomes (tests/fuzzing.py): split CSVs that the split CSV reader
accepts, with one row per 16 ground-truth samples, or a CosemdepthError naming the HDF5 file.
"""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest
from fuzzing import fuzz_settings, mutate_bytes, outcome, write
from hypothesis import given
from hypothesis import strategies as st

from cosemdepth.data.midair.splits import generate_splits, read_csv
from cosemdepth.errors import DatasetError


@st.composite
def groundtruth(draw):
    """``(attitude, position)`` arrays (or other objects) for one trajectory, mostly valid."""
    n = draw(st.sampled_from((0, 5, 31, 32, 48, 70)))
    t = np.arange(n) / 100.0
    half = 0.2 * np.sin(t)
    att = np.stack([np.cos(half), np.zeros(n), np.zeros(n), np.sin(half)], axis=1)
    pos = np.stack([3 * t, np.sin(t), -10 + 0 * t], axis=1)
    kind = draw(st.sampled_from(("valid", "valid", "nan", "huge", "nonunit", "dtype", "shape", "swap")))
    if kind == "nan" and n:
        target = draw(st.sampled_from((att, pos)))
        target[draw(st.integers(0, n - 1)), 0] = draw(st.sampled_from((np.nan, np.inf, -np.inf)))
    elif kind == "huge" and n:
        pos[draw(st.integers(0, n - 1))] = draw(st.sampled_from((1e308, -1e308, 1e39)))
    elif kind == "nonunit" and n:
        att[draw(st.integers(0, n - 1))] *= 1.5
    elif kind == "dtype":
        new = draw(st.sampled_from(("int32", "float16", "complex64", "bool", "S4", "compound")))
        if new == "compound":
            att = np.zeros(n, dtype=[("w", "f8"), ("x", "f8"), ("y", "f8"), ("z", "f8")])
        else:
            att = att.astype(new)
    elif kind == "shape":
        new = draw(st.sampled_from(((n,), (n, 3), (n, 4, 1), ())))
        att = np.ones(new)
    elif kind == "swap":
        att, pos = pos, att
    return att, pos


@st.composite
def sensor_records(draw):
    """A function writing a ``sensor_records.hdf5`` with the drawn layout."""
    gt = draw(groundtruth())
    layout = draw(
        st.sampled_from(
            (
                "ok",
                "ok",
                "ok",
                "no_gt",
                "traj_dataset",
                "gt_dataset",
                "attitude_group",
                "huge_declared",
                "dangling_link",
                "extra_traj",
            )
        )
    )

    def build(path) -> None:
        with h5py.File(path, "w") as h5:
            if layout == "traj_dataset":
                h5.create_dataset("trajectory_0000", data=np.zeros(3))
                return
            g = h5.create_group("trajectory_0000")
            if layout == "no_gt":
                return
            if layout == "gt_dataset":
                g.create_dataset("groundtruth", data=np.zeros((4, 4)))
                return
            gtg = g.create_group("groundtruth")
            if layout == "attitude_group":
                gtg.create_group("attitude")
            elif layout == "huge_declared":  # 10^10 rows declared, nothing stored
                gtg.create_dataset("attitude", shape=(10**10, 4), maxshape=(None, 4), chunks=(1024, 4), dtype="f8")
            elif layout == "dangling_link":
                gtg["attitude"] = h5py.SoftLink("/nowhere")
            else:
                gtg.create_dataset("attitude", data=gt[0])
            gtg.create_dataset("position", data=gt[1])
            if layout == "extra_traj":
                h5.create_group("trajectory_0001")

    return build


@fuzz_settings(max_examples=80)
@given(build=sensor_records(), data=st.data())
def test_fuzz_sensor_records(tmp_path_factory, build, data):
    base = tmp_path_factory.getbasetemp() / "fuzz_h5"
    climate = base / "root" / "Kite_training" / "sunny"
    (climate / "color_left" / "trajectory_0000").mkdir(parents=True, exist_ok=True)
    h5_path = climate / "sensor_records.hdf5"
    build(h5_path)
    if data.draw(st.sampled_from(("as is", "as is", "bytes"))) == "bytes":
        write(h5_path, data.draw(mutate_bytes(h5_path.read_bytes())))
    out = base / "out"
    shutil.rmtree(out, ignore_errors=True)

    def check(written) -> None:
        paths = [p for split in written.values() for p in split]
        assert len(paths) <= 1
        for p in paths:
            rows = read_csv(p)  # the generator's output is accepted by the reader
            assert len(rows) >= 1
            for r in rows:
                assert all(abs(r[c]) < 3.4e38 for c in ("qw", "qx", "qy", "qz", "tx", "ty", "tz"))

    outcome(lambda: generate_splits(base / "root", out), [h5_path], check)


@pytest.mark.parametrize("what", ["compound", "strings", "huge_declared", "far_positions"])
def test_sensor_records_regressions(tmp_path, what):
    """Found by the fuzzer: a compound or string attitude raised ValueError/TypeError; a huge declared size was
    read (allocating gigabytes); positions near 1e308 wrote split CSVs holding inf that the reader refuses."""
    climate = tmp_path / "root" / "Kite_training" / "sunny"
    (climate / "color_left" / "trajectory_0000").mkdir(parents=True)
    att = np.tile([1.0, 0, 0, 0], (40, 1))
    pos = np.zeros((40, 3))
    h5_path = climate / "sensor_records.hdf5"
    with h5py.File(h5_path, "w") as h5:
        gt = h5.create_group("trajectory_0000/groundtruth")
        if what == "compound":
            gt.create_dataset("attitude", data=np.zeros(40, dtype=[("w", "f8"), ("x", "f8")]))
        elif what == "strings":
            gt.create_dataset("attitude", data=np.full((40, 4), b"1.0"))
        elif what == "huge_declared":
            gt.create_dataset("attitude", shape=(10**10, 4), maxshape=(None, 4), chunks=(1024, 4), dtype="f8")
        else:
            gt.create_dataset("attitude", data=att)
            pos[16:] = 1e308
            pos[:16] = -1e308
        if "position" not in gt:
            gt.create_dataset("position", data=pos)
    with pytest.raises(DatasetError) as e:
        generate_splits(tmp_path / "root", tmp_path / "out")
    assert str(h5_path) in str(e.value)
