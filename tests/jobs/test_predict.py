"""``cosemdepth predict``: every artefact is written and reads back; own flights; bad inputs leave nothing behind."""

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))  # the commands' test helpers
from _outputs import SIZE, _one_thread, data, leftovers, model_dir, unwritable_folder  # noqa: F401 (pytest fixtures)
from PIL import Image

from cosemdepth.cli.main import main
from cosemdepth.data import open_dataset
from cosemdepth.data.midair.format import PALETTE_7
from cosemdepth.render.visualize import (
    VideoWriter,
    depth_to_png16,
    png16_to_depth,
    rgb_to_uint8,
)


def predict(*argv):
    return main(["predict", *map(str, argv), "--no-progress"])


def split_args(data):
    return ["--dataset", "midair", "--root", data, "--split-dir", data / "splits", "--size", SIZE]


def read_png(path):
    return np.array(Image.open(path))


def test_depth_png_encoding_by_hand():
    d = np.array([0.0, 0.001, 1 / 256, 10.5, 255.99, 300.0, -3.0, np.nan], dtype=np.float32)
    png = depth_to_png16(d)
    assert png.dtype == np.uint16
    assert png.tolist() == [0, 0, 1, 2688, 65533, 65535, 0, 0]
    np.testing.assert_allclose(png16_to_depth(png)[:5], [0, 0, 1 / 256, 10.5, 65533 / 256])


def test_predict_writes_every_artefact_and_they_read_back(model_dir, data, tmp_path):
    out = tmp_path / "pred"
    assert predict("--model", model_dir, *split_args(data), "--out", out, "--reference") == 0
    man = json.loads((out / "predictions.json").read_text())
    assert man["frames_written"] == 6 and man["encodings"]["depth_png_scale"] == 256
    run = man["run"]  # Mid-Air's 90-degree pinhole at the 32x32 input: f = c = 16; no pose settings of our own
    assert run["input_size"] == [SIZE, SIZE] and run["intrinsics"] == [16.0, 16.0, 16.0, 16.0]
    assert (run["path"], run["precision"], run["convention"], run["frame_skip"], run["poses"]) == (
        "reference",
        "fp32",
        None,
        None,
        None,
    )
    assert [t["name"] for t in man["trajectories"]] == [
        "Kite_training/sunny/traj_0000",
        "Kite_training/sunny/traj_0001",
    ]
    assert man["palette"] == PALETTE_7.tolist()
    assert leftovers(tmp_path) == []

    from cosemdepth import load_model

    model = load_model(model_dir, mode="reference")  # predict ran --reference
    ds = open_dataset("midair", data, split_dir=data / "splits", seq_len=1, size=SIZE)
    items = [ds[i] for i in range(len(ds))]
    for t, traj in enumerate(man["trajectories"]):
        frames = [f for f in man["frames"] if f["trajectory"] == traj["name"]]
        assert [f["frame"] for f in frames] == [0, 1, 2] and [f["reset"] for f in frames] == [True, False, False]
        # split datasets: the output stem is the colour image's (Mid-Air row 0 is camera frame 000004)
        assert [Path(f["files"]["depth"]).stem for f in frames] == [Path(f["source"]).stem for f in frames]
        assert [Path(f["source"]).name for f in frames] == ["000004.JPEG", "000008.JPEG", "000012.JPEG"]
        its = items[3 * t : 3 * t + 3]
        # an independent path: the whole-sequence API
        ref = model.infer(
            torch.cat([it["rgb"] for it in its]),
            (torch.cat([it["rot"] for it in its]), torch.cat([it["trans"] for it in its])),
            its[0]["intrinsics"],
        )
        for k, f in enumerate(frames):
            files = {key: out / rel for key, rel in f["files"].items()}
            depth = np.load(files["depth"])
            assert depth.dtype == np.float32 and depth.shape == (SIZE, SIZE)
            np.testing.assert_allclose(depth, ref.depth[k, 0].numpy(), rtol=1e-5, atol=1e-5)
            png = read_png(files["depth_png"])
            assert png.dtype == np.uint16
            # png / 256 is the depth to 1/512 m, saturated to [1 / 256, 65535 / 256], where the mask says the
            # depth is an estimate; 0 elsewhere (the reset frame: everywhere)
            valid = read_png(files["depth_valid"]) == 255
            assert (png[~valid] == 0).all() and (k > 0 or not valid.any())
            assert np.abs(png / 256.0 - np.clip(depth, 1 / 256, 65535 / 256))[valid].max(initial=0) <= 1 / 512 + 1e-6
            assert f["status"] == ("reset" if k == 0 else "estimated")
            assert abs(f["valid_fraction"] - valid.mean()) <= 1e-6
            labels = read_png(files["labels"])
            assert labels.dtype == np.uint8 and np.array_equal(labels, ref.semantic[k].argmax(0).numpy())
            assert np.array_equal(read_png(files["labels_color"]), PALETTE_7[labels])
            sbs = read_png(files["side_by_side"])
            # 5 panels of 384 px (SIZE = 32 upscaled 12 x), 4 px gaps, captions above, colour bar and legend below
            pics = traj["pictures"]
            assert pics["panels"] == [
                "RGB",
                "predicted depth",
                "ground-truth depth",
                "predicted labels",
                "ground-truth labels",
            ]
            assert pics["panel_size"] == [384, 384] and 384 == 12 * SIZE
            assert sbs.shape == (*pics["frame_size"], 3) and sbs.shape[1] == 5 * 384 + 4 * 4
            assert sbs.shape[0] > 384 + 40
            boxes = dict(zip(pics["panels"], pics["panel_boxes"]))
            x0, y0, x1, y1 = boxes["predicted labels"]
            assert (x1 - x0, y1 - y0) == (384, 384)
            # labels: each pixel a 12 x 12 block of its class colour (nearest upscaling)
            assert np.array_equal(sbs[y0:y1, x0:x1], np.kron(PALETTE_7[labels], np.ones((12, 12, 1), np.uint8)))
            x0, y0, x1, y1 = boxes["RGB"]
            rgb = rgb_to_uint8(its[k]["rgb"][0].numpy()).astype(int)
            # bilinear: the centre of each 12 x 12 block lies between its pixel and a neighbour (title box excluded)
            centre = sbs[y0 + 6 : y1 : 12, x0 + 6 : x1 : 12].astype(int)
            lo = np.minimum(rgb, np.minimum(np.roll(rgb, -1, 0), np.roll(rgb, -1, 1)))
            hi = np.maximum(rgb, np.maximum(np.roll(rgb, -1, 0), np.roll(rgb, -1, 1)))
            body = (slice(4, SIZE - 1), slice(0, SIZE - 1))
            assert ((centre[body] >= lo[body] - 1) & (centre[body] <= hi[body] + 1)).all()
        video = out / traj["video"]
        import imageio_ffmpeg

        assert video.suffix == ".mp4" and imageio_ffmpeg.count_frames_and_secs(str(video))[0] == 3


