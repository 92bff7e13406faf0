"""scripts/gpu_check.sh: its comparisons on hand-computed values, and its dry run on this CPU (every stage planned
and reported; what the CPU can run is run and checked against the PyTorch reference)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cosemdepth.bench import gpu_check
from cosemdepth.bench.gpu_check import STAGES, TOLERANCES, compare_outputs, within
from cosemdepth.cli import gpu_check as gpu_check_cli

ROOT = Path(__file__).resolve().parents[2]


def test_compare_outputs_on_hand_computed_frames():
    ref_d = np.array([[[[1.0, 2.0], [4.0, -1.0]]]])  # the -1 (no depth) is left out
    got_d = np.array([[[[1.1, 2.0], [3.0, 5.0]]]])  # relative differences 0.1, 0, 0.25: median 0.1
    ref_s = np.zeros((1, 2, 2, 2))
    ref_s[:, 0] = 1.0  # class 0 everywhere
    got_s = ref_s.copy()
    got_s[0, :, 0, 0] = [0.0, 1.0]  # one pixel of four flips
    reset_d = np.full_like(ref_d, 99.0)  # a reset frame's depth is not compared
    m = compare_outputs([(ref_d, ref_s), (ref_d, ref_s)], [(reset_d, ref_s), (got_d, got_s)], [True, False])
    assert m["depth_median_rel"] == pytest.approx(0.1)
    assert m["labels_equal"] == 0.75 and m["frames"] == 2
    assert compare_outputs([(None, ref_s)], [(None, ref_s)], [False]) == {
        "depth_median_rel": None,
        "labels_equal": 1.0,
        "frames": 1,
    }


def test_within_applies_both_bounds():
    tol = TOLERANCES["reduced"]
    assert within({"depth_median_rel": tol["depth_median_rel"], "labels_equal": tol["labels_equal"]}, "reduced")
    assert not within({"depth_median_rel": tol["depth_median_rel"] * 1.01, "labels_equal": 1.0}, "reduced")
    assert not within({"depth_median_rel": 0.0, "labels_equal": tol["labels_equal"] - 1e-4}, "reduced")
    assert within({"depth_median_rel": None, "labels_equal": None}, "fp32")


def rows(report, stage):
    return next(s for s in report["stages"] if s["name"] == stage)


def test_dry_run_of_the_script_plans_every_stage(tmp_path):
    out = tmp_path / "check.json"
    env = {**os.environ, "PYTHON": sys.executable, "OMP_NUM_THREADS": "1"}
    r = subprocess.run(
        ["bash", str(ROOT / "scripts" / "gpu_check.sh"), "--dry-run", "--model", "", "--size", "32", "--out", str(out)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        timeout=600,
    )
    report = json.loads(out.read_text())
    assert report["schema"] == gpu_check.SCHEMA and report["meta"]["dry_run"] is True
    assert [s["name"] for s in report["stages"]] == list(STAGES)
    summary = report["summary"]
    assert sum(summary.values()) == len(STAGES)
    assert r.returncode == (1 if summary["failed"] or summary["error"] else 0), r.stdout[-3000:]
    for s in report["stages"]:
        assert s["status"] in ("ok", "failed", "error", "not_run"), s
        assert s["status"] != "error", s
        if s["status"] == "not_run":
            assert s["reason"], s
    # what needs a GPU (or a second one, or packages this machine lacks) is planned and says why it did not run
    assert "dry run" in rows(report, "cuda_tests")["reason"] and "dry run" in rows(report, "ddp")["reason"]
    streaming = {(x["precision"], x["path"]): x for x in rows(report, "streaming")["results"]}
    assert set(streaming) == {(p, q) for p in ("fp32", "fp16", "bf16") for q in ("fast", "graph")}
    assert all(
        streaming[(p, "graph")]["status"] == "not_run" and "CUDA" in streaming[(p, "graph")]["reason"]
        for p in ("fp32", "fp16", "bf16")
    )
    assert streaming[("fp16", "fast")]["status"] == "not_run"
    # what the CPU can do ran, and float32 agrees with the reference path
    fp32 = streaming[("fp32", "fast")]
    assert fp32["status"] == "ok" and fp32["depth_median_rel"] < 1e-4 and fp32["labels_equal"] == 1.0
    assert fp32["median_ms_per_step"] > 0 and fp32["timed_steps"] == 2
    batched = rows(report, "batched")["results"]
    assert batched and all(x["batch"] == 2 and x["frames_per_s"] > 0 for x in batched)
    training = {x["precision"]: x for x in rows(report, "training")["results"]}
    assert training["fp32"]["status"] == "ok" and training["fp32"]["steps_per_s"] > 0
    providers = {x["provider"]: x for x in rows(report, "onnxruntime")["results"]}
    cpu = providers["CPUExecutionProvider"]
    assert cpu["status"] == "ok" and cpu["depth_median_rel"] < 1e-4 and cpu["labels_equal"] == 1.0
    assert providers["CUDAExecutionProvider"]["status"] == "not_run"
    assert providers["TensorrtExecutionProvider"]["status"] == "not_run"
    assert rows(report, "tensorrt")["status"] == "not_run" and rows(report, "tensorrt")["reason"]


def test_a_spent_budget_runs_nothing_and_says_so(tmp_path, capsys):
    out = tmp_path / "check.json"
    assert gpu_check_cli.main(["--dry-run", "--budget", "0", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert {s["status"] for s in report["stages"]} == {"not_run"}
    assert all("budget" in s["reason"] for s in report["stages"])
    assert not list(tmp_path.glob("*.tmp"))


def test_bad_arguments_stop_in_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        gpu_check_cli.main(["--dry-run", "--out", str(tmp_path / "missing" / "x.json")])
    assert e.value.code == 2 and "does not exist" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        gpu_check_cli.main(["--dry-run", "--iters", "0"])
    assert e.value.code == 2 and "--iters must be positive" in capsys.readouterr().err
