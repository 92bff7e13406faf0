"""Run configs: the paper's defaults, YAML files, overrides, type conversion, and errors that name the key."""

from __future__ import annotations

import pytest
import yaml

from cosemdepth.errors import ConfigError
from cosemdepth.training.config import (
    DataConfig,
    DatasetSource,
    RunConfig,
    TrainConfig,
    apply_override,
    builtin_configs,
    dump_config,
    load_config_dict,
    resolve_config,
)


def test_defaults_are_the_paper_recipe():
    t, d = TrainConfig(), DataConfig()
    assert (t.lr, t.betas, t.eps, t.weight_decay) == (1e-4, (0.9, 0.999), 1e-7, 0.0)
    assert (t.batch_size, t.epochs, t.seed, t.semantic_weight, t.grad_clip) == (3, 60, 42, 0.1, 0.0)
    assert (d.seq_len, d.db_seq_len, d.val_seq_len, d.size, d.augment) == (4, 4, 4, (384, 384), True)
    assert t.best == "paper" and t.lr_decay_epochs == ()
    cfg = RunConfig.from_dict({"data": {"train": [{"root": "x"}]}})
    assert (cfg.model.arch, cfg.model.levels, cfg.model.num_classes) == ("cosemdepth", 5, 7)


def test_shipped_configs_load_and_midair_is_the_default_recipe():
    assert {"midair", "synthair-small"} <= set(builtin_configs())
    midair = resolve_config("midair", ["data.train.0.root=/data/midair"])
    default = RunConfig.from_dict({"data": {"train": [{"root": "/data/midair"}], "num_workers": 4}})
    assert midair == default
    small = resolve_config("synthair-small", ["data.train.0.root=/data/synthair"])
    assert small.data.train[0].name == "synthair" and small.model.levels == 4 and small.data.size == (128, 128)


def test_overrides_convert_types_and_index_lists():
    cfg = resolve_config(
        None,
        [
            "data.train.0.name=toy",
            "train.lr=3e-4",
            "train.betas=[0.8, 0.99]",
            "train.bf16=true",
            "data.train.1.name=toy",
            "data.train.1.weight=0.25",
            "data.size=64",
            "debug.inject_nonfinite_steps=5",
            "data.augment=geometric",
        ],
    )
    assert cfg.train.lr == 3e-4 and isinstance(cfg.train.lr, float)  # YAML reads "3e-4" as a string
    assert cfg.train.betas == (0.8, 0.99) and cfg.train.bf16 is True
    assert [s.weight for s in cfg.data.train] == [1.0, 0.25]
    assert cfg.data.size == (64, 64)
    assert cfg.debug.inject_nonfinite_steps == (5,)
    assert cfg.data.augment == "geometric"
    assert resolve_config(None, ["data.train.0.name=toy", "data.augment=false"]).data.augment is False


def test_precedence_file_then_values_then_overrides(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("train:\n  lr: 1.0e-3\n  epochs: 7\ndata:\n  train:\n    - name: toy\n")
    cfg = resolve_config(f, ["train.epochs=9"], {"train.lr": 2e-3, "train.epochs": 8})
    assert (cfg.train.lr, cfg.train.epochs) == (2e-3, 9)


def test_dump_loads_back_to_the_same_config():
    cfg = resolve_config(
        None,
        [
            "data.train.0.name=toy",
            "data.train.0.options={length: 5}",
            "train.lr=2e-4",
            "data.val.name=toy",
            "train.lr_decay_epochs=[3, 5]",
        ],
    )
    again = RunConfig.from_dict(yaml.safe_load(dump_config(cfg)))
    assert again == cfg


@pytest.mark.parametrize(
    "overrides, key",
    [
        (["train.lrr=1"], "train.lrr"),
        (["trainer.lr=1"], "trainer"),
        (["train.lr=-1"], "train.lr"),
        (["train.lr=abc"], "train.lr"),
        (["train.batch_size=0"], "train.batch_size"),
        (["train.batch_size=2.5"], "train.batch_size"),
        (["train.betas=[0.9]"], "train.betas"),
        (["train.best=no_such_metric"], "train.best"),
        (["model.arch=resnet"], "model arch"),
        (["model.levels=9"], "model levels"),
        (["data.train.0.name=imagenet"], "data.train[0].name"),
        (["data.train.1.name=toy", "data.train.1.weight=-1"], "data.train[1].weight"),
        (["data.seq_len=1"], "data.seq_len"),
        (["data.db_seq_len=3"], "data.db_seq_len"),
        (["data.size=[32, 32, 3]"], "data.size"),
        (["debug.inject_nonfinite_steps=[0]"], "debug.inject_nonfinite_steps"),
        (["train.device=tpu"], "train.device"),
        (["train.semantic_class_weights=[1, 2]"], "train.semantic_class_weights"),
        (["train.semantic_class_weights=[1, 1, 1, 1, 1, 1, -1]"], "train.semantic_class_weights[6]"),
        (["train.semantic_class_weights=[0, 0, 0, 0, 0, 0, 0]"], "train.semantic_class_weights"),
        (["model.arch=m4depth", "train.semantic_class_weights=[1, 1, 1, 1, 1, 1, 1]"], "train.semantic_class_weights"),
    ],
)
def test_bad_values_raise_config_errors_naming_the_key(overrides, key):
    with pytest.raises(ConfigError) as e:
        resolve_config(None, ["data.train.0.name=toy"] + overrides)
    assert key in str(e.value)


def test_override_syntax_errors():
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        apply_override({}, "train.lr")
    with pytest.raises(ConfigError, match="next index is 1"):
        apply_override({"data": {"train": [{}]}}, "data.train.3.name=toy")
    with pytest.raises(ConfigError, match="index it with a number"):
        apply_override({"data": {"train": [{}]}}, "data.train.first.name=toy")


def test_config_file_errors(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config_dict(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("train: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config_dict(bad)
    listy = tmp_path / "list.yaml"
    listy.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="top level must be a mapping"):
        load_config_dict(listy)
    with pytest.raises(ConfigError, match="folder"):
        load_config_dict(tmp_path)


def test_a_config_needs_no_data_folder_until_it_is_used():
    assert RunConfig().data.train[0].root is None  # e.g. --print-config before the data exists
    with pytest.raises(ConfigError, match=r"data\.val\.name"):
        DatasetSource(name="kitti").check("data.val")
