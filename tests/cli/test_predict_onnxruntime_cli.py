"""``predict --backend onnxruntime``: the exported graph streamed through the same command gives the PyTorch
outputs (statuses, held frames, depth and labels up to float rounding), and its misuse fails in one line, exit 2."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("onnxruntime")  # an optional dependency (cosemdepth[export])

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
from _outputs import _one_thread, model_dir, tiny_model  # noqa: E402, F401 (pytest fixtures)
from test_predict_policy_cli import flight, predict  # noqa: E402

from cosemdepth.cli.main import main  # noqa: E402


@pytest.fixture(scope="module")
def graph(model_dir, tmp_path_factory):
    path = tmp_path_factory.mktemp("g") / "tiny16.onnx"
    assert main(["export", "--onnx", str(path), "--model", str(model_dir), "--size", "16", "16"]) == 0
    return path


def test_the_graph_streams_like_pytorch_held_frames_included(model_dir, graph, tmp_path, capsys):
    images, poses = flight(tmp_path / "f", [0, 0.5, 1.0, 1.0, 1.0, 1.5, 2.0])
    flags = ("--policy", "baseline", "--min-baseline", 0.3, "--size", 16)
    assert predict(model_dir, images, poses, tmp_path / "pt", *flags) == 0
    assert predict(model_dir, images, poses, tmp_path / "ort", *flags, "--backend", "onnxruntime", "--onnx", graph) == 0
    pt, ort = (json.loads((tmp_path / d / "predictions.json").read_text()) for d in ("pt", "ort"))
    assert (
        [f["status"] for f in ort["frames"]]
        == [f["status"] for f in pt["frames"]]
        == ["reset", "estimated", "estimated", "held", "held", "estimated", "estimated"]
    )
    assert ort["run"]["path"] == "onnxruntime" and ort["run"]["onnx"] == str(graph)
    for a, b in zip(pt["frames"], ort["frames"]):
        d0, d1 = (np.load(tmp_path / r / f["files"]["depth"]) for r, f in (("pt", a), ("ort", b)))
        np.testing.assert_allclose(d1, d0, rtol=1e-3, atol=1e-4)
        assert a["valid_fraction"] == pytest.approx(b["valid_fraction"], abs=0.02)


@pytest.mark.parametrize(
    "extra, message",
    [
        ((), "--backend onnxruntime needs --onnx FILE"),
        (("--reference",), "drop --reference / --precision"),
        (("--onnx", "missing.onnx"), "--onnx missing.onnx: no such file"),
    ],
)
def test_misuse_fails_in_one_line(model_dir, tmp_path, capsys, extra, message):
    images, poses = flight(tmp_path / "f", [0, 0.5])
    assert predict(model_dir, images, poses, tmp_path / "out", "--backend", "onnxruntime", *extra) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_a_graph_of_another_size_is_refused_before_any_frame(model_dir, graph, tmp_path, capsys):
    images, poses = flight(tmp_path / "f", [0, 0.5])
    rc = predict(model_dir, images, poses, tmp_path / "out", "--size", 32, "--backend", "onnxruntime", "--onnx", graph)
    assert rc == 2
    assert "the graph takes 16x16 images, the input is read at 32x32" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_onnx_without_the_backend_is_refused(model_dir, graph, tmp_path, capsys):
    images, poses = flight(tmp_path / "f", [0, 0.5])
    assert predict(model_dir, images, poses, tmp_path / "out", "--onnx", graph) == 2
    assert "add --backend onnxruntime" in capsys.readouterr().err


@pytest.mark.parametrize(
    "source, words",
    [
        (("--arch", "m4depth", "--levels", "2"), "architecture m4depth in the graph, cosemdepth in the model"),
        (("--arch", "cosemdepth", "--levels", "3"), "its config differs from the model's: levels 3 in the graph, 2"),
        (("--model", "{other seed}"), "other weights (sha256 "),
    ],
)
def test_a_graph_of_another_model_is_refused_before_any_frame(model_dir, tmp_path, capsys, source, words):
    other = tmp_path / "other.onnx"
    source = [str(tiny_model(tmp_path / "m1", seed=1)) if s == "{other seed}" else s for s in source]
    assert main(["export", "--onnx", str(other), *source, "--size", "16", "16"]) == 0
    capsys.readouterr()
    images, poses = flight(tmp_path / "f", [0, 0.5])
    rc = predict(model_dir, images, poses, tmp_path / "out", "--backend", "onnxruntime", "--onnx", other)
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert err.startswith(f"cosemdepth predict: error: {other}: not an export of --model {model_dir}: ")
    assert words in err
    assert not (tmp_path / "out").exists()


def test_an_int8_graph_is_recorded_as_int8(model_dir, tmp_path):
    q = tmp_path / "q.onnx"
    argv = ["export", "--onnx", str(q), "--model", str(model_dir), "--size", "16", "16", "--int8"]
    assert main([*argv, "--calibration-frames", "2"]) == 0
    images, poses = flight(tmp_path / "f", [0, 0.5, 1.0])
    assert (
        predict(model_dir, images, poses, tmp_path / "out", "--size", 16, "--backend", "onnxruntime", "--onnx", q) == 0
    )
    run = json.loads((tmp_path / "out" / "predictions.json").read_text())["run"]
    assert (run["path"], run["onnx"], run["precision"]) == ("onnxruntime", str(q), "int8")
