"""Your own flight: images + TUM/CSV absolute poses + intrinsics -> relative motions in the model convention."""

from __future__ import annotations

import numpy as np
import pytest
from _writers import snapshot
from PIL import Image

from cosemdepth.data import open_dataset
from cosemdepth.data.frames import FocalSize
from cosemdepth.errors import ConfigError, DatasetError

C, S = np.cos(np.pi / 4), np.sin(np.pi / 4)
H, W = 30, 40
TIMES = [1.0, 1.1, 1.2, 1.3]
# camera-to-world poses (OpenCV optical axes): forward 2 m, then yaw 90 degrees about the (down) y axis while
# stepping 1 m right, then 1 m along world z
POSES = [
    ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)),
    ((0.0, 0.0, 2.0), (1.0, 0.0, 0.0, 0.0)),
    ((1.0, 0.0, 2.0), (C, 0.0, S, 0.0)),
    ((1.0, 0.0, 3.0), (C, 0.0, S, 0.0)),
]
# hand-computed relative motions (X_prev = R X_curr + t): identity for the first (reset) frame
EXPECTED_Q = [(1, 0, 0, 0), (1, 0, 0, 0), (C, 0, S, 0), (1, 0, 0, 0)]
EXPECTED_T = [(0, 0, 0), (0, 0, 2), (1, 0, 0), (-1, 0, 0)]


def write_images(folder, names):
    folder.mkdir(parents=True, exist_ok=True)
    for k, n in enumerate(names):
        Image.fromarray(np.full((H, W, 3), 20 * k, np.uint8)).save(folder / n)


def write_tum(path, times=TIMES, poses=POSES):
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for t, (p, q) in zip(times, poses):
        lines.append(f"{t:.6f} {p[0]} {p[1]} {p[2]} {q[1]} {q[2]} {q[3]} {q[0]}")
    path.write_text("\n".join(lines) + "\n")
    return path


def motions(ds):
    items = list(ds)
    return (
        np.array([it["rot"][0].tolist() for it in items]),
        np.array([it["trans"][0].tolist() for it in items]),
        [bool(it["reset"][0]) for it in items],
    )


@pytest.fixture
def flight(tmp_path):
    write_images(tmp_path / "f", [f"{t:.6f}.png" for t in TIMES])
    return tmp_path / "f"


def test_tum_poses_give_hand_computed_relative_motions(flight):
    write_tum(flight / "poses.txt")
    ds = open_dataset("flight", flight, seq_len=1, fov=90.0)
    q, t, reset = motions(ds)
    np.testing.assert_allclose(q, EXPECTED_Q, atol=1e-6)
    np.testing.assert_allclose(t, EXPECTED_T, atol=1e-6)
    assert reset == [True, False, False, False]
    it = ds[0]
    assert it["rgb"].shape == (1, 3, H, W) and "depth" not in it and "semantic" not in it
    assert it["intrinsics"].tolist() == [20.0, 20.0, 20.0, 15.0]
    assert it["timestamp"].tolist() == [1.0]


def test_a_focal_size_rule_gives_the_flight_that_focal_length_at_its_aspect_ratio(flight):
    write_tum(flight / "poses.txt")
    # 30x40 images with a 90-degree horizontal FOV: f = 20 px; a focal length of 30 px is the size 45x60
    ds = open_dataset("flight", flight, seq_len=1, fov=90.0, size=FocalSize(30.0))
    assert ds[0]["rgb"].shape[-2:] == (45, 60)
    assert ds.intrinsics.tolist() == [30.0, 30.0, 30.0, 22.5]
    # with intrinsics: fx = 10 px at 30x40 -> a focal length of 5 px halves the size (rounded half up: 15x20)
    ds = open_dataset("flight", flight, seq_len=1, intrinsics=(10.0, 12.0, 20.0, 15.0), size=FocalSize(5.0))
    assert ds[0]["rgb"].shape[-2:] == (15, 20) and ds.intrinsics.tolist() == [5.0, 6.0, 10.0, 7.5]
    # opened at another size, the reader still says the size the rule gives (its own 30x40 camera, not 33x47's)
    ds = open_dataset("flight", flight, seq_len=1, fov=90.0, size=(33, 47))
    assert ds.opened_size(FocalSize(30.0)) == (45, 60) and ds.opened_size(None) == (30, 40)


