import json
import os

import numpy as np
import pytest
import torch

from cosemdepth.bench.memory import PeakMemory, peak_rss_bytes, reset_peak_rss, rss_bytes
from cosemdepth.bench.report import markdown, write_report
from cosemdepth.bench.runner import BenchCase, joint_vs_separate, percentile, run_case, run_separate


def test_percentile_matches_numpy():
    vals = sorted([5.0, 1.0, 9.0, 3.0, 7.0, 2.0])
    for q in (0, 10, 50, 90, 100):
        assert percentile(vals, q) == pytest.approx(np.percentile(vals, q))
    with pytest.raises(ValueError):
        percentile([], 50)


def test_peak_memory_sees_a_temporary_allocation():
    with PeakMemory("cpu") as pm:
        x = torch.ones(64 * 2**20 // 4)  # 64 MiB, touched
        del x
    assert pm.method.startswith("VmHWM") and pm.exact
    assert 60 * 2**20 <= pm.extra <= 90 * 2**20
    with PeakMemory("cpu") as small:
        y = torch.ones(1000)
        del y
    assert small.extra < 8 * 2**20
    assert rss_bytes() > 0 and peak_rss_bytes() >= rss_bytes() - 2**20 and reset_peak_rss()


def test_run_case_joint_vs_separate_and_reports(tmp_path):
    case = BenchCase(arch="cosemdepth", height=16, width=24, warmup=1, iters=2, levels=2)
    res = run_case(case)
    s = res.summary()
    from cosemdepth.models import build_model

    assert s["params"] == build_model(levels=2).num_parameters()
    assert len(s["step_ms"]) == 2 and s["p90_ms_per_frame"] >= s["median_ms_per_frame"] >= s["min_ms_per_frame"] > 0
    assert s["fps"] == pytest.approx(1000 / s["median_ms_per_frame"], rel=1e-2)
    assert len(s["others_cores_per_step"]) == 2 and all(0 <= o <= (os.cpu_count() or 1) + 0.5 for o in s["others_cores_per_step"])
    assert s["quiet_steps"] == sum(o <= 0.1 for o in s["others_cores_per_step"])
    sep = run_separate(case)
    assert sep.params == build_model(arch="m4depth", levels=2).num_parameters() + build_model(
        arch="m4semantic", levels=2
    ).num_parameters()
    cmp = joint_vs_separate(res, sep)
    assert cmp["joint_fewer_params"] and cmp["joint_params"] == s["params"]
    report = {
        "meta": {"date": "d", "cpu": "c", "cpu_count": 2, "torch_threads": 2, "torch": "t", "command": "x"},
        "results": [s, sep.summary()],
        "joint_vs_separate": [cmp],
    }
    write_report(report, tmp_path / "b.json", tmp_path / "b.md")
    assert json.loads((tmp_path / "b.json").read_text())["results"][0]["arch"] == "cosemdepth"
    md = (tmp_path / "b.md").read_text()
    assert md == markdown(report)
    assert "| Co-SemDepth | cpu | fp32 | fast | 1 | 16x24 |" in md and "M4Depth + M4Semantic" in md
    with pytest.raises(ValueError, match="reference path"):
        run_case(BenchCase(arch="m4semantic", precision="bf16", path="reference", height=16, width=16))


def test_graph_path_runs_the_static_program_on_cpu():
    case = BenchCase(arch="m4depth", height=16, width=16, warmup=1, iters=2, levels=2, path="graph", batch=2)
    s = run_case(case).summary()
    assert s["path"] == "graph" and len(s["step_ms"]) == 2 and s["params"] > 0
