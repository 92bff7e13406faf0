"""The commands run a model at its own focal length in pixels (its operating point) unless told otherwise, and warn
when told a size far from it."""

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
from _outputs import _one_thread, tiny_midair  # noqa: E402, F401 (pytest fixture)

from cosemdepth import build_model, save_model  # noqa: E402
from cosemdepth.cli._shared import model_size_pair  # noqa: E402
from cosemdepth.cli.main import build_parser, main  # noqa: E402
from cosemdepth.cli.predict import options  # noqa: E402
from cosemdepth.jobs.options import open_source  # noqa: E402
from cosemdepth.operating_point import OperatingPoint  # noqa: E402


def _open(args):
    """The dataset predict reads for these arguments (at the model's focal length unless --size)."""
    o = options(args)
    return open_source(o.source, o.run, o.model.operating_point()).dataset


#: A model trained at 32x32 with a 90-degree camera: 16 px of focal length.
OP = OperatingPoint((32, 32), (16.0, 16.0), None, "test")


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    torch.manual_seed(0)
    return save_model(
        build_model(arch="cosemdepth", levels=2), tmp_path_factory.mktemp("m") / "at32", operating_point=OP
    )


@pytest.fixture(scope="module")
def plain_model(tmp_path_factory):
    torch.manual_seed(0)
    return save_model(build_model(arch="cosemdepth", levels=2), tmp_path_factory.mktemp("m") / "plain")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return tiny_midair(tmp_path_factory.mktemp("d") / "s", size=64)  # a Mid-Air-format split at 64x64 (f = 32 px)


def evaluate(model, data, out, *extra):
    assert (
        main(
            [
                "evaluate",
                "--model",
                str(model),
                "--dataset",
                "synthair",
                "--root",
                str(data),
                "--out",
                str(out),
                "--no-progress",
                "--reference",
                *map(str, extra),
            ]
        )
        == 0
    )
    return json.loads((out / "metrics.json").read_text())


def test_evaluate_without_size_runs_at_the_model_s_focal_length(model, data, tmp_path, capsys):
    default = evaluate(model, data, tmp_path / "default")
    assert "warning" not in capsys.readouterr().err
    at32 = evaluate(model, data, tmp_path / "at32", "--size", 32)
    assert "warning" not in capsys.readouterr().err
    assert default["dataset"]["size"] == at32["dataset"]["size"] == [32, 32]
    assert default["metrics"] == at32["metrics"] and default["metrics"]["depth_frames"] == 4


def test_a_size_far_from_the_model_s_focal_length_gets_a_warning(model, data, tmp_path, capsys):
    evaluate(model, data, tmp_path / "at64", "--size", 64)
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "warning" in ln]
    assert len(lines) == 1
    for part in ("--size 64x64", "32.0 px", "16.0 px (32x32)", "runs at 32x32"):
        assert part in lines[0], part
    evaluate(model, data, tmp_path / "at36", "--size", 36)  # 18 px: within the factor
    assert "warning" not in capsys.readouterr().err


def test_the_warning_of_an_anisotropic_size_names_the_size_the_input_runs_at_without_it(model, data, tmp_path, capsys):
    # a square input at 33x47 (f = 23.5 px): without --size it runs at the model's focal length with its own
    # (square) aspect, 32x32, not the requested aspect scaled to that focal length (22x32)
    evaluate(model, data, tmp_path / "aniso", "--size", "33x47")
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "warning" in ln]
    assert len(lines) == 1 and "--size 33x47 gives a focal length of 23.5 px" in lines[0]
    assert lines[0].endswith("(without --size this input runs at 32x32)")
    # export / benchmark: without --size they run at the model's training size
    h, w = model_size_pair([33, 47], argparse.Namespace(operating_point=OP))
    assert (h, w) == (33, 47)
    assert capsys.readouterr().err.strip().endswith("(without --size this input runs at 32x32)")


