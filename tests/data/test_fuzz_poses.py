"""Fuzz tests of the pose-file readers (TUM, CSV) and of a flight opened from a damaged pose file.

Allowed outcomes (tests/fuzzing.py): a pose track that passes the invariant checks below (and equals the written
poses when the file is unchanged), or a CosemdepthError naming the pose file.
"""

from __future__ import annotations

import numpy as np
import pytest
from fuzzing import fuzz_settings, outcome, text_file_bytes, write
from hypothesis import example, given
from hypothesis import strategies as st
from PIL import Image

from cosemdepth.data.flight import open_flight
from cosemdepth.data.poses import read_pose_csv, read_tum
from cosemdepth.errors import DatasetError


@st.composite
def poses(draw, max_n: int = 5):
    """``(timestamps [n], positions [n, 3], quaternions [n, 4] w-first)`` of a valid track."""
    n = draw(st.integers(1, max_n))
    t0 = draw(st.floats(0, 2e9))
    dt = draw(st.lists(st.floats(1e-3, 10), min_size=n, max_size=n))
    ts = t0 + np.cumsum(dt)
    pos = np.array(draw(st.lists(st.tuples(*[st.floats(-1e4, 1e4)] * 3), min_size=n, max_size=n)))
    q = np.array(draw(st.lists(st.tuples(*[st.floats(-1, 1)] * 4), min_size=n, max_size=n)))
    q[:, 0] += 2.0  # away from zero so the normalization is well defined
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return ts, pos, q


def tum_text(ts, pos, q) -> str:
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for t, p, r in zip(ts, pos, q):
        lines.append(" ".join(repr(float(v)) for v in (t, *p, r[1], r[2], r[3], r[0])))
    return "\n".join(lines) + "\n"


def csv_text(ts, pos, q) -> str:
    lines = ["timestamp,tx,ty,tz,qw,qx,qy,qz"]
    for t, p, r in zip(ts, pos, q):
        lines.append(",".join(repr(float(v)) for v in (t, *p, *r)))
    return "\n".join(lines) + "\n"


def check_track(track, data: bytes, truth) -> None:
    """Invariants of any track a reader returns, and equality with ``truth`` when the file is the written one."""
    n = len(track)
    assert n >= 1
    assert track.positions.shape == (n, 3) and track.quaternions.shape == (n, 4)
    assert np.isfinite(track.positions).all() and np.isfinite(track.quaternions).all()
    np.testing.assert_allclose(np.linalg.norm(track.quaternions, axis=1), 1.0, atol=1e-9)
    if track.timestamps is not None:
        assert track.timestamps.shape == (n,) and np.isfinite(track.timestamps).all()
        assert (np.diff(track.timestamps) > 0).all()
    assert (np.diff(track.lines) > 0).all() and track.lines[0] >= 1
    assert track.lines[-1] <= data.count(b"\n") + 1
    if truth is not None:
        ts, pos, q = truth
        np.testing.assert_array_equal(track.timestamps, ts)
        np.testing.assert_array_equal(track.positions, pos)
        np.testing.assert_allclose(track.quaternions, q, atol=1e-15)


@fuzz_settings(max_examples=80)
@given(truth=poses(), data=st.data())
@example(truth=(np.array([1.0]), np.zeros((1, 3)), np.array([[1.0, 0, 0, 0]])), data=None)
def test_fuzz_tum(tmp_path_factory, truth, data):
    text = tum_text(*truth)
    raw = data.draw(text_file_bytes(text)) if data is not None else text.encode()
    path = write(tmp_path_factory.getbasetemp() / "fuzz_poses" / "poses.txt", raw)
    outcome(lambda: read_tum(path), [path], lambda t: check_track(t, raw, truth if raw == text.encode() else None))


@fuzz_settings(max_examples=80)
@given(truth=poses(), data=st.data())
def test_fuzz_pose_csv(tmp_path_factory, truth, data):
    text = csv_text(*truth)
    raw = data.draw(text_file_bytes(text))
    path = write(tmp_path_factory.getbasetemp() / "fuzz_poses" / "poses.csv", raw)
    outcome(lambda: read_pose_csv(path), [path], lambda t: check_track(t, raw, truth if raw == text.encode() else None))


def _flight_images(folder, n: int) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("*.png"):
        old.unlink()
    for i in range(n):
        p = folder / f"{i:06d}.png"
        if not p.exists():
            Image.fromarray(np.full((4, 6, 3), 40 * i, np.uint8)).save(p)


@fuzz_settings(max_examples=30)
@given(truth=poses(max_n=3), data=st.data())
@example(  # positions far apart: finite in the file, but their difference overflows
    truth=(
        np.array([1.0, 2.0, 3.0]),
        np.array([[1e308, 0, 0], [-1e308, 0, 0], [0, 0, 0]]),
        np.tile([1.0, 0, 0, 0], (3, 1)),
    ),
    data=None,
)
@example(  # finite in float64, out of float32's range (the dataset's motion arrays)
    truth=(np.array([1.0, 2.0, 3.0]), np.array([[0, 0, 0], [1e39, 0, 0], [0, 0, 0]]), np.tile([1.0, 0, 0, 0], (3, 1))),
    data=None,
)
def test_fuzz_flight_poses(tmp_path_factory, truth, data):
    """A flight whose pose file is damaged: the motions the dataset hands to the model are finite, or the error
    names the pose file."""
    root = tmp_path_factory.getbasetemp() / "fuzz_flight"
    _flight_images(root, len(truth[0]))
    text = tum_text(*truth)
    raw = data.draw(text_file_bytes(text)) if data is not None else text.encode()
    path = write(root / "poses.txt", raw)

    def check(ds) -> None:
        (traj,) = ds.trajectories
        assert np.isfinite(traj.rot).all() and np.isfinite(traj.trans).all()
        np.testing.assert_allclose(np.linalg.norm(traj.rot, axis=1), 1.0, atol=1e-5)

    match = data.draw(st.sampled_from(("order", "auto", "stamp"))) if data is not None else "order"
    if match != "order":  # images named by the poses' timestamps (or near them), matched by timestamp
        for old in root.glob("*.png"):
            old.unlink()
        for t in truth[0]:
            stamp = t + data.draw(st.sampled_from((0.0, 0.0, 0.05, -0.3)))
            Image.fromarray(np.zeros((4, 6, 3), np.uint8)).save(root / f"{stamp:.6f}.png")
    outcome(lambda: open_flight(root, poses=path, fov=90.0, match=match), [path], check)


def test_pose_csv_field_over_csv_limit(tmp_path):
    """Found by the fuzzer: a field longer than the csv module's limit (131072 characters) raised _csv.Error."""
    path = write(tmp_path / "poses.csv", b"timestamp,tx,ty,tz,qw,qx,qy,qz\n" + b"1" * 200_000 + b",0,0,0,1,0,0,0\n")
    outcome(lambda: read_pose_csv(path), [path], lambda t: pytest.fail(f"read {t}"))


def test_flight_motion_beyond_float32(tmp_path):
    """Found by the fuzzer: positions valid in float64 whose motion overflows float32 (the dataset's arrays) gave
    an infinite translation."""
    _flight_images(tmp_path, 2)
    path = write(tmp_path / "poses.txt", b"1 0 0 0 0 0 0 1\n2 1e39 0 0 0 0 0 1\n")
    with pytest.raises(DatasetError, match="not finite in float32") as e:
        open_flight(tmp_path, poses=path, fov=90.0, match="order")
    assert str(path) in str(e.value)
