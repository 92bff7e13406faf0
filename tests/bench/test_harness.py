"""The benchmark harness: run metadata read from the system, the report shape and its validator, the timing
helper."""

import json
import subprocess
from pathlib import Path

import pytest

from cosemdepth.bench import harness
from cosemdepth.bench.harness import CPU_FLAGS, META_KEYS, make_report, validate, write_report

CPUINFO = """processor\t: 0
vendor_id\t: GenuineIntel
model name\t: Intel(R) Xeon(R) Platinum 8480+
flags\t\t: fpu sse2 avx2 avx512f avx512_vnni amx_tile amx_bf16
processor\t: 1
model name\t: ignored, only the first counts
"""


def test_cpu_model_and_flags_from_cpuinfo_text():
    assert harness.cpu_model(CPUINFO) == "Intel(R) Xeon(R) Platinum 8480+"
    assert harness.cpu_flags(CPUINFO) == {
        "avx2": True,
        "avx512f": True,
        "avx512_bf16": False,
        "avx512_vnni": True,
        "amx_tile": True,
        "amx_bf16": True,
        "amx_int8": False,
    }
    assert harness.cpu_model("") is None and harness.cpu_flags("processor : 0\n") is None


def test_git_state_is_this_checkout_s():
    root = Path(harness.__file__).resolve().parents[3]
    head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True)
    commit, dirty = harness.git_state()
    if head.returncode == 0 and (root / "src" / "cosemdepth" / "bench" / "harness.py").is_file():
        assert commit == head.stdout.strip() and isinstance(dirty, bool)
    # a file outside any checkout of the project: nothing is claimed
    assert harness.git_state(Path("/tmp/cosemdepth/bench/harness.py")) == (None, None)


def test_run_meta_has_every_key_and_a_valid_report_round_trips(tmp_path):
    meta = harness.run_meta(command="python benchmarks/x.py --a 1", extra_field=3)
    assert (
        set(META_KEYS) <= set(meta) and meta["command"] == "python benchmarks/x.py --a 1" and meta["extra_field"] == 3
    )
    assert meta["cpu_flags"] is None or set(meta["cpu_flags"]) == set(CPU_FLAGS)
    rep = make_report("conv_peak", {"threads": [1]}, {"rows": [1.5, float("nan")]}, meta=meta, extra=[1])
    assert validate(rep) == []
    out = write_report(tmp_path / "r.json", rep)
    back = json.loads(out.read_text())
    assert back["results"]["rows"] == [1.5, None] and back["extra"] == [1]  # NaN written as null: strict JSON
    assert back["tool"] == "conv_peak" and back["schema"] == harness.SCHEMA


def test_validate_names_what_is_wrong(tmp_path):
    meta = {k: None for k in META_KEYS} | {"date_utc": "2026-12-04T10:00:00Z", "torch": "2.13"}
    good = {"tool": "t", "schema": 1, "meta": meta, "params": {}, "results": []}
    assert validate(good) == []
    assert validate([]) == ["a report is a JSON object, not list"]
    assert validate({k: v for k, v in good.items() if k != "params"}) == ["missing top-level key 'params'"]
    assert validate({**good, "schema": 2}) == ["'schema' must be 1, got 2"]
    assert validate({**good, "results": 3}) == ["'results' must be an object or a list"]
    assert validate({**good, "meta": {**meta, "torch": None}}) == ["meta 'torch' must not be null"]
    assert validate({**good, "meta": {k: v for k, v in meta.items() if k != "git_commit"}}) == [
        "meta lacks 'git_commit' (null when not known)"
    ]
    assert validate({**good, "meta": {**meta, "date_utc": "2026-12-04 10:00 UTC"}}) == [
        "meta 'date_utc' must be YYYY-MM-DDTHH:MM:SSZ, got '2026-12-04 10:00 UTC'"
    ]
    assert validate({**good, "meta": {**meta, "cpu_flags": {"avx2": True}}})[0].startswith("meta 'cpu_flags'")
    assert validate({**good, "meta": {**meta, "threads": 0}}) == ["meta 'threads' must be a positive integer or null"]
    with pytest.raises(ValueError, match="schema"):
        write_report(tmp_path / "bad.json", {**good, "schema": 2})
    assert not (tmp_path / "bad.json").exists()
    with pytest.raises(ValueError, match="may not be named"):
        make_report("t", {}, [], meta=meta, schema=2)


def test_time_calls_and_summarize():
    calls = []
    times = harness.time_calls(lambda: calls.append(1), warmup=2, iters=3)
    assert len(calls) == 5 and len(times) == 3 and all(t >= 0 for t in times)
    with pytest.raises(ValueError):
        harness.time_calls(lambda: None, iters=0)
    assert harness.summarize([0.001, 0.003, 0.002], scale=1e3) == {
        "n": 3,
        "median": 2.0,
        "min": 1.0,
        "max": 3.0,
        "mean": 2.0,
    }


def test_command_line_of_a_script_and_of_the_cli():
    assert harness.command_line(["cosemdepth", "benchmark", "--size", "64 64"]) == "cosemdepth benchmark --size '64 64'"
    assert harness.command_line(["/abs/path/benchmarks/conv_peak.py", "--threads", "1"]).startswith("python ")
