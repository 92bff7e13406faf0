"""TopAir: 8-bit depth, 9 classes, CSVs whose first row has id -1 (the true first frame must be a reset)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from _writers import snapshot, write_png_gray
from PIL import Image

from cosemdepth.cli.main import main
from cosemdepth.data import open_dataset
from cosemdepth.data.topair_splits import read_airsim_rec
from cosemdepth.errors import DatasetError

HEADER = "id\tcamera_l\tdepth\tsemantic\tqw\tqx\tqy\tqz\ttx\tty\ttz"
N = 6


def write_topair(root, env="OakForest_3", size=16, seed=0):
    rng = np.random.default_rng(seed)
    truth = {}
    for i in range(N):
        name = f"{i:06d}.png"
        rgb = rng.integers(0, 256, (size, size, 3), dtype=np.uint8)
        depth = rng.integers(0, 256, (size, size), dtype=np.uint8)
        labels = rng.integers(0, 9, (size, size), dtype=np.uint8)
        (root / env / "images").mkdir(parents=True, exist_ok=True)
        Image.fromarray(rgb).save(root / env / "images" / name)
        write_png_gray(root / env / "depth" / name, depth)
        write_png_gray(root / env / "seg_id" / name, labels)
        truth[i] = (rgb, depth, labels)
    rows = [
        HEADER,
        f"-1\t{env}/images/000000.png\t{env}/depth/000000.png\t{env}/seg_id/000000.png\t"
        "1.000000\t0.000000\t0.000000\t0.000000\t0.000100\t0.000100\t0.000100",
    ]
    for k in range(N - 1):
        name = f"{k + 1:06d}.png"
        rows.append(
            f"{k}\t{env}/images/{name}\t{env}/depth/{name}\t{env}/seg_id/{name}\t"
            f"1.000000\t0.000000\t0.000000\t0.000000\t0.1\t0.0\t{1.0 + k}"
        )
    (root / "splits" / "test_data").mkdir(parents=True, exist_ok=True)
    (root / "splits" / "test_data" / "traj_0011.csv").write_text("\n".join(rows) + "\n")
    return truth


def test_topair_reads_depth_labels_and_resets_on_the_true_first_frame(tmp_path):
    truth = write_topair(tmp_path)
    ds = open_dataset("topair", tmp_path, split="test", seq_len=1, size=16)
    items = list(ds)
    assert len(items) == N
    assert [bool(it["reset"][0]) for it in items] == [True] + [False] * (N - 1)
    assert [int(it["id"][0]) for it in items] == list(range(-1, N - 1))
    for i, it in enumerate(items):
        rgb, depth, labels = truth[i]
        np.testing.assert_array_equal(it["rgb"][0].permute(1, 2, 0).numpy(), rgb.astype(np.float32) / np.float32(255))
        np.testing.assert_allclose(it["depth"][0, 0].numpy(), depth * (100.0 / 255.0), rtol=1e-6)
        np.testing.assert_array_equal(it["semantic"][0].numpy(), labels)
        assert it["intrinsics"].tolist() == [8.0, 8.0, 8.0, 8.0]
    assert items[3]["trans"][0].tolist() == pytest.approx([0.1, 0.0, 3.0])
    # nearest (TF2 half-pixel) resize of depth and labels: 16 -> 8 picks indices 1, 3, 5, ...
    small = open_dataset("topair", tmp_path, split="test", seq_len=2, size=8)[0]
    assert torch.equal(small["semantic"][0], torch.from_numpy(truth[0][2][1::2, 1::2]).long())
    np.testing.assert_allclose(small["depth"][1, 0].numpy(), truth[1][1][1::2, 1::2] * (100.0 / 255.0), rtol=1e-6)
    assert small["reset"].tolist() == [True, False]


def test_topair_label_out_of_range(tmp_path):
    write_topair(tmp_path)
    bad = np.zeros((16, 16), np.uint8)
    bad[0, 0] = 9
    write_png_gray(tmp_path / "OakForest_3" / "seg_id" / "000002.png", bad)
    ds = open_dataset("topair", tmp_path, split="test", size=16)
    with pytest.raises(DatasetError, match=r"seg_id/000002\.png: label ID 9 out of range 0\.\.8"):
        ds[2]


def test_topair_reader_writes_nothing(tmp_path):
    write_topair(tmp_path)
    before = snapshot(tmp_path)
    list(open_dataset("topair", tmp_path, split="test", seq_len=1, size=8, augment=True))
    assert snapshot(tmp_path) == before


def test_topair_split_generator_from_airsim_recordings(tmp_path):
    root = tmp_path / "topair"
    write_topair(root, env="RuralAust3_1")
    write_topair(root, env="Africa_2")
    # AirSim recording: body NED, flying north (x) at 2 m per frame, then turning east by 90 degrees
    header = "VehicleName\tTimeStamp\tPOS_X\tPOS_Y\tPOS_Z\tQ_W\tQ_X\tQ_Y\tQ_Z\tImageFile"
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    rec = [header]
    for i in range(N):
        q = (1.0, 0.0, 0.0, 0.0) if i < 4 else (c, 0.0, 0.0, s)
        rec.append(f"Drone1\t{i}\t{2.0 * i}\t0\t-10\t{q[0]}\t{q[1]}\t{q[2]}\t{q[3]}\timg_{i}.png")
    for env in ("RuralAust3_1", "Africa_2"):
        (root / env / "airsim_rec.txt").write_text("\n".join(rec) + "\n")
    out = tmp_path / "out"
    assert main(["splits", "topair", str(root), str(out)]) == 0
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*.csv")) == [
        "test_data/traj_0013.csv",
        "train_data/traj_0001.csv",
    ]
    lines = [ln.split("\t") for ln in (out / "test_data" / "traj_0013.csv").read_text().splitlines()]
    assert lines[0] == HEADER.split("\t")
    # RuralAust3_1 has frame skip 2: rows for images 0 (id -1), 2, 4
    assert [ln[0] for ln in lines[1:]] == ["-1", "0", "1"]
    assert [ln[1] for ln in lines[1:]] == [f"RuralAust3_1/images/{i:06d}.png" for i in (0, 2, 4)]
    assert lines[1][4:] == ["1.000000", "0.000000", "0.000000", "0.000000", "0.000100", "0.000100", "0.000100"]
    # 0 -> 2: 4 m forward (camera z); 2 -> 4: 4 m forward and a 90-degree yaw to the right (about camera y, down)
    assert [float(v) for v in lines[2][4:]] == pytest.approx([1, 0, 0, 0, 0, 0, 4.0], abs=1e-6)
    assert [float(v) for v in lines[3][4:]] == pytest.approx([c, 0, s, 0, 0, 0, 4.0], abs=1e-6)
    # and the reader takes these CSVs as they are
    ds = open_dataset("topair", root, split_dir=out, split="test", size=8)
    assert [bool(it["reset"][0]) for it in ds] == [True, False, False]


def test_airsim_recording_errors(tmp_path):
    p = tmp_path / "airsim_rec.txt"
    p.write_text("POS_X\tPOS_Y\tPOS_Z\tQ_W\tQ_X\tQ_Y\tQ_Z\n0\t0\t0\t0.5\t0\t0\t0\n")
    with pytest.raises(DatasetError, match=r"airsim_rec\.txt:2: quaternion is not unit"):
        read_airsim_rec(p)
    p.write_text("POS_X\tPOS_Y\n0\t0\n")
    with pytest.raises(DatasetError, match="header must contain"):
        read_airsim_rec(p)
