"""``cosemdepth fast-accuracy``: the reference row is what ``evaluate --reference`` measures, fp32 passes, a mode
outside the tolerances exits 1, the report has the benchmark shape, a file it did not write is never replaced."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
from _outputs import (  # noqa: E402, F401 (pytest fixtures)
    SIZE,  # noqa: E402
    _one_thread,
    data,
    model_dir,
)

import cosemdepth.bench.accuracy as accuracy  # noqa: E402
from cosemdepth.bench.harness import validate  # noqa: E402
from cosemdepth.cli.main import main  # noqa: E402

DATA = ["--dataset", "midair", "--size", str(SIZE), "--threads", "1"]


def fast_accuracy(model, root, out, *extra):
    return main(
        [
            "fast-accuracy",
            "--model",
            str(model),
            "--root",
            str(root),
            "--split-dir",
            str(Path(root) / "splits"),
            *DATA,
            "--out",
            str(out),
            *map(str, extra),
        ]
    )


@pytest.fixture(scope="module")
def reference_metrics(model_dir, data, tmp_path_factory):
    out = tmp_path_factory.mktemp("eval") / "ev"
    assert (
        main(
            [
                "evaluate",
                "--model",
                str(model_dir),
                "--root",
                str(data),
                "--split-dir",
                str(data / "splits"),
                *DATA,
                "--reference",
                "--no-progress",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    return json.loads((out / "metrics.json").read_text())["metrics"]


def test_report_reference_row_and_fp32_verdict(model_dir, data, tmp_path, reference_metrics, capsys):
    out = tmp_path / "fa.json"
    assert fast_accuracy(model_dir, data, out, "--modes", "fast-fp32") == 0
    assert "every mode within the tolerances" in capsys.readouterr().out
    rep = json.loads(out.read_text())
    assert validate(rep) == [] and rep["tool"] == "cosemdepth fast-accuracy"
    assert rep["params"]["size"] == [SIZE, SIZE] and rep["params"]["modes"] == ["fast-fp32"]
    assert rep["params"]["int8_calibration"] is None
    ref = rep["results"]["metrics"]["reference"]
    # the same protocol as evaluate: the reference path gives evaluate's figures
    for key in ("abs_rel", "rmse", "delta1", "miou"):
        assert ref[key] == pytest.approx(reference_metrics[key], rel=1e-9), key
    v = rep["results"]["verdicts"]["fast-fp32"]
    assert v["ok"] and abs(v["miou_diff_points"]) < 1e-6 and abs(v["abs_rel_rel_diff"]) < 1e-5
    # rerunning replaces the report it wrote
    assert fast_accuracy(model_dir, data, out, "--modes", "fast-fp32", "--max-frames", 3) == 0
    assert json.loads(out.read_text())["params"]["max_frames"] == 3


def test_a_mode_outside_the_tolerances_exits_1(model_dir, data, tmp_path, monkeypatch):
    monkeypatch.setattr(accuracy, "ABSREL_TOL_REL", -1.0)  # no difference is within a negative tolerance
    out = tmp_path / "fa.json"
    assert fast_accuracy(model_dir, data, out, "--modes", "fast-fp32", "--max-frames", 3) == 1
    assert json.loads(out.read_text())["results"]["verdicts"]["fast-fp32"]["abs_rel_ok"] is False


def test_int8_records_its_calibration(model_dir, data, tmp_path):
    out = tmp_path / "fa.json"
    fast_accuracy(model_dir, data, out, "--modes", "fast-int8", "--max-frames", 3, "--calibration-frames", 2)
    rep = json.loads(out.read_text())
    assert rep["params"]["int8_calibration"] == {"root": str(data), "frames": 2, "same_as_evaluated": True}
    assert set(rep["results"]["metrics"]) == {"reference", "fast-int8"}


def test_a_file_it_did_not_write_is_kept(model_dir, data, tmp_path, capsys):
    out = tmp_path / "notes.json"
    out.write_text('{"mine": true}')
    assert fast_accuracy(model_dir, data, out) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(out) in err[0] and "not written by cosemdepth" in err[0]
    assert out.read_text() == '{"mine": true}'


def test_verdicts_by_hand():
    ref = {"miou": 0.40, "abs_rel": 0.2000}
    assert accuracy.verdict({"miou": 0.404, "abs_rel": 0.2019}, ref) == pytest.approx(
        {"miou_diff_points": 0.4, "miou_ok": True, "abs_rel_rel_diff": 0.0095, "abs_rel_ok": True, "ok": True}
    )
    v = accuracy.verdict({"miou": 0.406, "abs_rel": 0.1979}, ref)
    assert v["miou_diff_points"] == pytest.approx(0.6) and not v["miou_ok"]
    assert v["abs_rel_rel_diff"] == pytest.approx(-0.0105) and not v["abs_rel_ok"] and not v["ok"]
    assert accuracy.verdict({"abs_rel": 0.2}, {"abs_rel": 0.2}) == {
        "abs_rel_rel_diff": 0.0,
        "abs_rel_ok": True,
        "ok": True,
    }


def test_a_report_changed_since_is_kept(model_dir, data, tmp_path, capsys):
    out = tmp_path / "fa.json"
    assert fast_accuracy(model_dir, data, out, "--modes", "fast-fp32", "--max-frames", 2) == 0
    edited = out.read_text().replace('"schema": 1', '"schema": 1, "note": "mine"')
    out.write_text(edited)
    assert fast_accuracy(model_dir, data, out, "--modes", "fast-fp32", "--max-frames", 2) == 2
    assert str(out) in capsys.readouterr().err and out.read_text() == edited


def test_onnx_modes_run_the_exported_graphs(model_dir, data, tmp_path):
    """onnx-fp32 is the reference up to float rounding; onnx-int8 leaves the depth decoder float (its depth metrics
    are onnx-fp32's) and records its calibration."""
    out = tmp_path / "fa.json"
    extra = ("--modes", "onnx-fp32", "onnx-int8", "--max-frames", 4, "--calibration-frames", 3)
    assert fast_accuracy(model_dir, data, out, *extra) in (0, 1)
    rep = json.loads(out.read_text())
    assert validate(rep) == [] and set(rep["results"]["metrics"]) == {"reference", "onnx-fp32", "onnx-int8"}
    assert rep["params"]["int8_calibration"]["frames"] == 3
    m, v = rep["results"]["metrics"], rep["results"]["verdicts"]
    assert v["onnx-fp32"]["ok"] and abs(v["onnx-fp32"]["abs_rel_rel_diff"]) < 1e-4
    for key in ("abs_rel", "rmse", "delta1"):
        assert m["onnx-int8"][key] == pytest.approx(m["onnx-fp32"][key], rel=1e-9), key
