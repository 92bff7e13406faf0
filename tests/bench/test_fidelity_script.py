"""benchmarks/fidelity.py writes its JSON (the benchmark report shape) only when asked: a plain run leaves the tracked
result file alone."""

import importlib.util
import json
from pathlib import Path

import pytest

from cosemdepth.bench.harness import validate

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "fidelity.py"


@pytest.fixture
def fidelity(monkeypatch, tmp_path):
    spec = importlib.util.spec_from_file_location("fidelity_script", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)

    class FakeModel:
        def set_numerics(self, pscv_half):
            self.half = pscv_half

    frame = {"depth": {"median": 1e-4, "p99": 2e-3, "max": 3e-2}, "semantic_l1": {"max_abs": 5e-6}}
    monkeypatch.setattr(mod, "load_model", lambda path, mode="fast": FakeModel())
    monkeypatch.setattr(mod, "compare_with_reference", lambda model, fixture: {"streaming": [frame, frame]})
    monkeypatch.setattr(mod, "TRACKED", tmp_path / "tracked" / "fidelity.json")
    (tmp_path / "tracked").mkdir()
    return mod


def test_default_run_writes_nothing(fidelity, tmp_path, capsys):
    fidelity.main(["--fixture", str(tmp_path)])
    printed = capsys.readouterr().out
    assert "frame 1: depth median 1.00e-04 p99 2.00e-03 max 3.00e-02" in printed and "wrote" not in printed
    assert list((tmp_path / "tracked").iterdir()) == []


def test_out_and_update_write_the_same_figures_as_printed(fidelity, tmp_path, capsys):
    fidelity.main(["--fixture", str(tmp_path)])
    plain = capsys.readouterr().out
    out = tmp_path / "mine.json"
    fidelity.main(["--fixture", str(tmp_path), "--out", str(out)])
    with_out = capsys.readouterr().out
    assert with_out == plain + f"wrote {out}\n"
    report = json.loads(out.read_text())
    assert validate(report) == [] and report["tool"] == "fidelity" and report["params"]["fixture"] == str(tmp_path)
    assert report["results"]["pscv_float32"]["streaming"][0]["depth"]["p99"] == 2e-3
    assert list((tmp_path / "tracked").iterdir()) == []
    fidelity.main(["--fixture", str(tmp_path), "--update"])
    assert capsys.readouterr().out == plain + f"wrote {fidelity.TRACKED}\n"
    assert fidelity.TRACKED.exists()


def test_out_and_update_are_exclusive(fidelity, tmp_path):
    with pytest.raises(SystemExit) as e:
        fidelity.parse_args(["--out", str(tmp_path / "x.json"), "--update"])
    assert e.value.code == 2


def test_default_fixture_is_the_shared_one_when_present_else_the_repositorys(fidelity, tmp_path, monkeypatch):
    monkeypatch.setattr(fidelity, "SHARED_FIXTURE", tmp_path / "absent")
    assert fidelity.default_fixture() == fidelity.IN_REPO_FIXTURE
    assert (fidelity.IN_REPO_FIXTURE / "reference.npz").is_file()
    (tmp_path / "shared").mkdir()
    (tmp_path / "shared" / "reference.npz").write_bytes(b"")
    monkeypatch.setattr(fidelity, "SHARED_FIXTURE", tmp_path / "shared")
    assert fidelity.default_fixture() == tmp_path / "shared"