@pytest.mark.parametrize(
    "columns",
    [("timestamp", "tx", "ty", "tz", "qw", "qx", "qy", "qz"), ("qx", "tz", "timestamp", "qw", "ty", "qz", "tx", "qy")],
)
def test_csv_poses_any_column_order(flight, columns):
    lines = [",".join(columns)]
    for t, (p, q) in zip(TIMES, POSES):
        v = {"timestamp": t, "tx": p[0], "ty": p[1], "tz": p[2], "qw": q[0], "qx": q[1], "qy": q[2], "qz": q[3]}
        lines.append(",".join(str(v[c]) for c in columns))
    (flight / "track.csv").write_text("\n".join(lines) + "\n")
    q, t, _ = motions(open_dataset("flight", flight, poses=flight / "track.csv", fov=90.0))
    np.testing.assert_allclose(q, EXPECTED_Q, atol=1e-6)
    np.testing.assert_allclose(t, EXPECTED_T, atol=1e-6)


def test_ned_body_poses(flight):
    # Mid-Air-like body poses: 3 m north, then a 90-degree yaw to the right (about body z, down) and 1 m east
    poses = [
        ((0, 0, -10), (1, 0, 0, 0)),
        ((3, 0, -10), (1, 0, 0, 0)),
        ((3, 1, -10), (C, 0, 0, S)),
        ((3, 2, -10), (C, 0, 0, S)),
    ]
    write_tum(flight / "poses.txt", poses=poses)
    q, t, _ = motions(open_dataset("flight", flight, fov=90.0, convention="ned"))
    np.testing.assert_allclose(q, [(1, 0, 0, 0), (1, 0, 0, 0), (C, 0, S, 0), (1, 0, 0, 0)], atol=1e-6)
    # body axes -> camera axes: forward is camera z, right is camera x
    np.testing.assert_allclose(t, [(0, 0, 0), (0, 0, 3), (1, 0, 0), (0, 0, 1)], atol=1e-6)


def test_frame_skip_and_interpolation(tmp_path):
    write_images(tmp_path / "f", ["1.000000.png", "1.050000.png", "1.100000.png", "1.200000.png"])
    write_tum(tmp_path / "f" / "poses.txt")
    q, t, _ = motions(open_dataset("flight", tmp_path / "f", fov=90.0))
    # 1.05 lies halfway between the poses at 1.0 and 1.1: position (0, 0, 1)
    np.testing.assert_allclose(t[:3], [(0, 0, 0), (0, 0, 1), (0, 0, 1)], atol=1e-6)
    q, t, reset = motions(open_dataset("flight", tmp_path / "f", fov=90.0, frame_skip=2))
    np.testing.assert_allclose(q, [(1, 0, 0, 0), (1, 0, 0, 0)], atol=1e-6)
    np.testing.assert_allclose(t, [(0, 0, 0), (0, 0, 2)], atol=1e-6)  # 1.0 -> 1.1
    assert reset == [True, False]


def test_frame_skip_uses_the_motion_between_kept_frames(flight):
    write_tum(flight / "poses.txt")
    q, t, _ = motions(open_dataset("flight", flight, fov=90.0, frame_skip=2))
    np.testing.assert_allclose(q, [(1, 0, 0, 0), (C, 0, S, 0)], atol=1e-6)
    np.testing.assert_allclose(t, [(0, 0, 0), (1, 0, 2)], atol=1e-6)


def test_match_by_order_with_natural_sort(tmp_path):
    names = ["frame_1.jpg", "frame_2.jpg", "frame_10.jpg", "frame_3.jpg"]
    write_images(tmp_path / "f", names)
    write_tum(tmp_path / "f" / "poses.txt")
    ds = open_dataset("flight", tmp_path / "f", fov=90.0)
    q, t, _ = motions(ds)
    np.testing.assert_allclose(t, EXPECTED_T, atol=1e-6)  # poses in file order go with 1, 2, 3, 10
    assert ds.trajectories[0].frames[3].rgb.name == "frame_10.jpg"
    (tmp_path / "f" / "frame_3.jpg").unlink()
    with pytest.raises(DatasetError, match=r"poses\.txt: 4 poses for 3 images"):
        open_dataset("flight", tmp_path / "f", fov=90.0)