def test_rerun_replaces_the_previous_output(model_dir, data, tmp_path):
    out = tmp_path / "pred"
    assert predict("--model", model_dir, *split_args(data), "--out", out, "--video", "none") == 0
    assert predict("--model", model_dir, *split_args(data), "--out", out, "--max-frames", 2, "--video", "none") == 0
    man = json.loads((out / "predictions.json").read_text())
    assert man["frames_written"] == 2
    assert len(list(out.rglob("*.npy"))) == 2 and not list(out.rglob("*.mp4"))
    assert leftovers(tmp_path) == []


def test_own_flight_with_a_gif(model_dir, tmp_path):
    images = tmp_path / "flight" / "images"
    images.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for k in range(4):
        Image.fromarray(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)).save(images / f"img_{k:04d}.png")
    poses = tmp_path / "flight" / "poses.txt"
    poses.write_text("".join(f"{k * 0.1:.3f} 0 0 {k * 0.5} 0 0 0 1\n" for k in range(4)))  # TUM, forward 0.5 m
    out = tmp_path / "out"
    rc = predict(
        "--model",
        model_dir,
        "--flight",
        "--images",
        images,
        "--poses",
        poses,
        "--hfov",
        90,
        "--size",
        "32x64",
        "--out",
        out,
        "--video",
        "gif",
    )
    assert rc == 0
    man = json.loads((out / "predictions.json").read_text())
    # the settings behind the outputs: hfov 90 on the 48x64 images gives fx = fy = 64 / 2 = 32, cx = 32, cy = 24,
    # scaled to the 32x64 model input (rows x 2/3)
    run = man["run"]
    assert run["input_size"] == [32, 64] and run["hfov_deg"] == 90 and run["intrinsics_given"] is None
    np.testing.assert_allclose(run["intrinsics"], [32, 32 * 2 / 3, 32, 16], rtol=1e-6)
    assert (run["path"], run["precision"], run["convention"], run["frame_skip"]) == ("fast", "fp32", "opencv", 1)
    assert run["poses"] == str(poses) and run["model"] == str(model_dir) and run["jpeg_idct"] == "fast"
    assert man["frames_written"] == 4 and len(man["trajectories"]) == 1
    traj = man["trajectories"][0]
    assert traj["name"] == "images" and traj["video"] == "images/video.gif"
    gif = Image.open(out / traj["video"])
    assert gif.n_frames == 4
    sbs = read_png(out / man["frames"][1]["files"]["side_by_side"])
    # RGB | depth | labels: no ground truth; 32 x 64 upscaled 12 x to 384 x 768 panels
    pics = traj["pictures"]
    assert pics["panels"] == ["RGB", "predicted depth", "predicted labels"] and pics["panel_size"] == [384, 768]
    assert sbs.shape == (*pics["frame_size"], 3) and sbs.shape[1] == 3 * 768 + 2 * 4
    assert gif.size == (sbs.shape[1], sbs.shape[0])
    assert man["frames"][0]["source"].endswith("img_0000.png")
    # outputs keep the input image's name (they were renumbered 000000, 000001, ...)
    assert sorted(p.name for p in (out / "images" / "depth").iterdir()) == [f"img_{k:04d}.npy" for k in range(4)]
    assert sorted(p.name for p in (out / "images" / "labels").iterdir()) == [f"img_{k:04d}.png" for k in range(4)]
    for f in man["frames"]:
        assert Path(f["files"]["side_by_side"]).stem == Path(f["source"]).stem


