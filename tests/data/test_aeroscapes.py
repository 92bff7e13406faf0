"""Aeroscapes: ImageSets split files, 12 classes, semantic only, identity motion, every image a reset."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from _writers import snapshot, write_png_gray
from PIL import Image

from cosemdepth.data import open_dataset
from cosemdepth.errors import DatasetError

H, W = 18, 32  # 720x1280 scaled down by 40


def write_aeroscapes(root):
    rng = np.random.default_rng(0)
    names = [f"00000{i}_00{i}" for i in range(5)]
    labels = {}
    (root / "JPEGImages").mkdir(parents=True)
    for n in names:
        rgb = np.full((H, W, 3), 100, np.uint8)
        Image.fromarray(rgb).save(root / "JPEGImages" / f"{n}.jpg", quality=95)
        labels[n] = rng.integers(0, 12, (H, W), dtype=np.uint8)
        write_png_gray(root / "SegmentationClass" / f"{n}.png", labels[n])
    (root / "ImageSets").mkdir()
    (root / "ImageSets" / "trn.txt").write_text("\n".join([names[3], names[0], names[4]]) + "\n")
    (root / "ImageSets" / "val.txt").write_text(f"{names[2]}\n\n{names[1]}\n")
    return names, labels


def test_split_files_order_and_item_layout(tmp_path):
    names, labels = write_aeroscapes(tmp_path)
    train = list(open_dataset("aeroscapes", tmp_path, split="train"))
    assert len(train) == 3
    for it, n in zip(train, [names[3], names[0], names[4]]):
        assert "depth" not in it
        assert it["rgb"].shape == (1, 3, H, W)
        np.testing.assert_array_equal(it["semantic"][0].numpy(), labels[n])
        assert it["rot"].tolist() == [[1.0, 0.0, 0.0, 0.0]] and it["trans"].tolist() == [[0.0, 0.0, 0.0]]
        assert it["reset"].tolist() == [True]
        assert it["intrinsics"].tolist() == [W / 2, H / 2, W / 2, H / 2]
    val = open_dataset("aeroscapes", tmp_path, split="val", seq_len=2)
    assert len(val) == 1
    it = val[0]
    assert it["reset"].tolist() == [True, True]
    np.testing.assert_array_equal(it["semantic"][1].numpy(), labels[names[1]])
    # 'test' reads val.txt (Aeroscapes has no test split)
    assert len(open_dataset("aeroscapes", tmp_path, split="test")) == 2


def test_any_output_size(tmp_path):
    names, labels = write_aeroscapes(tmp_path)
    it = open_dataset("aeroscapes", tmp_path, split="val", size=(9, 16))[0]
    assert it["rgb"].shape == (1, 3, 9, 16) and it["semantic"].shape == (1, 9, 16)
    assert torch.equal(it["semantic"][0], torch.from_numpy(labels[names[2]][1::2, 1::2]).long())
    assert it["intrinsics"].tolist() == [8.0, 4.5, 8.0, 4.5]
    it = open_dataset("aeroscapes", tmp_path, split="val", size=20, augment=True)[0]
    assert it["rgb"].shape == (1, 3, 20, 20)


def test_errors_name_the_file(tmp_path):
    names, _ = write_aeroscapes(tmp_path)
    with pytest.raises(DatasetError, match=r"ImageSets/trn\.txt: Aeroscapes split file not found"):
        (tmp_path / "ImageSets" / "trn.txt").unlink()
        open_dataset("aeroscapes", tmp_path, split="train")
    with pytest.raises(DatasetError, match="splits"):
        open_dataset("aeroscapes", tmp_path, split="holdout")
    bad = np.zeros((H, W), np.uint8)
    bad[2, 2] = 12
    write_png_gray(tmp_path / "SegmentationClass" / f"{names[2]}.png", bad)
    with pytest.raises(DatasetError, match=rf"{names[2]}\.png: label ID 12 out of range 0\.\.11"):
        open_dataset("aeroscapes", tmp_path, split="val")[0]
    (tmp_path / "JPEGImages" / f"{names[1]}.jpg").unlink()
    with pytest.raises(DatasetError, match=rf"{names[1]}\.jpg: file not found"):
        open_dataset("aeroscapes", tmp_path, split="val")[1]


def test_reader_writes_nothing(tmp_path):
    write_aeroscapes(tmp_path)
    before = snapshot(tmp_path)
    list(open_dataset("aeroscapes", tmp_path, split="train", size=16))
    assert snapshot(tmp_path) == before
