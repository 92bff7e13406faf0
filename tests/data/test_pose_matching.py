"""Matching a flight's images to its poses: stamp, order, index and auto; units; skipped images; the reasons."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cosemdepth.data import open_dataset
from cosemdepth.data.pose_matching import match_images
from cosemdepth.data.poses import read_poses
from cosemdepth.errors import ConfigError, DatasetError


def tum(path: Path, stamps) -> Path:
    """Pose row i at position (i, 0, 0), no rotation: a matched position names its row."""
    path.write_text("".join(f"{t} {i} 0 0 0 0 0 1\n" for i, t in enumerate(stamps)))
    return path


def names(*stems, ext=".png") -> list[Path]:
    return [Path("imgs") / f"{s}{ext}" for s in stems]


def rows(m) -> list[float]:
    return m.positions[:, 0].tolist()


def test_frame_numbers_with_stamps_from_zero_are_matched_by_order(tmp_path):
    """000000.png ... with a pose file counted from 0 s: one stem (0) is in the poses' range, the rest are not;
    the names are frame numbers, not stamps."""
    track = read_poses(tum(tmp_path / "p.txt", [f"{0.04 * k:.2f}" for k in range(16)]))
    m = match_images(names(*(f"{k:06d}" for k in range(16))), track)
    assert m.match == "order" and rows(m) == list(range(16))
    assert m.reason == "image names are zero-padded frame numbers; one pose per image"
    # the same frames without zero padding: not all of them are stamps within 0..0.6 s
    m = match_images(names(*range(16)), track)
    assert m.match == "order" and m.reason.startswith("15 of 16 image names are outside the poses' time range")


def test_auto_never_guesses_index(tmp_path):
    track = read_poses(tum(tmp_path / "p.txt", [f"{0.01 * i:.2f}" for i in range(64)]))
    with pytest.raises(
        DatasetError,
        match=r"p\.txt: cannot tell how the 8 images of imgs go with its 64 poses: "
        r"image names are zero-padded frame numbers, and the counts differ .*if image k goes with "
        r"pose row k \(rows numbered from 0\), pass --match index",
    ):
        match_images(names(*(f"{k:06d}" for k in range(0, 16, 2))), track)


def test_index_takes_the_row_of_each_frame_number(tmp_path):
    track = read_poses(tum(tmp_path / "p.txt", [f"{0.04 * k:.2f}" for k in range(16)]))
    m = match_images(names(*(f"{k:06d}" for k in (6, 0, 4, 2))), track, match="index")
    assert m.match == "index" and m.reason is None
    assert [p.stem for p in m.images] == ["000000", "000002", "000004", "000006"] and rows(m) == [0, 2, 4, 6]
    np.testing.assert_allclose(m.times, [0.0, 0.08, 0.16, 0.24])
    # a frame number past the last row: an error naming the image, or skipped and counted
    frames = names(*(f"{k:06d}" for k in (0, 15, 16, 20)))
    with pytest.raises(
        DatasetError,
        match=r"000016\.png: frame number 16 has no pose: .*p\.txt has 16 pose rows, "
        r"numbered from 0",
    ):
        match_images(frames, track, match="index")
    m = match_images(frames, track, match="index", skip_unposed=True)
    assert rows(m) == [0, 15] and [p.name for p in m.skipped] == ["000016.png", "000020.png"]
    assert m.summary()["skipped"] == 2 and m.summary()["first_skipped"].endswith("000016.png")
    with pytest.raises(DatasetError, match=r"img_1\.png: image name is not a frame number"):
        match_images(names("img_1"), track, match="index")


def test_auto_takes_stamps_only_when_every_name_is_in_range(tmp_path):
    track = read_poses(tum(tmp_path / "p.txt", ["1.0", "1.1", "1.2", "1.3", "1.4"]))
    m = match_images(names("1.05", "1.25", "1.4"), track)
    assert m.match == "stamp" and m.reason == "every image name is a stamp within the poses' time range"
    np.testing.assert_allclose(rows(m), [0.5, 2.5, 4.0])  # interpolated halfway, and exact
    # one name out of range: not stamps; 3 images for 5 poses: not order either
    with pytest.raises(
        DatasetError,
        match=r"1 of 3 image names are outside the poses' time range as stamps, and the "
        "counts differ",
    ):
        match_images(names("1.05", "1.25", "9.0"), track)
    # asked for explicitly, the image out of range is an error naming it, or skipped
    with pytest.raises(DatasetError, match=r"9\.0\.png: no pose for timestamp 9\.000000"):
        match_images(names("1.05", "1.25", "9.0"), track, match="stamp")
    m = match_images(names("1.05", "1.25", "9.0"), track, match="stamp", skip_unposed=True)
    assert [p.name for p in m.skipped] == ["9.0.png"] and m.total == 3 and m.indices.tolist() == [0, 1]


def test_max_gap_is_the_one_given_and_the_message_says_it(tmp_path):
    track = read_poses(tum(tmp_path / "p.txt", ["1.0", "1.3"]))
    with pytest.raises(
        DatasetError,
        match=r"1\.1\.png: no pose for timestamp 1\.100000 .*poses 0\.100000 s before "
        r"and 0\.200000 s after, 0\.300000 s apart; .*interpolation only across gaps <= 0\.25 s: "
        r"--max-pose-gap, or --skip-unposed\)$",
    ):
        match_images(names("1.1"), track, match="stamp", max_gap=0.25)
    m = match_images(names("1.1"), track, match="stamp", max_gap=0.3)
    np.testing.assert_allclose(rows(m), [1 / 3])
    assert m.summary()["max_pose_gap_s"] == 0.3
    with pytest.raises(ConfigError, match="--max-pose-gap must be >= 0 seconds"):
        match_images(names("1.1"), track, max_gap=-1.0)


def test_nanosecond_names_match_poses_in_seconds_or_nanoseconds(tmp_path):
    t0 = 1700000000 * 10**9
    images = names(*(t0 + k * 40_000_000 + 5_000_000 for k in range(3)))  # between poses 10 ms apart
    for stamps in ([f"{1700000000 + 0.01 * i:.2f}" for i in range(16)], [t0 + i * 10_000_000 for i in range(16)]):
        track = read_poses(tum(tmp_path / "p.txt", stamps))
        m = match_images(images, track)
        assert m.match == "stamp"
        np.testing.assert_allclose(rows(m), [0.5, 4.5, 8.5], atol=1e-4)
        np.testing.assert_allclose(m.times - 1700000000, [0.005, 0.045, 0.085], atol=1e-6)
        assert m.summary()["image_stamp_unit"] == {"unit": "ns", "how": "epoch"}


def test_nanoseconds_from_zero_need_the_unit_and_the_error_says_so(tmp_path):
    images = names(*(k * 40_000_000 + 5_000_000 for k in range(3)))
    track = read_poses(tum(tmp_path / "p.txt", [i * 10_000_000 for i in range(16)]))
    with pytest.raises(
        DatasetError,
        match=r"5000000\.png: no pose for timestamp 5000000\.000000 .*interpolation "
        r"only across gaps <= 0\.1 s.*read as s \(the default.*pass --stamp-unit ns$",
    ):
        match_images(images, track)
    m = match_images(images, track, stamp_unit="ns")
    np.testing.assert_allclose(rows(m), [0.5, 4.5, 8.5])
    np.testing.assert_allclose(m.times, [0.005, 0.045, 0.085])
    # image names in ns, poses in s, both from 0: auto finds no match, the message says which units would
    track = read_poses(tum(tmp_path / "p.txt", [f"{0.01 * i:.2f}" for i in range(16)]))
    with pytest.raises(DatasetError, match=r"pass --stamp-unit ns,s$"):
        match_images(images, track)
    m = match_images(images, track, stamp_unit=("ns", "s"))
    assert m.match == "stamp"
    np.testing.assert_allclose(rows(m), [0.5, 4.5, 8.5])


def test_a_given_stamp_unit_is_never_ignored_by_auto(tmp_path):
    """One pose per image, but the names in ns and the poses declared in s: auto would take the order and the
    unit would change nothing; given, the unit means stamps, and the mismatch is the error."""
    t0 = 1700000000 * 10**9
    images = names(*(t0 + k * 40_000_000 for k in range(3)))
    track = read_poses(tum(tmp_path / "p.txt", [t0 + k * 40_000_000 for k in range(3)]))  # ns, as the names
    assert match_images(images, track).match == "stamp"  # auto reads both as ns
    assert match_images(images, track, stamp_unit="ns").match == "stamp"
    with pytest.raises(DatasetError, match=r"no pose for timestamp"):
        match_images(images, track, stamp_unit=("ns", "s"))  # poses read as 1.7e18 s: no image fits
    m = match_images(images, track, stamp_unit=("ns", "s"), match="order")  # the rule given: the unit is moot
    assert m.match == "order" and rows(m) == [0.0, 1.0, 2.0]


def test_open_flight_keeps_what_was_matched(tmp_path):
    from PIL import Image

    (tmp_path / "f").mkdir()
    for k in range(5):
        Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(tmp_path / "f" / f"{k / 10:.1f}.png")
    tum(tmp_path / "f" / "poses.txt", ["0.0", "0.1", "0.35", "0.4"])  # 0.1 .. 0.35: a 0.25 s gap
    with pytest.raises(DatasetError, match=r"0\.2\.png: no pose .*gaps <= 0\.1 s"):
        open_dataset("flight", tmp_path / "f", fov=90.0)
    ds = open_dataset("flight", tmp_path / "f", fov=90.0, skip_unposed=True)
    (traj,) = ds.trajectories
    assert [f.rgb.name for f in traj.frames] == ["0.0.png", "0.1.png", "0.4.png"]
    assert [f.id for f in traj.frames] == [0, 1, 4]  # the image's place among all images
    info = ds.pose_matching
    assert (info["match"], info["chosen_by"], info["images"], info["posed"], info["skipped"]) == (
        "stamp",
        "auto",
        5,
        3,
        2,
    )
    assert info["describe"] == (
        "3 of 5 images matched to poses by stamp (auto: every image name is a stamp within "
        "the poses' time range; image names in s, pose stamps in s, interpolation across "
        "gaps <= 0.1 s), 2 skipped without a pose (first: 0.2.png)"
    )
    ds = open_dataset("flight", tmp_path / "f", fov=90.0, max_gap=0.25)
    assert len(ds.trajectories[0].frames) == 5 and ds.pose_matching["skipped"] == 0
    with pytest.raises(ConfigError, match="match must be one of auto, stamp, order, index"):
        open_dataset("flight", tmp_path / "f", fov=90.0, match="timestamp")


def test_frame_numbers_read_as_stamps_say_so(tmp_path):
    track = read_poses(tum(tmp_path / "p.txt", [f"{0.04 * k:.2f}" for k in range(16)]))
    with pytest.raises(
        DatasetError,
        match=r"000001\.png: no pose for timestamp 1\.000000 .*; the image names look "
        r"like zero-padded frame numbers: --match order \(one pose per image\) or index$",
    ):
        match_images(names(*(f"{k:06d}" for k in range(16))), track, match="stamp")
    # frame numbers past the end of a longer track: index is suggested only for names that can be row numbers
    with pytest.raises(DatasetError) as e:
        match_images(names(*(3_000_000 + k for k in range(3))), track)
    assert "--match index" not in str(e.value) and "to match by stamp anyway: --match stamp" in str(e.value)
