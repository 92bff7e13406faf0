"""Every committed result file under benchmarks/results/ has the one report shape, and is the one current result
of a tool that exists: its name is the tool's (``cosemdepth fast-accuracy`` -> ``cosemdepth_fast_accuracy.json``;
a tool with modes: ``<tool>_<mode>.json``), the tool is a script in benchmarks/ or an installed command, and every
script in benchmarks/ has its result."""

import json
from pathlib import Path

import pytest

from cosemdepth.bench.harness import META_KEYS, SCHEMA, validate
from cosemdepth.cli.main import COMMANDS

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "benchmarks" / "results"
SCRIPTS = sorted(p.stem for p in (ROOT / "benchmarks").glob("*.py"))
FILES = sorted(RESULTS.rglob("*.json"))


def stem_of(report: dict) -> str:
    name = report["tool"].replace(" ", "_").replace("-", "_")
    mode = report["params"].get("mode")
    return f"{name}_{mode}" if mode else name


def test_there_are_results_and_at_most_fifteen_scripts():
    assert FILES and len(SCRIPTS) <= 15


@pytest.mark.parametrize("path", FILES, ids=[p.name for p in FILES])
def test_result_file_has_the_report_shape(path):
    report = json.loads(path.read_text(encoding="utf-8"))
    assert validate(report) == [], path.name
    assert report["schema"] == SCHEMA and set(META_KEYS) <= set(report["meta"])
    assert path.parent == RESULTS and path.stem == stem_of(report)
    tool = report["tool"]
    if tool.startswith("cosemdepth "):
        assert tool.split(" ", 1)[1] in COMMANDS
    else:
        assert tool in SCRIPTS


def test_every_script_has_its_current_result():
    tools = {json.loads(p.read_text(encoding="utf-8"))["tool"] for p in FILES}
    assert set(SCRIPTS) <= tools, sorted(set(SCRIPTS) - tools)


def test_companion_files_belong_to_a_result():
    """Markdown tables and plots sit beside the JSON of their run: no file without one."""
    stems = {p.stem for p in FILES}
    others = [p for p in RESULTS.rglob("*") if p.is_file() and p.suffix != ".json"]
    assert all(p.parent == RESULTS and p.stem in stems for p in others), [p.name for p in others]
