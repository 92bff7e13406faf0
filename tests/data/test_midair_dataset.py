"""The Mid-Air reader on a tiny dataset written by the test writer: exact decoding, resize rules, windows,
bad input, and no writes into the dataset folder."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch
from _writers import read_split_rows, snapshot, write_midair
from PIL import Image

from cosemdepth.data import make_loader, open_dataset
from cosemdepth.data.frames import FocalSize
from cosemdepth.data.midair.splits import generate_splits
from cosemdepth.errors import ConfigError, DatasetError

SIZE = 32
SPEC_MAP = np.array([0, 6, 2, 3, 3, 3, 4, 6, 1, 6, 5, 6, 6, 6])  # design 10.5, by Mid-Air ID
LAYOUT = {("Kite_training", "sunny"): [0, 1, 2, 3], ("PLE_training", "fall"): [4000, 4006, 4001]}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    base = tmp_path_factory.mktemp("midair")
    truth = write_midair(base / "root", LAYOUT, frames=20, size=SIZE)
    generate_splits(base / "root", base / "splits")
    return truth, base / "root", base / "splits"


def decoded_jpeg(path) -> np.ndarray:
    """Pillow's decode (the accurate IDCT): what the reader gives with ``jpeg_idct="accurate"``; the default fast
    IDCT is checked against djpeg's pixels in test_decode.py."""
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB")).astype(np.float32) / np.float32(255)


def test_items_read_back_exactly_at_native_size(dataset):
    truth, root, splits = dataset
    ds = open_dataset("midair", root, split_dir=splits, split="test", seq_len=1, size=SIZE, jpeg_idct="accurate")
    assert len(ds) > 0
    for item in ds:
        traj = item["trajectory"]
        row = read_split_rows(splits / "test_data" / f"{traj}.csv")[int(item["frame"][0])]
        rgb = item["rgb"][0].permute(1, 2, 0).numpy()
        np.testing.assert_array_equal(rgb, decoded_jpeg(root / row["camera_l"]))
        assert np.abs(rgb * 255 - truth.rgb[row["camera_l"]]).mean() < 3  # JPEG quality 95
        disp = truth.disparity_bits[row["disp"]].view(np.float16).astype(np.float32)
        np.testing.assert_array_equal(item["depth"][0, 0].numpy(), np.float32(512) / disp)  # any size (design 10.2)
        np.testing.assert_array_equal(item["semantic"][0].numpy(), SPEC_MAP[truth.labels[row["semantic"]]])
        assert item["semantic"].dtype == torch.int64
        np.testing.assert_array_equal(
            item["rot"][0].numpy(), np.array([row[c] for c in ("qw", "qx", "qy", "qz")], dtype=np.float32)
        )
        np.testing.assert_array_equal(
            item["trans"][0].numpy(), np.array([row[c] for c in ("tx", "ty", "tz")], dtype=np.float32)
        )
        assert item["intrinsics"].tolist() == [16.0, 16.0, 16.0, 16.0]
        assert item["reset"].tolist() == [int(row["id"]) == 0]


def test_resize_rules_bl2_for_colour_and_depth_nearest_for_labels(dataset):
    truth, root, splits = dataset
    native = open_dataset("midair", root, split_dir=splits, split="test", seq_len=1, size=SIZE)[2]
    half = open_dataset("midair", root, split_dir=splits, split="test", seq_len=1, size=16)[2]

    # an exact 2x downsampling with half-pixel bilinear is the mean of each 2x2 block
    def block_mean(x):
        return x.reshape(*x.shape[:-2], 16, 2, 16, 2).mean(dim=(-3, -1))

    torch.testing.assert_close(half["rgb"], block_mean(native["rgb"]), rtol=0, atol=1e-6)
    torch.testing.assert_close(half["depth"], block_mean(native["depth"]), rtol=1e-6, atol=0)
    assert torch.equal(half["semantic"], native["semantic"][:, ::2, ::2])  # OpenCV nearest: floor(k * 2)
    assert half["intrinsics"].tolist() == [8.0, 8.0, 8.0, 8.0]
    odd = open_dataset("midair", root, split_dir=splits, split="test", seq_len=1, size=(12, 20))[2]
    rows = np.floor(np.arange(12) * 32 / 12).astype(int)
    cols = np.floor(np.arange(20) * 32 / 20).astype(int)
    assert torch.equal(odd["semantic"][0], native["semantic"][0][rows][:, cols])
    assert odd["rgb"].shape == (1, 3, 12, 20) and odd["depth"].shape == (1, 1, 12, 20)
    assert odd["intrinsics"].tolist() == [10.0, 6.0, 10.0, 6.0]


