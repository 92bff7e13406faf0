"""benchmarks/temporal_semantics.py --init: the fine-tuning recipe comes from the source model's config.json, and a
folder that is not a model is a one-line error before anything is generated or trained."""

import importlib.util
import json
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "temporal_semantics.py"


@pytest.fixture(scope="module")
def script():
    spec = importlib.util.spec_from_file_location("temporal_semantics_script", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _model_dir(tmp_path, train: dict) -> Path:
    d = tmp_path / "model"
    d.mkdir()
    meta = {"model": {"arch": "cosemdepth", "levels": 5}, "source": {"run_config": {"train": train}}}
    (d / "config.json").write_text(json.dumps(meta), encoding="utf-8")
    return d


def test_from_scratch_the_recipe_is_synthair_small_unless_lr_is_given(script):
    assert script.recipe_sets(None, None) == []
    assert script.recipe_sets(None, 1e-4) == ["train.lr=0.0001"]


def test_fine_tuning_takes_levels_precision_and_class_weights_from_the_source(script, tmp_path):
    d = _model_dir(tmp_path, {"bf16": True, "semantic_class_weights": [0.5, 2.0]})
    assert script.recipe_sets(d, None) == [
        f"train.lr={script.FINETUNE_LR}",
        "model.levels=5",
        "train.bf16=true",
        "train.semantic_class_weights=[0.5, 2.0]",
    ]


def test_fine_tuning_a_source_without_a_recorded_run_config_keeps_fp32_and_uniform_weights(script, tmp_path):
    d = _model_dir(tmp_path, {})
    assert script.recipe_sets(d, 2e-5) == ["train.lr=2e-05", "model.levels=5"]


def test_different_recipes_train_into_different_run_folders(script):
    a, b = script._tag(["w", "train.lr=3e-05"]), script._tag(["w", "train.lr=1e-05"])
    assert a != b and len(a) == 8 and script._tag(["w", "train.lr=3e-05"]) == a


def test_init_that_is_not_a_model_folder_exits_2_and_writes_nothing(script, tmp_path, monkeypatch, capsys):
    work = tmp_path / "work"
    monkeypatch.setattr(
        sys,
        "argv",
        [
            "temporal_semantics.py",
            "--init",
            str(tmp_path / "nope"),
            "--work",
            str(work),
            "--out",
            str(tmp_path / "out" / "r"),
            "--strip",
            str(tmp_path / "s.png"),
        ],
    )
    assert script.main() == 2
    err = capsys.readouterr().err
    assert err.strip() == f"--init {tmp_path / 'nope'}: not a model folder (no config.json)"
    assert not work.exists() and not (tmp_path / "out").exists()


def _row(miou, flicker, ms):
    return {"miou": {"mean": miou}, "flicker": {"mean": flicker}, "ms_per_frame": ms}


def test_acceptance_against_hand_computed_differences(script):
    summary = {
        "cosemdepth": _row(0.30, 0.10, 100.0),
        "cosemdepth_t": _row(0.325, 0.065, 111.0),
        "s_prev_gt": _row(0.31, 0.08, 104.0),
    }
    acc = script.acceptance(summary)
    assert acc["miou_gain_points"]["measured"] == pytest.approx(2.5) and acc["miou_gain_points"]["met"]
    assert acc["flicker_reduction"]["measured"] == pytest.approx(0.35) and acc["flicker_reduction"]["met"]
    assert acc["time_increase"]["measured"] == pytest.approx(0.11) and not acc["time_increase"]["met"]
    assert acc["s_prev_gt_miou_gain_points"]["measured"] == pytest.approx(1.0)
    assert script.acceptance({"cosemdepth": summary["cosemdepth"]}) == {}


def test_a_derived_variant_is_the_source_weights_under_the_config_change(script, tmp_path):
    import torch

    from cosemdepth.checkpoints.model_io import load_model, save_model
    from cosemdepth.models import build_model

    torch.manual_seed(0)
    src = tmp_path / "cosemdepth_t-s0"
    save_model(build_model(arch="cosemdepth-t", levels=2), src / "best")
    run = tmp_path / "cosemdepth_t_avg-s0"
    source_v, changes = script.DERIVED["cosemdepth_t_avg"]
    assert source_v == "cosemdepth_t" and changes == {"semantic_fusion": 0.5}
    script.derive_run(src, run, changes)
    a, b = load_model(src / "best", mode="reference"), load_model(run / "best", mode="reference")
    assert b.config.semantic_fusion == 0.5 and a.config.semantic_fusion == 0.0
    assert b.config.to_dict() == {**a.config.to_dict(), "semantic_fusion": 0.5}
    assert all(torch.equal(x, y) for x, y in zip(a.state_dict().values(), b.state_dict().values()))
    before = (run / "best" / "model.safetensors").stat().st_mtime_ns
    script.derive_run(src, run, changes)  # an existing derived run is kept
    assert (run / "best" / "model.safetensors").stat().st_mtime_ns == before