def test_gif_writer_alone(tmp_path):
    w = VideoWriter(tmp_path / "v", fps=5, fmt="gif")
    for k in range(3):
        w.write(np.full((10, 12, 3), 80 * k, np.uint8))
    path = w.close()
    assert path == tmp_path / "v.gif" and Image.open(path).n_frames == 3
    assert leftovers(tmp_path) == []
    w = VideoWriter(tmp_path / "w", fmt="mp4")
    w.write(np.zeros((9, 11, 3), np.uint8))  # odd sizes are padded for H.264
    w.abort()
    assert list(tmp_path.iterdir()) == [tmp_path / "v.gif"]


# ----------------------------------------------------------------------------------------------- bad inputs


def test_output_folder_that_is_a_file(model_dir, data, tmp_path, capsys):
    f = tmp_path / "out"
    f.write_text("mine")
    assert predict("--model", model_dir, *split_args(data), "--out", f) == 2
    assert "exists and is not a folder" in capsys.readouterr().err
    assert f.read_text() == "mine" and leftovers(tmp_path) == []


def test_output_folder_with_other_files(model_dir, data, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    assert predict("--model", model_dir, *split_args(data), "--out", out) == 2
    assert "not empty" in capsys.readouterr().err
    assert [p.name for p in out.iterdir()] == ["keep.txt"]


def test_unwritable_folder(model_dir, data, tmp_path, capsys):
    with unwritable_folder(tmp_path / "ro") as ro:
        assert predict("--model", model_dir, *split_args(data), "--out", ro / "out") == 2
        assert "cannot write" in capsys.readouterr().err
        assert list(ro.iterdir()) == []


def test_missing_model_and_missing_dataset(model_dir, data, tmp_path, capsys):
    out = tmp_path / "out"
    assert predict("--model", tmp_path / "nope", *split_args(data), "--out", out) == 2
    assert "model folder not found" in capsys.readouterr().err
    assert (
        predict(
            "--model",
            model_dir,
            "--dataset",
            "midair",
            "--root",
            tmp_path / "nodata",
            "--split-dir",
            tmp_path / "nodata" / "splits",
            "--out",
            out,
        )
        == 2
    )
    assert "not found" in capsys.readouterr().err
    assert predict("--model", model_dir, "--flight", "--images", tmp_path, "--out", out) == 2
    assert "--poses" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_corrupt_frame_mid_run_leaves_nothing(model_dir, data, tmp_path, capsys):
    bad = tmp_path / "bad"
    shutil.copytree(data, bad)
    jpeg = bad / "Kite_training/sunny/color_left/trajectory_0001/000008.JPEG"  # row 1 of the second trajectory
    jpeg.write_bytes(jpeg.read_bytes()[:40])
    out = tmp_path / "deep" / "out"
    assert (
        predict(
            "--model",
            model_dir,
            "--dataset",
            "midair",
            "--root",
            bad,
            "--split-dir",
            bad / "splits",
            "--size",
            SIZE,
            "--out",
            out,
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "000008.JPEG" in err
    assert not (tmp_path / "deep").exists()  # nor the parent folder it created
    assert leftovers(tmp_path) == []


def test_two_trajectories_per_batch_give_the_same_files(model_dir, data, tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    assert predict("--model", model_dir, *split_args(data), "--out", one, "--video", "none") == 0
    assert (
        predict("--model", model_dir, *split_args(data), "--out", two, "--video", "mp4", "--trajectories-per-batch", 2)
        == 0
    )
    a = json.loads((one / "predictions.json").read_text())
    b = json.loads((two / "predictions.json").read_text())
    key = lambda f: (f["trajectory"], f["frame"])  # noqa: E731
    assert sorted(map(key, a["frames"])) == sorted(map(key, b["frames"]))
    for f in b["frames"]:
        np.testing.assert_allclose(
            np.load(two / f["files"]["depth"]), np.load(one / f["files"]["depth"]), rtol=1e-4, atol=1e-4
        )
    import imageio_ffmpeg

    assert [imageio_ffmpeg.count_frames_and_secs(str(two / t["video"]))[0] for t in b["trajectories"]] == [3, 3]