def test_seq_len_1_on_test_split_yields_every_csv_row_in_order(dataset):
    _, root, splits = dataset
    csvs = sorted((splits / "test_data").rglob("*.csv"), key=lambda p: p.as_posix())
    expected = [(c, r) for c in csvs for r in read_split_rows(c)]
    ds = open_dataset("midair", root, split_dir=splits, split="test", seq_len=1, size=8)
    items = list(ds)
    assert len(items) == len(expected) == len(ds) == 3 * 4
    for item, (csv_path, row) in zip(items, expected):
        assert item["trajectory"] == csv_path.relative_to(splits / "test_data").with_suffix("").as_posix()
        assert item["id"].tolist() == [int(row["id"])]
        assert item["reset"].tolist() == [row["id"] == "0"]
    # the colour of each item is the image its row names
    native = open_dataset("midair", root, split_dir=splits, split="test", seq_len=1, size=SIZE, jpeg_idct="accurate")
    for item, (_, row) in zip(native, expected):
        np.testing.assert_array_equal(item["rgb"][0].permute(1, 2, 0).numpy(), decoded_jpeg(root / row["camera_l"]))


def test_stream_windows_are_consecutive_and_drop_the_remainder(dataset):
    _, root, splits = dataset
    ds = open_dataset("midair", root, split_dir=splits, split="test", seq_len=3, size=8)
    assert len(ds) == 3  # 4 rows per trajectory -> one window of 3
    for item in ds:
        assert item["frame"].tolist() == [0, 1, 2]
        assert item["reset"].tolist() == [True, False, False]
        assert item["rgb"].shape == (3, 3, 8, 8)


def test_train_windows_random_offset_in_chunks_and_reset_first(dataset):
    _, root, splits = dataset
    ds = open_dataset("midair", root, split_dir=splits, split="train", seq_len=2, size=8, db_seq_len=4, seed=3)
    n_train = len(list((splits / "train_data").rglob("*.csv")))
    assert len(ds) == n_train  # one chunk of 4 rows per trajectory
    offsets = set()
    for epoch in range(8):
        ds.set_epoch(epoch)
        for i in range(len(ds)):
            item = ds[i]
            f = item["frame"].tolist()
            assert f[1] == f[0] + 1 and 0 <= f[0] <= 2
            assert item["reset"].tolist() == [True, False]
            offsets.add(f[0])
            if epoch == 0:
                assert torch.equal(ds[i]["rgb"], item["rgb"])  # same (seed, epoch, index) -> same item
    assert offsets == {0, 1, 2}
    with pytest.raises(ConfigError, match="db_seq_len"):
        open_dataset("midair", root, split_dir=splits, split="train", seq_len=4, db_seq_len=2)
    with pytest.raises(DatasetError, match="no window of 8 rows fits"):
        open_dataset("midair", root, split_dir=splits, split="train", seq_len=2, db_seq_len=8)


def _csv_norms(folder):
    """``||t||`` of every row of every CSV under ``folder`` (sorted paths, as the reader takes them), by a plain parse."""
    out = []
    for csv in sorted(folder.rglob("*.csv"), key=lambda p: p.relative_to(folder).as_posix()):
        out.append([float(np.linalg.norm([float(r[c]) for c in ("tx", "ty", "tz")])) for r in read_split_rows(csv)])
    return out


