import json
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import numpy_helper

from cosemdepth.cli.main import main
from cosemdepth.export.onnx import export_onnx


def test_export_command_writes_a_runnable_graph(tmp_path, capsys):
    out = tmp_path / "sem.onnx"
    rc = main(["export", "--onnx", str(out), "--arch", "m4semantic", "--levels", "2", "--size", "16", "24"])
    assert rc == 0 and out.is_file()
    sess = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    assert sess.get_inputs()[0].shape == [1, 3, 16, 24] and sess.get_outputs()[0].shape == [1, 7, 16, 24]
    assert "freshly initialised" in capsys.readouterr().out


def test_export_command_errors_name_the_argument(tmp_path, capsys):
    assert main(["export", "--onnx", str(tmp_path / "a.onnx"), "--size", "4", "4"]) == 2
    assert "--size" in capsys.readouterr().err
    assert main(["export", "--onnx", str(tmp_path / "a.onnx"), "--opset", "12", "--arch", "m4semantic"]) == 2
    err = capsys.readouterr().err  # the reason is the operators the graph uses (GridSample is not one of them)
    assert "--opset must be in [13, " in err and "opset-13 operators" in err and "GridSample" not in err
    from cosemdepth.export.onnx import max_opset  # newer than the exporter writes: one line, not torch's traceback

    assert main(["export", "--onnx", str(tmp_path / "a.onnx"), "--opset", "99", "--arch", "m4semantic"]) == 2
    err = capsys.readouterr().err
    assert (
        err.startswith(f"cosemdepth export: error: --opset must be in [13, {max_opset()}]") and "Traceback" not in err
    )
    assert not (tmp_path / "a.onnx").exists()


