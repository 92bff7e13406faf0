"""A decoder defined outside the package (the folder ``edge_decoder/`` beside this file, loaded as a plugin through
``COSEMDEPTH_PLUGINS``) is trained, evaluated, predicted and exported by the command line with no change to the
package: its loss, metric, ground truth, training picture and output files come from its task."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from PIL import Image

HERE = Path(__file__).resolve().parent
SRC = HERE.parents[1] / "src"
sys.path.insert(0, str(HERE))

import edge_decoder  # noqa: E402  (registers the edge decoder in this process too, for the expectations)

from cosemdepth.data import open_dataset  # noqa: E402
from cosemdepth.plugins import PLUGINS_ENV  # noqa: E402

SIZE = 32


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(SRC), str(HERE)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    env[PLUGINS_ENV] = "edge_decoder"
    env["OMP_NUM_THREADS"] = env["MKL_NUM_THREADS"] = "1"
    return env


def _cli(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "cosemdepth", *args], env=env or _env(), capture_output=True, text=True, timeout=600
    )


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("synth") / "data"
    done = _cli(
        "synth",
        "--out",
        str(root),
        "--trajectories",
        "1",
        "--frames",
        "24",
        "--size",
        str(SIZE),
        "--climates",
        "sunny",
        "--no-progress",
    )
    assert done.returncode == 0, done.stderr
    return root


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("train") / "run"
    sets = {
        "model.arch": edge_decoder.ARCH,
        "model.levels": 3,
        "data.train.0.name": "toy",
        "data.train.0.options": '{"length": 4}',
        "data.size": 16,
        "data.num_workers": 0,
        "train.batch_size": 2,
        "train.epochs": 1,
        "train.num_threads": 1,
        "train.log_every": 1,
        "train.progress": "false",
        "train.image_every": 1,
        "train.validate_every_epochs": 1,
    }
    done = _cli("train", "--out", str(run), *[a for k, v in sets.items() for a in ("--set", f"{k}={v}")])
    assert done.returncode == 0, done.stdout + done.stderr
    return run


def test_training_runs_the_edge_loss_and_validates_the_edge_metric(trained):
    events = [json.loads(line) for line in (trained / "events.jsonl").read_text().splitlines()]
    train = [e for e in events if e["kind"] == "train"]
    assert len(train) == 2 and all(e["good_steps"] == 1 for e in train)
    for e in train:  # the total is the sum of the decoders' losses (weight 1 each)
        assert 0.0 < e["loss_edge"] < 3.0  # a mean absolute error below 1 on each of the 3 levels
        assert e["loss_total"] == pytest.approx(e["loss_depth"] + e["loss_edge"], rel=1e-5)
    validation = [e["metrics"] for e in events if e["kind"] == "validation"]
    assert validation and 0.0 <= validation[-1]["edge_mae"] < 1.0
    assert "abs_rel" in validation[-1]  # the depth decoder is still measured beside it
    config = json.loads((trained / "best" / "config.json").read_text())
    assert json.dumps(config).count(edge_decoder.ARCH) >= 1


def test_evaluate_and_predict_write_the_edge_metric_and_files(trained, flight, tmp_path):
    data = [
        "--dataset",
        "synthair",
        "--root",
        str(flight),
        "--split-dir",
        str(flight / "splits"),
        "--split",
        "test",
        "--size",
        str(SIZE),
    ]
    done = _cli("evaluate", "--model", str(trained / "best"), *data, "--out", str(tmp_path / "eval"))
    assert done.returncode == 0, done.stderr
    metrics = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert metrics["model"]["arch"] == edge_decoder.ARCH

    done = _cli("predict", "--model", str(trained / "best"), *data, "--out", str(tmp_path / "pred"), "--video", "none")
    assert done.returncode == 0, done.stderr
    pred = json.loads((tmp_path / "pred" / "predictions.json").read_text())
    assert "edge" in pred["encodings"]
    frames = pred["frames"]
    assert frames and all("edge" in f["files"] for f in frames)

    # the evaluation's metric, recomputed from the written PNGs and the ground truth derived from the depth: the
    # frames that start a trajectory are left out, and the PNGs round to 1/255
    dataset = open_dataset("synthair", flight, flight / "splits", "test", seq_len=1, size=SIZE)
    assert len(dataset) == len(frames)
    errors = []
    for i, f in enumerate(frames):
        png = np.asarray(Image.open(tmp_path / "pred" / f["files"]["edge"]), dtype=np.float64) / 255.0
        assert png.shape == (SIZE, SIZE)
        if f["reset"]:
            continue
        gt = edge_decoder.edge_strength(torch.as_tensor(dataset[i]["depth"]))[0, 0].double().numpy()
        errors.append(np.abs(png - gt).mean())
    assert metrics["metrics"]["edge_frames"] == len(errors) > 0
    assert abs(metrics["metrics"]["edge_mae"] - float(np.mean(errors))) <= 0.5 / 255 + 1e-6


def test_an_unknown_plugin_is_a_one_line_error(tmp_path):
    env = _env()
    env[PLUGINS_ENV] = "no_such_plugin_module"
    done = _cli("train", "--out", str(tmp_path / "run"), "--print-config", env=env)
    assert done.returncode == 2
    assert PLUGINS_ENV in done.stderr and "no_such_plugin_module" in done.stderr
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()


def test_export_gives_the_edge_decoder_its_onnx_output(trained, tmp_path):
    out = tmp_path / "model.onnx"
    done = _cli("export", "--model", str(trained / "best"), "--onnx", str(out), "--size", "16", "16")
    assert done.returncode == 0, done.stderr
    graph = onnx.load(str(out)).graph
    assert [o.name for o in graph.output][:2] == ["depth", "edge"]