def test_step_translations_are_the_window_rows_after_the_first(dataset):
    _, root, splits = dataset
    train = _csv_norms(splits / "train_data")
    assert train and all(len(rows) == 4 for rows in train)
    # train windows of 2 in chunks of 4: any row of a chunk but its first is a later frame of some window
    ds = open_dataset("midair", root, split_dir=splits, split="train", seq_len=2, size=8, db_seq_len=4)
    np.testing.assert_allclose(ds.step_translations(), [n for rows in train for n in rows[1:4]], rtol=1e-6)
    # windowed (val, seq_len 2): windows rows 0-1 and 2-3, their second rows
    val = _csv_norms(splits / "val_data")
    ds = open_dataset("midair", root, split_dir=splits, split="val", seq_len=2, size=8)
    np.testing.assert_allclose(ds.step_translations(), [rows[k] for rows in val for k in (1, 3)], rtol=1e-6)
    # streaming every row: all but the resets (the first row of each trajectory: CSV id 0)
    test = _csv_norms(splits / "test_data")
    ds = open_dataset("midair", root, split_dir=splits, split="test", seq_len=1, size=8)
    np.testing.assert_allclose(ds.step_translations(), [n for rows in test for n in rows[1:]], rtol=1e-6)


def test_a_focal_size_rule_opens_the_split_where_its_camera_has_that_focal_length(dataset):
    _, root, splits = dataset
    # native 32x32 with the 90-degree camera (f = 16 px): a focal length of 8 px is the 16x16 size
    ds = open_dataset("midair", root, split_dir=splits, split="test", seq_len=1, size=FocalSize(8.0))
    ref = open_dataset("midair", root, split_dir=splits, split="test", seq_len=1, size=16)
    assert ds.intrinsics.tolist() == [8.0, 8.0, 8.0, 8.0]
    assert torch.equal(ds[1]["rgb"], ref[1]["rgb"]) and ds[1]["rgb"].shape[-2:] == (16, 16)
    assert open_dataset("midair", root, split_dir=splits, split="test", size=FocalSize(20.0))[0]["rgb"].shape[-2:] == (
        40,
        40,
    )


def test_val_split_uses_windows_with_reset_first(dataset):
    _, root, splits = dataset
    ds = open_dataset("midair", root, split_dir=splits, split="val", seq_len=4, size=8)
    assert ds.mode == "windowed"
    items = list(ds)
    assert len(items) == 1  # PLE_training/fall trajectory 4006 is validation
    assert items[0]["trajectory"] == "PLE_training/fall/traj_0002"
    assert items[0]["reset"].tolist() == [True, False, False, False]


def test_label_modes(dataset, tmp_path):
    truth, root, splits = dataset
    raw = open_dataset("midair", root, split_dir=splits, split="test", size=SIZE, labels="raw")[0]
    row = read_split_rows(splits / "test_data" / f"{raw['trajectory']}.csv")[0]
    np.testing.assert_array_equal(raw["semantic"][0].numpy(), truth.labels[row["semantic"]])
    with pytest.raises(
        DatasetError, match=r"segmentation/trajectory_\d{4}/000004\.PNG: label ID 1[0-3] out of range 0\.\.6"
    ):
        open_dataset("midair", root, split_dir=splits, split="test", size=SIZE, labels="mapped")[0]
    seven = write_midair(tmp_path / "root7", {("Kite_training", "sunny"): [0]}, frames=8, label_ids=7)
    generate_splits(tmp_path / "root7", tmp_path / "splits7")
    item = open_dataset("midair", tmp_path / "root7", split_dir=tmp_path / "splits7", size=SIZE, labels="mapped")[0]
    row = read_split_rows(tmp_path / "splits7/test_data/Kite_training/sunny/traj_0000.csv")[0]
    np.testing.assert_array_equal(item["semantic"][0].numpy(), seven.labels[row["semantic"]])


