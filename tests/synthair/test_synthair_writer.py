"""SynthAir writer: the Mid-Air tree, the encodings, the ground truth and the split CSVs on disk."""

from __future__ import annotations

import io
import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from PIL import Image

from cosemdepth.data.midair.splits import read_csv
from cosemdepth.errors import ConfigError
from cosemdepth.synthair.climate import get_climate
from cosemdepth.synthair.render import SKY_DEPTH, render_frame
from cosemdepth.synthair.writer import SynthConfig, encode_jpeg, generate, plan_flights

SIZE, FRAMES = 48, 20  # 20 camera frames -> 4 CSV rows (frames 4, 8, 12, 16)


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def small(tmp_path_factory, world):
    out = tmp_path_factory.mktemp("synthair") / "ds"
    cfg = SynthConfig(out=out, trajectories=1, frames=FRAMES, size=SIZE, seed=0, climates=("sunny", "foggy"))
    summary = generate(cfg, progress=False)
    return cfg, summary


def test_layout_is_the_mid_air_tree(small):
    cfg, summary = small
    root = Path(cfg.out)
    assert summary["frames_rendered"] == summary["frames_total"] == 2 * 4
    for climate, number in (("sunny", 0), ("foggy", 2000)):
        base = root / "SynthAir" / climate
        for folder, ext in (("color_left", "JPEG"), ("stereo_disparity", "PNG"), ("segmentation", "PNG")):
            names = sorted(p.name for p in (base / folder / f"trajectory_{number:04d}").iterdir())
            assert names == [f"{k:06d}.{ext}" for k in (4, 8, 12, 16)]
        assert (base / "sensor_records.hdf5").is_file()
    assert not (root / "SynthAir" / "cloudy").exists()
    meta = json.loads((root / "synthair.json").read_text())
    assert meta["seed"] == 0 and meta["size"] == SIZE and meta["frames"] == FRAMES and meta["complete"] is True
    assert meta["version"] and meta["climates"] == ["sunny", "foggy"] and meta["splits"] == "splits"
    # no temporary files left behind; the split folder carries the output marker listing the CSVs it wrote
    assert not [p for p in root.rglob("*") if p.name.startswith(".") and p.name != ".cosemdepth-output.json"]
    marker = json.loads((root / "splits" / ".cosemdepth-output.json").read_text())
    assert marker["command"] == "splits" and sorted(marker["files"]) == sorted(
        p.relative_to(root / "splits").as_posix() for p in (root / "splits").rglob("*.csv")
    )


def test_a_generated_dataset_is_an_input_of_other_commands(small):
    from cosemdepth.output_safety.input_kinds import identify

    cfg, _ = small
    root = Path(cfg.out)
    assert identify(root) is not None and identify(root)[0].name == "a SynthAir dataset"
    assert identify(root)[0].writers == ("synth",)  # resumed by synth, never another command's output
    assert identify(root / "splits")[0].name == "a split folder"
    assert identify(root / "SynthAir" / "sunny")[0].name == "part of a Mid-Air-format dataset"


def test_sensor_records_hold_100hz_ground_truth_and_camera_lists(small):
    cfg, _ = small
    base = Path(cfg.out) / "SynthAir" / "sunny"
    with h5py.File(base / "sensor_records.hdf5", "r") as h5:
        assert list(h5.keys()) == ["trajectory_0000"]
        gt = h5["trajectory_0000/groundtruth"]
        att, pos = gt["attitude"][()], gt["position"][()]
        assert att.shape == (4 * FRAMES, 4) and pos.shape == (4 * FRAMES, 3)
        np.testing.assert_allclose(np.linalg.norm(att, axis=1), 1.0, atol=1e-9)
        # 100 Hz: consecutive positions are 1/100 s apart at drone speeds (a few m/s), velocity consistent
        vel = gt["velocity"][()]
        speed = np.linalg.norm(np.diff(pos, axis=0), axis=1) * 100
        assert 2.0 < speed.mean() < 20.0
        np.testing.assert_allclose(vel[1:-1], (pos[2:] - pos[:-2]) * 50, atol=1e-6)
        for folder in ("color_left", "stereo_disparity", "segmentation"):
            listed = [v.decode() for v in h5[f"trajectory_0000/camera_data/{folder}"][()]]
            assert len(listed) == 4
            for rel in listed:
                assert rel.startswith(f"{folder}/trajectory_0000/") and (base / rel).is_file()