def test_predict_on_a_dataset_without_size_gives_the_outputs_of_the_model_s_size(model, data, tmp_path):
    outs = []
    for name, extra in (("default", []), ("at32", ["--size", "32"])):
        out = tmp_path / name
        assert (
            main(
                [
                    "predict",
                    "--model",
                    str(model),
                    "--dataset",
                    "synthair",
                    "--root",
                    str(data),
                    "--out",
                    str(out),
                    "--video",
                    "none",
                    "--no-progress",
                    "--reference",
                    *extra,
                ]
            )
            == 0
        )
        outs.append((out, json.loads((out / "predictions.json").read_text())))
    (a, ma), (b, mb) = outs
    assert len(ma["frames"]) == len(mb["frames"]) == 6
    for fa, fb in zip(ma["frames"], mb["frames"]):
        np.testing.assert_array_equal(np.load(a / fa["files"]["depth"]), np.load(b / fb["files"]["depth"]))


def _flight(tmp_path, h=48, w=64):
    images = tmp_path / "flight" / "images"
    images.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for k in range(3):
        Image.fromarray(rng.integers(0, 255, (h, w, 3), dtype=np.uint8)).save(images / f"img_{k:04d}.png")
    poses = tmp_path / "flight" / "poses.txt"
    poses.write_text("".join(f"{k * 0.1:.3f} 0 0 {k * 0.5} 0 0 0 1\n" for k in range(3)))
    return images, poses


def _args(*argv):
    return build_parser(only="predict").parse_args(["predict", *map(str, argv)])


def test_a_flight_with_hfov_gets_the_model_s_focal_length_at_its_aspect_ratio(model, plain_model, tmp_path):
    images, poses = _flight(tmp_path)
    flight = ["--flight", "--images", images, "--poses", poses, "--hfov", 90, "--out", tmp_path / "o"]
    # 48x64 at 90 degrees: f = 32 px; the model's 16 px is the size 24x32
    ds = _open(_args("--model", model, *flight))
    assert ds.intrinsics.tolist() == [16.0, 16.0, 16.0, 12.0] and ds[0]["rgb"].shape[-2:] == (24, 32)
    # a model without an operating point keeps the flight's own size, and a dataset the table's
    assert _open(_args("--model", plain_model, *flight))[0]["rgb"].shape[-2:] == (48, 64)
    # and the predictions are those of --size 24x32
    outs = []
    for name, extra in (("default", []), ("explicit", ["--size", "24x32"])):
        out = tmp_path / name
        assert (
            main(
                [
                    "predict",
                    "--model",
                    str(model),
                    *map(str, flight[:-1]),
                    str(out),
                    "--video",
                    "none",
                    "--no-progress",
                    "--reference",
                    *extra,
                ]
            )
            == 0
        )
        outs.append((out, json.loads((out / "predictions.json").read_text())))
    (a, ma), (b, mb) = outs
    for fa, fb in zip(ma["frames"], mb["frames"]):
        np.testing.assert_array_equal(np.load(a / fa["files"]["depth"]), np.load(b / fb["files"]["depth"]))


def test_a_model_without_an_operating_point_keeps_the_dataset_table_s_size(plain_model, data, tmp_path):
    ds = _open(_args("--model", plain_model, "--dataset", "synthair", "--root", data, "--out", tmp_path / "o"))
    assert ds.intrinsics.tolist() == [192.0, 192.0, 192.0, 192.0]  # 384x384, as before operating points


def test_export_and_benchmark_default_to_the_model_s_training_size(capsys):
    with_op = argparse.Namespace(operating_point=OperatingPoint((96, 128), (64.0, 64.0)))
    assert model_size_pair(None, with_op) == (96, 128)
    assert model_size_pair(None, argparse.Namespace()) == (384, 384)
    assert model_size_pair([48, 64], with_op) == (48, 64)  # half the focal length: a warning
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "32.0 px" in err and "64.0 px (96x128)" in err
    assert model_size_pair([48, 64], with_op, warn=False) == (48, 64) and not capsys.readouterr().err