def test_modalities_option_and_semantic_column_derived_when_missing(dataset, tmp_path):
    _, root, splits = dataset
    item = open_dataset("midair", root, split_dir=splits, split="test", size=8, modalities=("depth",))[0]
    assert "semantic" not in item and "depth" in item
    # CSVs written by the original generator have no semantic column: the path is derived from camera_l
    src = splits / "test_data" / "Kite_training" / "sunny" / "traj_0000.csv"
    rows = src.read_text().splitlines()
    cut = ["\t".join(f for i, f in enumerate(ln.split("\t")) if i != 3) for ln in rows]
    (tmp_path / "s" / "test_data").mkdir(parents=True)
    (tmp_path / "s" / "test_data" / "traj_0000.csv").write_text("\n".join(cut) + "\n")
    a = open_dataset("midair", root, split_dir=tmp_path / "s", split="test", size=8)[1]
    b = open_dataset("midair", root, split_dir=splits, split="test", size=8)[1]
    assert torch.equal(a["semantic"], b["semantic"])


def test_synthair_default_split_dir_and_any_env_names(tmp_path):
    write_midair(tmp_path / "synth", {("SynthAir", "sunset"): [0, 1, 2, 3]}, frames=12, size=16)
    generate_splits(tmp_path / "synth", tmp_path / "synth" / "splits")  # the generator's location
    ds = open_dataset("synthair", tmp_path / "synth", split="test", seq_len=1, size=16)
    # generic rule: indices 0 and 3 are test, and the last test trajectory of the climate is validation
    assert [it["trajectory"] for it in ds] == ["SynthAir/sunset/traj_0000"] * 2
    val = open_dataset("synthair", tmp_path / "synth", split="val", seq_len=2, size=16)
    assert [it["trajectory"] for it in val] == ["SynthAir/sunset/traj_0003"]
    assert ds.name == "synthair"


def test_open_dataset_argument_errors(dataset):
    _, root, splits = dataset
    with pytest.raises(ConfigError, match="split_dir"):
        open_dataset("midair", root)
    with pytest.raises(ConfigError, match="unknown dataset 'kitti'"):
        open_dataset("kitti", root)
    with pytest.raises(ConfigError, match=r"unknown option\(s\) \['colour'\]"):
        open_dataset("midair", root, split_dir=splits, colour=True)
    with pytest.raises(ConfigError, match="size"):
        open_dataset("midair", root, split_dir=splits, size=(3, 4, 5))
    with pytest.raises(DatasetError, match="no 'nosuch' split"):
        open_dataset("midair", root, split_dir=splits, split="nosuch")


@pytest.fixture
def copy(dataset, tmp_path):
    _, root, splits = dataset
    shutil.copytree(root, tmp_path / "root")
    shutil.copytree(splits, tmp_path / "splits")
    return tmp_path / "root", tmp_path / "splits"


def first_row(splits):
    csv = splits / "test_data" / "Kite_training" / "sunny" / "traj_0000.csv"
    return csv, read_split_rows(csv)[0]


def test_missing_image_names_the_file(copy):
    root, splits = copy
    _, row = first_row(splits)
    (root / row["camera_l"]).unlink()
    ds = open_dataset("midair", root, split_dir=splits, split="test", size=8)
    with pytest.raises(DatasetError, match=r"trajectory_0000/000004\.JPEG: file not found"):
        ds[0]


def test_truncated_jpeg_names_the_file(copy):
    root, splits = copy
    _, row = first_row(splits)
    p = root / row["camera_l"]
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    with pytest.raises(DatasetError, match=r"000004\.JPEG: corrupt JPEG"):
        open_dataset("midair", root, split_dir=splits, split="test", size=8)[0]


