"""Rerun recordings (``predict --rerun``, ``cosemdepth view``), read back with rerun's own loader
(``rerun.chunk.RrdReader``): entities, row counts, one depth value, the trajectory, the class table, the metrics."""

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))  # the commands' test helpers
from _outputs import (  # noqa: F401 (pytest fixtures)
    _one_thread,
    data,
    leftovers,  # (puts tests/data on the path)
    model_dir,
)
from test_predict_bag import N, bag_args, image_stamps, make_bag

from cosemdepth.cli.main import main


def read_rrd(path) -> dict[str, list]:
    """entity path -> the record batches of its chunks."""
    from rerun.chunk import RrdReader

    out: dict[str, list] = {}
    for chunk in RrdReader(str(path)).store().stream():
        out.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return out


def rows(batches) -> int:
    return sum(b.num_rows for b in batches)


def column(batches, suffix: str) -> list:
    out = []
    for b in batches:
        names = [n for n in b.schema.names if n.endswith(suffix)]
        out += b.column(names[0]).to_pylist() if names else []
    return out


def test_predict_bag_with_rerun(model_dir, tmp_path):
    bag = make_bag(tmp_path / "in")
    out, rrd = tmp_path / "out", tmp_path / "flight.rrd"
    assert (
        main(
            [
                "predict",
                "--model",
                str(model_dir),
                *map(str, bag_args(bag, "--camera-info-topic", "/cam/info")),
                "--out",
                str(out),
                "--rerun",
                str(rrd),
                "--video",
                "none",
                "--no-progress",
            ]
        )
        == 0
    )
    ent = read_rrd(rrd)
    for e in ("/world/camera", "/world/camera/image/rgb", "/world/camera/image/depth", "/world/camera/image/labels"):
        assert rows(ent[e]) == N, e
    assert rows(ent["/world/camera/image"]) == 1  # the static pinhole
    assert column(ent["/world/camera/image"], "Pinhole:resolution")[0] == [[32, 32]]
    # frame 3's depth equals the .npy predict wrote where its mask is valid, and is 0 (no point) elsewhere
    man = json.loads((out / "predictions.json").read_text())
    want = np.load(out / man["frames"][3]["files"]["depth"])
    valid = np.asarray(__import__("PIL.Image", fromlist=["Image"]).open(out / man["frames"][3]["files"]["depth_valid"]))
    buf = column(ent["/world/camera/image/depth"], "DepthImage:buffer")[3]
    got = np.frombuffer(bytes(buf[0]), dtype=np.float32).reshape(32, 32)
    assert np.array_equal(got, np.where(valid == 255, want, 0.0).astype(np.float32))
    assert column(ent["/world/camera/image/depth"], "DepthImage:meter")[3] == [1.0]
    # the trajectory: the bag's poses (ENU world, FLU body); one strip of N points; timeline 'time' = the stamps
    strip = column(ent["/world/trajectory"], "LineStrips3D:strips")[0][0]
    assert len(strip) == N
    from _bags import trajectory

    p2, _ = trajectory(image_stamps()[2] / 1e9 - 100.0)
    np.testing.assert_allclose(strip[2], p2, atol=1e-5)  # pose interpolated at the image stamp (float32)
    import pyarrow as pa

    times = [t for b in ent["/world/camera"] for t in b.column("time").cast(pa.int64()).to_pylist()]
    assert times == image_stamps()  # within the float64 seconds given to rerun
    ctx = column(ent["/world"], "AnnotationContext:context")[0][0]
    assert len(ctx) == 7 and ctx[0]["class_description"]["info"]["label"] == "sky"
    assert "/metrics/abs_rel" not in ent  # no ground truth in a bag


def test_view_a_dataset_with_metrics(model_dir, data, tmp_path, capsys):
    rrd = tmp_path / "v.rrd"
    argv = [
        "view",
        "--model",
        str(model_dir),
        "--dataset",
        "midair",
        "--root",
        str(data),
        "--split-dir",
        str(data / "splits"),
        "--size",
        "32",
        "--max-frames",
        "4",
        "--rrd",
        str(rrd),
        "--no-progress",
    ]
    assert main(argv) == 0
    assert f"open it with: rerun {rrd}" in capsys.readouterr().out
    ent = read_rrd(rrd)
    assert rows(ent["/world/camera/image/depth"]) == 4
    from cosemdepth.data import open_dataset

    ds = open_dataset("midair", data, split_dir=data / "splits", seq_len=1, size=32)
    resets = [bool(ds[i]["reset"][0]) for i in range(4)]
    assert resets.count(True) == 2  # two trajectories start in the first 4 frames: metrics on the 2 others only
    assert rows(ent["/metrics/abs_rel"]) == 2 and rows(ent["/metrics/miou"]) == 2
    assert len(column(ent["/world/trajectory"], "LineStrips3D:strips")[0]) == 2  # one strip per trajectory
    assert all(0 <= v[0] <= 1 for v in column(ent["/metrics/miou"], "Scalars:scalars"))
    # the chained camera path starts at the origin
    assert column(ent["/world/trajectory"], "LineStrips3D:strips")[0][0][0] == [0.0, 0.0, 0.0]
    # a recording cosemdepth wrote is replaced; a file of the user's with the same name never is (one-line error)
    assert main(argv) == 0
    capsys.readouterr()
    rrd.write_bytes(b"my own notes")
    for extra, message in (
        ([], f"{rrd}: the --rrd recording exists and cannot be replaced: changed since cosemdepth view wrote it"),
        (["--overwrite"], "--overwrite does not apply to view"),
    ):  # view has no --overwrite
        assert main([*argv, *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith(f"cosemdepth view: error: {message}") and "\n" not in err
        assert rrd.read_bytes() == b"my own notes"
    assert not leftovers(tmp_path)


def test_rerun_bad_name_and_failure_leaves_nothing(model_dir, tmp_path, capsys):
    bag = make_bag(tmp_path / "in", gap=(100.095, 100.185))
    rrd = tmp_path / "x.rrd"
    argv = [
        "predict",
        "--model",
        str(model_dir),
        *map(str, bag_args(bag, "--camera-info-topic", "/cam/info")),
        "--out",
        str(tmp_path / "out"),
        "--no-progress",
    ]
    assert main([*argv, "--rerun", str(tmp_path / "x.txt")]) == 2
    assert "a rerun recording's name must end with .rrd" in capsys.readouterr().err
    assert main([*argv, "--rerun", str(rrd)]) == 2  # no poses around two images
    assert "no pose for the image at stamp 100.117000000" in capsys.readouterr().err
    assert not rrd.exists() and not leftovers(tmp_path) and not (tmp_path / "out").exists()
