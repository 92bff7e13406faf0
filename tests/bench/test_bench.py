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
    assert len(s["others_cores_per_step"]) == 2 and all(
        0 <= o <= (os.cpu_count() or 1) + 0.5 for o in s["others_cores_per_step"]
    )
    assert s["quiet_steps"] == sum(o <= 0.1 for o in s["others_cores_per_step"])
    sep = run_separate(case)
    assert (
        sep.params
        == build_model(arch="m4depth", levels=2).num_parameters()
        + build_model(arch="m4semantic", levels=2).num_parameters()
    )
    cmp = joint_vs_separate(res, sep)
    assert cmp["joint_fewer_params"] and cmp["joint_params"] == s["params"]
    report = {
        "meta": {"date_utc": "d", "cpu_model": "c", "cpu_count": 2, "threads": 2, "torch": "t", "command": "x"},
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


def test_noise_verdict_on_hand_made_samples():
    """No "joint faster: no" drawn from a difference inside the run-to-run noise."""
    from cosemdepth.bench.noise import compare_times, format_busy, format_spread, quantile, spread

    a = [10.0, 11.0, 12.0, 13.0, 14.0]  # IQR 11-13
    assert spread(a) == {"min": 10.0, "q25": 11.0, "median": 12.0, "q75": 13.0, "max": 14.0}
    assert quantile([4.0, 1.0, 3.0, 2.0], 0.5) == 2.5 and quantile([4.0, 1.0, 3.0, 2.0], 0.25) == 1.75
    assert compare_times(a, [12.0, 12.5, 13.5, 15.0, 16.0]) == "within noise"  # medians differ, IQRs overlap
    assert compare_times(a, [12.5, 13.5, 14.0, 15.0, 16.0]) == "faster"  # IQR 13.5-15 above 11-13
    assert compare_times(a, [13.5, 14.0, 14.5, 30.0, 31.0]) == "faster"  # 13 < 14 (b's q25)
    assert compare_times([13.5, 14.0, 14.5, 30.0, 31.0], a) == "slower"
    assert compare_times(a, [9.0, 13.0, 13.5, 14.0, 100.0]) == "within noise"  # touching ranges are not apart
    assert compare_times(a, list(reversed(a))) == "within noise"
    assert format_spread(spread(a), "ms/frame") == "12.0 ms/frame (min 10.0, IQR 11.0-13.0, max 14.0)"
    assert format_busy(0.505050505050505) == "machine busy: 51 %" and format_busy(None) == "machine busy: unknown"
    with pytest.raises(ValueError):
        spread([])


def test_joint_vs_separate_verdict_uses_the_spread():
    from cosemdepth.bench.runner import BenchResult

    case = BenchCase(arch="cosemdepth", height=16, width=16)

    def result(times, arch="cosemdepth"):
        r = BenchResult(BenchCase(**{**case.__dict__, "arch": arch}), 10, list(times), [], 1.0)
        r.others = [0.0] * len(times)
        return r

    close = joint_vs_separate(result([10, 11, 12, 13, 14]), result([12, 12.5, 13.5, 15, 16], "m4depth+m4semantic"))
    assert close["joint_faster"] == "within noise" and close["time_basis"] == "quiet steps"
    assert close["joint_spread_ms_per_frame"]["q75"] == 13 and close["separate_spread_ms_per_frame"]["q25"] == 12.5
    apart = joint_vs_separate(result([10, 11, 12, 13, 14]), result([20, 21, 22, 23, 24], "m4depth+m4semantic"))
    assert apart["joint_faster"] == "yes"
    md = markdown(
        {
            "meta": {"date_utc": "d", "cpu_model": "c", "cpu_count": 2, "threads": 2, "torch": "t"},
            "results": [],
            "joint_vs_separate": [close, {**apart, "joint_faster": True}],
        }
    )
    assert "| 12.0 (11.0-13.0) | 13.5 (12.5-15.0) |" in md and "| within noise |" in md and "| yes |" in md


def test_int8_case_is_calibrated_before_timing_and_cpu_only():
    from cosemdepth.bench.runner import build

    case = BenchCase(arch="m4semantic", height=16, width=16, levels=2, precision="int8")
    engine = build(case).engine
    assert engine.int8 and engine.calibrated  # no timed frame runs the float32 calibration pass
    with pytest.raises(ValueError, match="CPU only"):
        build(BenchCase(**{**case.__dict__, "device": "cuda"}))