def test_intrinsics_are_rescaled_to_the_output_size(flight):
    write_tum(flight / "poses.txt")
    it = open_dataset("flight", flight, intrinsics=(50.0, 40.0, 20.0, 15.0), size=(15, 20))[0]
    assert it["intrinsics"].tolist() == [25.0, 20.0, 10.0, 7.5]
    assert it["rgb"].shape == (1, 3, 15, 20)
    it = open_dataset("flight", flight, intrinsics="50,40,19.5,14.5", intrinsics_convention="opencv", size=(15, 20))[0]
    assert it["intrinsics"].tolist() == [25.0, 20.0, 10.0, 7.5]
    it = open_dataset("flight", flight, fov=90.0, size=(15, 20))[0]
    assert it["intrinsics"].tolist() == [10.0, 10.0, 10.0, 7.5]
    with pytest.raises(ConfigError, match="exactly one of intrinsics"):
        open_dataset("flight", flight)
    with pytest.raises(ConfigError, match="exactly one of intrinsics"):
        open_dataset("flight", flight, fov=90.0, intrinsics=(1, 1, 1, 1))


def test_optional_depth_and_labels(flight):
    write_tum(flight / "poses.txt")
    (flight / "depth").mkdir()
    (flight / "labels").mkdir()
    for k, t in enumerate(TIMES):
        np.save(flight / "depth" / f"{t:.6f}.npy", np.full((H, W), 5.0 + k, np.float32))
        Image.fromarray(np.full((H, W), k, np.uint8)).save(flight / "labels" / f"{t:.6f}.png")
    ds = open_dataset(
        "flight", flight, seq_len=2, fov=90.0, depth_dir=flight / "depth", semantic_dir=flight / "labels", size=(15, 20)
    )
    it = ds[1]
    assert it["depth"].shape == (2, 1, 15, 20) and float(it["depth"][1].mean()) == 8.0
    assert it["semantic"].shape == (2, 15, 20) and int(it["semantic"][0, 0, 0]) == 2
    assert it["reset"].tolist() == [False, False]
    (flight / "depth" / "1.300000.npy").unlink()
    with pytest.raises(DatasetError, match="no depth file for image '1.300000'"):
        open_dataset("flight", flight, fov=90.0, depth_dir=flight / "depth")


def test_timestamps_that_do_not_match_name_the_image(tmp_path):
    write_images(tmp_path / "f", ["1.000000.png", "1.100000.png", "1.500000.png"])
    write_tum(tmp_path / "f" / "poses.txt")
    with pytest.raises(DatasetError, match=r"1\.500000\.png: no pose for timestamp 1\.500000 in .*poses\.txt"):
        open_dataset("flight", tmp_path / "f", fov=90.0, match="stamp")
    # a gap larger than max_gap is not interpolated
    write_images(tmp_path / "g", ["1.000000.png", "1.150000.png"])
    write_tum(tmp_path / "g" / "poses.txt", times=[1.0, 1.1, 1.4, 1.5])
    with pytest.raises(DatasetError, match=r"1\.150000\.png: no pose"):
        open_dataset("flight", tmp_path / "g", fov=90.0)


@pytest.mark.parametrize(
    "line, message",
    [
        ("1.200000 1 0 nan 0 0.7071 0 0.7071", r"poses\.txt:4: tz is nan"),
        ("1.200000 1 0 2 0 0.5 0 0.5", r"poses\.txt:4: quaternion is not unit"),
        ("1.200000 1 0 2 0 0.7071 0", r"poses\.txt:4: expected 8 values"),
        ("1.050000 1 0 2 0 0.7071 0 0.7071", r"poses\.txt:4: timestamps must increase"),
    ],
)
def test_bad_pose_files(flight, line, message):
    path = write_tum(flight / "poses.txt")
    lines = path.read_text().splitlines()
    lines[3] = line
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=message):
        open_dataset("flight", flight, fov=90.0)


def test_missing_pose_file_and_images(tmp_path, flight):
    with pytest.raises(DatasetError, match="no pose file given"):
        open_dataset("flight", flight, fov=90.0)
    with pytest.raises(DatasetError, match=r"nope\.txt: pose file not found"):
        open_dataset("flight", flight, fov=90.0, poses=flight / "nope.txt")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="no images"):
        open_dataset("flight", tmp_path / "empty", fov=90.0)


def test_images_of_another_size_and_no_writes(flight):
    write_tum(flight / "poses.txt")
    before = snapshot(flight)
    list(open_dataset("flight", flight, fov=90.0, size=16, augment=True))
    assert snapshot(flight) == before
    Image.fromarray(np.zeros((H + 2, W, 3), np.uint8)).save(flight / "1.200000.png")
    with pytest.raises(DatasetError, match=r"1\.200000\.png: image is 32x40 but the flight's first image is 30x40"):
        open_dataset("flight", flight, fov=90.0)[2]
