"""scripts/class_weights.py: label counts of a config's training windows and the weights made from them."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
import torch

from cosemdepth.data.toy import ToyDataset
from cosemdepth.measures.losses import median_frequency_weights

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "class_weights.py"


def _script():
    spec = importlib.util.spec_from_file_location("class_weights_script", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_counts_every_supervised_frame_of_the_training_windows(tmp_path, capsys):
    out = tmp_path / "weights.json"
    sets = ["data.train=[{name: toy, options: {length: 5}}]", "data.size=[32, 32]", "train.seed=3"]
    rc = _script().main(
        ["--config", "synthair-demo", *sum((["--set", s] for s in sets), []), "--power", "1", "--out", str(out)]
    )
    assert rc == 0
    report = json.loads(out.read_text())
    # Independently: the same toy windows (the seed of the run), frames 1.. of each, counted by numpy-free torch.
    toy = ToyDataset(length=5, size=(32, 32), seq_len=4, seed=3, num_classes=7, split="train")
    expected = torch.zeros(7, dtype=torch.int64)
    for i in range(len(toy)):
        expected += torch.bincount(torch.as_tensor(toy[i]["semantic"])[1:].flatten().long(), minlength=7)
    assert report["counts"] == expected.tolist()
    assert sum(report["shares"]) == pytest.approx(1.0)
    assert report["semantic_class_weights"] == pytest.approx(median_frequency_weights(expected.tolist(), 1.0), abs=5e-4)
    assert "semantic_class_weights: [" in capsys.readouterr().out


def test_a_model_without_semantics_is_a_one_line_error(tmp_path, capsys):
    rc = _script().main(["--config", "synthair-demo", "--set", "model.arch=m4depth", "--out", str(tmp_path / "w.json")])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no semantic decoder" in err
    assert not (tmp_path / "w.json").exists()