def test_corrupt_png_names_the_file(copy):
    root, splits = copy
    _, row = first_row(splits)
    p = root / row["disp"]
    data = bytearray(p.read_bytes())
    data[60:90] = bytes(30)
    p.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match=r"stereo_disparity/trajectory_0000/000004\.PNG: corrupt image"):
        open_dataset("midair", root, split_dir=splits, split="test", size=8)[0]
    p.write_bytes(b"not a png at all")
    with pytest.raises(DatasetError, match=r"000004\.PNG: not a PNG"):
        open_dataset("midair", root, split_dir=splits, split="test", size=8)[0]


def test_label_out_of_range_names_the_file(copy):
    root, splits = copy
    _, row = first_row(splits)
    ids = np.zeros((SIZE, SIZE), np.uint8)
    ids[3, 4] = 14
    Image.fromarray(ids).save(root / row["semantic"])
    with pytest.raises(
        DatasetError, match=r"segmentation/trajectory_0000/000004\.PNG: label ID 14 out of range 0\.\.13"
    ):
        open_dataset("midair", root, split_dir=splits, split="test", size=8)[0]


def test_label_png_flavours(copy):
    root, splits = copy
    _, row = first_row(splits)
    ref = open_dataset("midair", root, split_dir=splits, split="test", size=SIZE)[0]["semantic"]
    with Image.open(root / row["semantic"]) as im:
        ids = np.asarray(im)
    Image.fromarray(ids.astype(np.uint16)).save(root / row["semantic"])  # 16-bit gray
    assert torch.equal(open_dataset("midair", root, split_dir=splits, split="test", size=SIZE)[0]["semantic"], ref)
    rgb = np.stack([ids, np.full_like(ids, 200), np.zeros_like(ids)], axis=-1)  # RGB, ID in channel 0
    Image.fromarray(rgb).save(root / row["semantic"])
    assert torch.equal(open_dataset("midair", root, split_dir=splits, split="test", size=SIZE)[0]["semantic"], ref)


@pytest.mark.parametrize("message", ["NaN", "not unit"])
def test_bad_csv_fails_at_open_naming_file_and_line(copy, message):
    root, splits = copy
    csv, _ = first_row(splits)
    lines = csv.read_text().splitlines()
    fields = lines[2].split("\t")
    fields[4] = "nan" if message == "NaN" else "0.5"
    lines[2] = "\t".join(fields)
    csv.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=rf"traj_0000\.csv:3: .*{message}"):
        open_dataset("midair", root, split_dir=splits, split="test")


def test_truncated_csv_fails_at_open(copy):
    root, splits = copy
    csv, _ = first_row(splits)
    text = csv.read_text()
    csv.write_text(text[: len(text) - 40])
    with pytest.raises(DatasetError, match=r"traj_0000\.csv:\d+: .*truncated"):
        open_dataset("midair", root, split_dir=splits, split="test")


def test_readers_never_write_into_the_dataset_folder(copy):
    root, splits = copy
    before = snapshot(root)
    for split, kw in (("test", {}), ("train", {"augment": True, "db_seq_len": 4}), ("val", {"seq_len": 4})):
        ds = open_dataset("midair", root, split_dir=splits, split=split, size=16, **kw)
        for _ in ds:
            pass
    ds = open_dataset("midair", root, split_dir=splits, split="test", size=16)
    for _ in make_loader(ds, batch_size=2, num_workers=2):
        pass
    assert snapshot(root) == before


def test_val_split_with_seq_len_1_streams_with_csv_resets(dataset):
    _, root, splits = dataset
    ds = open_dataset("midair", root, split_dir=splits, split="val", seq_len=1, size=8)
    assert ds.mode == "stream"
    assert [bool(it["reset"][0]) for it in ds] == [True, False, False, False]
    assert (
        open_dataset("midair", root, split_dir=splits, split="val", seq_len=2, size=8, mode="stream").mode == "stream"
    )