def _hamilton(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def _rot(q):
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_split_csv_motions_match_the_hdf5_ground_truth(small):
    """Recompute every CSV row from the 100 Hz ground truth by hand (design 10.3) and check the design 2.2 convention
    X_prev = R X_curr + t on a world point seen by both cameras."""
    cfg, _ = small
    root = Path(cfg.out)
    csvs = sorted((root / "splits").rglob("*.csv"))
    assert len(csvs) == 2  # one trajectory per climate, index 0 -> test
    assert all(p.parent.parent.parent.name == "test_data" for p in csvs)
    rows = read_csv(root / "splits" / "test_data" / "SynthAir" / "sunny" / "traj_0000.csv")
    with h5py.File(root / "SynthAir" / "sunny" / "sensor_records.hdf5", "r") as h5:
        att = h5["trajectory_0000/groundtruth/attitude"][()]
        pos = h5["trajectory_0000/groundtruth/position"][()]
    assert [r["id"] for r in rows] == [0, 1, 2, 3]
    cam_from_body = np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]])  # camera x = body y, y = body z, z = body x
    point = pos[40] + np.array([30.0, 5.0, 10.0])  # a world point ahead of and below the cameras
    for k, r in enumerate(rows):
        assert r["camera_l"] == f"SynthAir/sunny/color_left/trajectory_0000/{4 * (k + 1):06d}.JPEG"
        assert r["disp"] == f"SynthAir/sunny/stereo_disparity/trajectory_0000/{4 * (k + 1):06d}.PNG"
        assert r["semantic"] == f"SynthAir/sunny/segmentation/trajectory_0000/{4 * (k + 1):06d}.PNG"
        a, b = 16 * k, 16 * k + 16
        qa_inv = att[a] * np.array([1, -1, -1, -1])
        q_body = _hamilton(qa_inv, att[b])
        t_body = _rot(att[a]).T @ (pos[b] - pos[a])
        np.testing.assert_allclose([r["qw"], r["qx"], r["qy"], r["qz"]], q_body[[0, 2, 3, 1]], atol=2e-6)
        np.testing.assert_allclose([r["tx"], r["ty"], r["tz"]], t_body[[1, 2, 0]], atol=2e-6)
        x_prev = cam_from_body @ (_rot(att[a]).T @ (point - pos[a]))
        x_curr = cam_from_body @ (_rot(att[b]).T @ (point - pos[b]))
        r_csv = _rot(np.array([r["qw"], r["qx"], r["qy"], r["qz"]]))
        np.testing.assert_allclose(r_csv @ x_curr + np.array([r["tx"], r["ty"], r["tz"]]), x_prev, atol=1e-4)
        assert r["tz"] > 0.1  # forward flight


def test_files_decode_to_what_the_renderer_produced(small, world):
    """Disparity PNG (float16 bits of 512/depth, Mid-Air's convention at any size) -> depth, segmentation PNG ->
    labels, JPEG -> colours."""
    cfg, _ = small
    root = Path(cfg.out)
    flights = plan_flights(cfg, world)
    for climate, number in (("sunny", 0), ("foggy", 2000)):
        planned = flights[climate][number]
        for k in (4, 12):
            j = 4 * k
            frame = render_frame(
                world,
                get_climate(climate).with_sun_azimuth(planned.sun_azimuth),
                planned.flight.attitude[j],
                planned.flight.position[j],
                SIZE,
                SIZE,
            )
            base = root / "SynthAir" / climate
            disp_img = Image.open(base / f"stereo_disparity/trajectory_{number:04d}/{k:06d}.PNG")
            assert disp_img.mode == "I;16"
            raw = np.asarray(disp_img).astype(np.uint16)
            disparity = raw.view(np.float16).astype(np.float64)
            assert (disparity > 0).all() and np.isfinite(disparity).all()
            depth = 512.0 / disparity  # not (SIZE / 2) / disparity: the old, wrong convention
            np.testing.assert_allclose(depth, frame.depth, rtol=1e-3)
            sky = frame.labels == 0
            np.testing.assert_allclose(depth[sky], SKY_DEPTH, rtol=1e-3)
            seg_img = Image.open(base / f"segmentation/trajectory_{number:04d}/{k:06d}.PNG")
            assert seg_img.mode == "L"
            assert np.array_equal(np.asarray(seg_img), frame.labels)
            jpg = Image.open(base / f"color_left/trajectory_{number:04d}/{k:06d}.JPEG")
            assert jpg.format == "JPEG" and jpg.mode == "RGB" and jpg.size == (SIZE, SIZE)
            assert np.abs(np.asarray(jpg).astype(int) - frame.rgb.astype(int)).mean() < 4.0  # JPEG q95 loss
            same = Image.open(io.BytesIO(encode_jpeg(frame.rgb, cfg.jpeg_quality)))
            assert np.array_equal(np.asarray(jpg), np.asarray(same))


def test_generation_is_deterministic_and_resumable(small, tmp_path):
    cfg, _ = small
    first = _files(Path(cfg.out))
    again = SynthConfig(
        out=tmp_path / "again", trajectories=1, frames=FRAMES, size=SIZE, seed=0, climates=("sunny", "foggy"), workers=2
    )
    generate(again, progress=False)
    assert _files(tmp_path / "again") == first
    # resume: an interrupted run (a frame missing) is completed with the same bytes
    victim = tmp_path / "again" / "SynthAir" / "foggy" / "segmentation" / "trajectory_2000" / "000008.PNG"
    victim.unlink()
    summary = generate(again, progress=False)
    assert summary["resumed"] and summary["frames_rendered"] == 1
    assert _files(tmp_path / "again") == first