def test_export_refuses_the_ground_truth_depth_variant_in_one_line(tmp_path, capsys):
    from cosemdepth.checkpoints.model_io import save_model
    from cosemdepth.models import build_model

    save_model(build_model(levels=2, semantic_time="gt"), tmp_path / "gt")
    out = tmp_path / "gt.onnx"
    assert main(["export", "--model", str(tmp_path / "gt"), "--onnx", str(out), "--size", "16", "16"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "ground-truth depth" in err and "not exported" in err
    assert not out.exists() and not list(tmp_path.glob("*.onnx*"))


def test_export_command_graph_of_cosemdepth_t_carries_the_semantic_state(tmp_path):
    out = tmp_path / "t.onnx"
    assert main(["export", "--onnx", str(out), "--arch", "cosemdepth-t", "--levels", "2", "--size", "16", "24"]) == 0
    sess = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    ins = {i.name: i.shape for i in sess.get_inputs()}
    assert ins["state_semantic_1"] == [1, 7, 8, 12] and ins["state_semantic_2"] == [1, 7, 4, 6]
    outs = [o.name for o in sess.get_outputs()]
    assert outs[:2] == ["depth", "semantic"] and outs[-2:] == ["next_state_semantic_1", "next_state_semantic_2"]


def test_benchmark_command_writes_json_and_markdown(tmp_path, capsys, bf16_cpu):
    j, md = tmp_path / "b.json", tmp_path / "b.md"
    rc = main(
        [
            "benchmark",
            "--models",
            "m4semantic",
            "--levels",
            "2",
            "--size",
            "16",
            "16",
            "--batch",
            "1",
            "2",
            "--iters",
            "2",
            "--batched-iters",
            "1",
            "--warmup",
            "1",
            "--json",
            str(j),
            "--md",
            str(md),
        ]
    )
    assert rc == 0
    rep = json.loads(j.read_text())
    rows = {(r["path"], r["precision"], r["batch"]) for r in rep["results"]}
    assert rows == {
        ("reference", "fp32", 1),
        ("fast", "fp32", 1),
        ("fast", "fp32", 2),
        ("fast", "bf16", 1),
        ("fast", "bf16", 2),
        ("fast", "int8", 1),
        ("fast", "int8", 2),
    }
    from cosemdepth.models import build_model

    params = build_model(arch="m4semantic", levels=2).num_parameters()
    assert all(r["height"] == 16 and r["levels"] == 2 and r["params"] == params for r in rep["results"])
    assert rep["meta"]["cpu_count"] >= 1 and "M4Semantic" in md.read_text()
    # the spread of the repeats and a readable busy figure ("machine busy 0.505050505050505" before)
    import re

    rows = [line for line in capsys.readouterr().out.splitlines() if "ms/frame" in line]
    assert len(rows) == 7
    assert all(re.search(r"\(min [\d.]+, IQR [\d.]+-[\d.]+, max [\d.]+\)", r) for r in rows), rows
    assert all(re.search(r"\(machine busy: (\d{1,3} %|unknown)\)$", r) for r in rows), rows


def test_benchmark_threads_must_be_positive(capsys):
    import pytest

    with pytest.raises(SystemExit) as exit_:  # an argument error (argparse exits): 0 was taken as "not given"
        main(["benchmark", "--threads", "0", "--json", "", "--md", ""])
    assert exit_.value.code == 2
    assert "--threads: expected a positive integer, got '0'" in capsys.readouterr().err


def test_benchmark_command_rejects_fp16_on_cpu(capsys):
    assert main(["benchmark", "--device", "cpu", "--precision", "fp16", "--json", "", "--md", ""]) == 2
    assert "fp16" in capsys.readouterr().err


def test_benchmark_command_rejects_int8_on_cuda(monkeypatch, capsys):
    import torch

    import cosemdepth.cli.benchmark as bench

    monkeypatch.setattr(bench, "resolve_device", lambda name: torch.device("cuda"))  # no GPU needed for the check
    assert main(["benchmark", "--device", "cuda", "--precision", "int8", "--json", "", "--md", ""]) == 2
    err = capsys.readouterr().err.strip()
    assert "--precision int8" in err and "CPU" in err and "Traceback" not in err and len(err.splitlines()) == 1


SHIPPED = Path(__file__).resolve().parents[2] / "weights" / "synthair-cosemdepth"


def test_export_check_reports_what_it_compared_and_fails_a_broken_graph(tmp_path, capsys, monkeypatch):
    out = tmp_path / "m.onnx"
    argv = ["export", "--onnx", str(out), "--model", str(SHIPPED), "--size", "32", "32", "--check"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "6 frames of a SynthAir flight at 32x32" in text and "Noise floor" in text and text.rstrip().endswith("OK")
    for output in ("depth", "semantic", "state"):
        assert any(line.split()[:1] == [output] and line.rstrip().endswith("ok") for line in text.splitlines())

    from cosemdepth.cli import export as export_cli

    def broken_export(*args, **kwargs):  # the export, then the semantic decoder's last convolution scaled by 1.01
        from cosemdepth.export.provenance import stamp

        path = export_onnx(*args, **kwargs)
        proto = onnx.load(str(path))
        name = "model.semantic_decoder.levels.0.refiner.convs.6.weight"
        init = next(i for i in proto.graph.initializer if i.name == name)
        init.CopyFrom(numpy_helper.from_array(numpy_helper.to_array(init) * np.float32(1.01), name))
        onnx.save(proto, str(path))
        stamp(path, {})  # stamped as the exporter stamps its graph: a wrong graph, not one changed after export
        return path

    monkeypatch.setattr(export_cli, "export_onnx", broken_export)
    assert main(argv) == 1
    text = capsys.readouterr().out
    assert text.rstrip().endswith("MISMATCH")
    assert any(line.split()[:1] == ["semantic"] and "OVER on frame(s)" in line for line in text.splitlines())


def test_benchmark_onnxruntime_backend_times_the_exported_graph(tmp_path, capsys):
    js, md = tmp_path / "b.json", tmp_path / "b.md"
    rc = main(
        [
            "benchmark",
            "--backend",
            "onnxruntime",
            "--models",
            "m4depth",
            "--levels",
            "2",
            "--size",
            "16",
            "16",
            "--batch",
            "1",
            "2",
            "--warmup",
            "1",
            "--iters",
            "2",
            "--batched-iters",
            "1",
            "--threads",
            "1",
            "--json",
            str(js),
            "--md",
            str(md),
        ]
    )
    assert rc == 0
    rep = json.loads(js.read_text())
    assert rep["meta"]["backend"] == "onnxruntime"
    rows = rep["results"]
    assert [(r["arch"], r["path"], r["precision"], r["batch"], r["device"]) for r in rows] == [
        ("m4depth", "onnxruntime", "fp32", 1, "cpu"),
        ("m4depth", "onnxruntime", "fp32", 2, "cpu"),
    ]
    assert [len(r["step_ms"]) for r in rows] == [2, 1] and all(t > 0 for r in rows for t in r["step_ms"])
    # both are rounded to 1e-3 ms from the same median, so they agree to within that rounding
    assert rows[1]["median_ms_per_frame"] == pytest.approx(rows[1]["median_ms_per_step"] / 2, abs=1e-3)
    assert main(["benchmark", "--backend", "onnxruntime", "--device", "cuda:0", "--json", "", "--md", ""]) == 2