def test_all_frames_option_renders_every_25hz_frame(world, tmp_path):
    cfg = SynthConfig(
        out=tmp_path / "all", trajectories=1, frames=10, size=16, seed=0, climates=("cloudy",), all_frames=True
    )
    generate(cfg, progress=False)
    names = sorted(p.name for p in (tmp_path / "all/SynthAir/cloudy/color_left/trajectory_3000").iterdir())
    assert names == [f"{k:06d}.JPEG" for k in range(10)]
    rows = read_csv(tmp_path / "all/splits/test_data/SynthAir/cloudy/traj_0000.csv")
    assert [r["camera_l"][-11:] for r in rows] == ["000004.JPEG"]


def test_trajectories_are_split_like_mid_air(world, tmp_path):
    """Index % 3 == 0 -> test, the rest train; with two test trajectories the last one goes to validation."""
    cfg = SynthConfig(out=tmp_path / "s", trajectories=4, frames=8, size=16, seed=0, climates=("sunset",))
    generate(cfg, progress=False)
    found = {
        p.parent.parent.parent.name: sorted(q.name for q in p.parent.iterdir())
        for p in (tmp_path / "s/splits").rglob("*.csv")
    }
    assert found == {
        "test_data": ["traj_0000.csv"],
        "val_data": ["traj_0003.csv"],
        "train_data": ["traj_0001.csv", "traj_0002.csv"],
    }
    trajs = sorted(p.name for p in (tmp_path / "s/SynthAir/sunset/color_left").iterdir())
    assert trajs == ["trajectory_1000", "trajectory_1001", "trajectory_1002", "trajectory_1003"]


def test_output_folder_checks(world, tmp_path, small):
    cfg, _ = small
    a_file = tmp_path / "file"
    a_file.write_text("x")
    with pytest.raises(ConfigError, match="not a folder"):
        generate(SynthConfig(out=a_file, frames=8, size=16), progress=False)
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(ConfigError, match="not empty"):
        generate(SynthConfig(out=other, frames=8, size=16), progress=False)
    assert sorted(p.name for p in other.iterdir()) == ["notes.txt"]
    with pytest.raises(ConfigError, match="another SynthAir dataset.*size"):
        generate(
            SynthConfig(out=cfg.out, trajectories=1, frames=FRAMES, size=SIZE * 2, seed=0, climates=("sunny", "foggy")),
            progress=False,
        )


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"size": 8}, "--size"),
        ({"size": 100000}, "--size"),
        ({"frames": 7}, "--frames"),
        ({"trajectories": 0}, "--trajectories"),
        ({"trajectories": 1001}, "--trajectories"),
        ({"seed": -1}, "--seed"),
        ({"climates": ("rainy",)}, "rainy"),
        ({"climates": ("sunny", "sunny")}, "twice"),
        ({"climates": ()}, "--climates"),
        ({"supersample": 2}, "--supersample"),
        ({"workers": 0}, "--workers"),
    ],
)
def test_bad_arguments_are_refused_before_anything_is_written(tmp_path, kwargs, match):
    out = tmp_path / "never"
    with pytest.raises(ConfigError, match=match):
        generate(SynthConfig(out=out, **{"frames": 8, "size": 16, **kwargs}), progress=False)
    assert not out.exists()


def test_a_128px_set_read_by_an_independent_mid_air_reader_gives_the_rendered_depth(world, tmp_path):
    """Mid-Air's convention, as every Mid-Air tool reads it (design 10.2): depth = 512 / disparity whatever the PNG's
    size. A minimal reader written here (PNG -> uint16 -> float16 bits -> 512 / disparity) must give the renderer's
    depth from a 128 px set; the old writer stored (S/2)/z, which this reader would read 8x too far."""
    cfg = SynthConfig(out=tmp_path / "s128", trajectories=1, frames=8, size=128, seed=0, climates=("sunny",))
    generate(cfg, progress=False)
    planned = plan_flights(cfg, world)["sunny"][0]
    for k in (4,):  # camera frame 4 (ground-truth sample 16): the first CSV row
        frame = render_frame(
            world,
            get_climate("sunny").with_sun_azimuth(planned.sun_azimuth),
            planned.flight.attitude[4 * k],
            planned.flight.position[4 * k],
            128,
            128,
        )
        with Image.open(tmp_path / f"s128/SynthAir/sunny/stereo_disparity/trajectory_0000/{k:06d}.PNG") as im:
            raw = np.array(im, dtype=np.uint16)
        depth = 512.0 / raw.view(np.float16).astype(np.float64)
        # float16 keeps 11 significant bits: a relative rounding of at most 2^-11 on the disparity
        np.testing.assert_allclose(depth, frame.depth, rtol=2.0**-11 * 1.01)
        assert abs(np.median(depth / frame.depth) - 1.0) < 1e-4
