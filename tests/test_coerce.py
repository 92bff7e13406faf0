"""The one typed coercer (cosemdepth.coerce): hand cases for each field type, the one-line errors naming the key, and
the three readers that use it (a model folder's config.json, a YAML run config, --set overrides)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Literal, Optional, Union

import pytest

from cosemdepth.coerce import coerce, from_mapping
from cosemdepth.errors import ConfigError
from cosemdepth.models.config import ModelConfig
from cosemdepth.training.config import RunConfig, resolve_config


@pytest.mark.parametrize(
    "value, tp, expected",
    [
        (True, bool, True),
        ("yes", bool, True),
        ("Off", bool, False),
        (" false ", bool, False),
        ("1", bool, True),
        (3, int, 3),
        (3.0, int, 3),
        ("-12", int, -12),
        (" 7 ", int, 7),
        (2, float, 2.0),
        ("3e-4", float, 3e-4),
        (1.5, float, 1.5),
        ("-inf", float, float("-inf")),
        ("abc", str, "abc"),
        (5, str, "5"),
        (0.5, str, "0.5"),
        ("gt", Literal["off", "gt"], "gt"),
        (False, Literal["off", "gt"], "off"),
        (True, Literal["on", "x"], "on"),
        (None, Optional[int], None),
        ("4", Optional[int], 4),
        (None, Optional[Literal["a"]], None),
        ("true", Union[bool, str], True),
        ("paper", Union[bool, str], "paper"),
        (False, Union[bool, str], False),
        ([1, "2"], tuple[int, ...], (1, 2)),
        (5, tuple[int, ...], (5,)),
        ([], tuple[float, ...], ()),
        (["0.9", 0.99], tuple[float, float], (0.9, 0.99)),
        ([1, 2.0], list[int], [1, 2]),
        ("x", list[str], ["x"]),
        ({"a": 1}, dict, {"a": 1}),
        ({"k": [1]}, dict[str, list], {"k": [1]}),
    ],
)
def test_each_type_by_hand(value, tp, expected):
    got = coerce(value, tp, "k")
    assert got == expected and type(got) is type(expected)


@pytest.mark.parametrize(
    "value, tp, message",
    [
        ("maybe", bool, "k: expected true or false, got 'maybe'"),
        (1, bool, "k: expected true or false, got 1"),
        (2.5, int, "k: expected an integer, got 2.5"),
        (True, int, "k: expected an integer, got True"),
        ("3.0", int, "k: expected an integer, got '3.0'"),
        (float("nan"), int, "k: expected an integer, got nan"),
        ("fast", float, "k: expected a number, got 'fast'"),
        (False, float, "k: expected a number, got False"),
        ([1], str, "k: expected a string, got [1]"),
        (True, str, "k: expected a string, got True"),
        ("own", Literal["off", "gt"], "k: expected one of 'off', 'gt', got 'own'"),
        (False, Literal["no", "off"], "k: expected one of 'no', 'off', got False"),  # two spellings of false: ambiguous
        (None, int, "k: a value is required, got null"),
        ("x", Optional[int], "k: expected an integer, got 'x'"),
        ([1], Union[int, float], "k: invalid value [1] (expected an integer, got [1]; expected a number, got [1])"),
        (["a"], tuple[int, ...], "k[0]: expected an integer, got 'a'"),
        ([1, 2, 3], tuple[float, float], "k: expected a list of 2 values, got [1, 2, 3]"),
        (0.5, tuple[float, float], "k: expected a list of 2 values, got 0.5"),
        ([1, "b"], list[int], "k[1]: expected an integer, got 'b'"),
        ([1], dict, "k: expected a mapping, got [1]"),
    ],
)
def test_errors_are_one_line_naming_the_key(value, tp, message):
    with pytest.raises(ConfigError) as e:
        coerce(value, tp, "k")
    assert str(e.value) == message and "\n" not in message


def test_a_type_it_does_not_know_is_a_programming_error():
    with pytest.raises(TypeError, match="unsupported config type"):
        coerce(1, complex, "k")


@dataclass(frozen=True)
class Inner:
    rate: float = 1.0
    tags: tuple[str, ...] = ()

    def __post_init__(self):
        if self.rate < 0:
            raise ConfigError(f"rate must be >= 0, got {self.rate}")


@dataclass(frozen=True)
class Outer:
    name: str = "a"
    inner: Inner = field(default_factory=Inner)
    items: tuple[Inner, ...] = ()
    extra: Optional[Inner] = None


def test_nested_dataclasses_with_defaults_and_keys_from_the_top():
    got = from_mapping(Outer, {"inner": {"rate": "2"}, "items": [{"tags": "x"}, {}], "extra": {"rate": 0}})
    assert got == Outer(inner=Inner(2.0), items=(Inner(tags=("x",)), Inner()), extra=Inner(0.0))
    assert from_mapping(Outer, None) == Outer() and from_mapping(Outer, {"extra": None}).extra is None
    inner = Inner(3.0)
    assert from_mapping(Outer, {"inner": inner}).inner is inner  # an instance passes as it is
    with pytest.raises(ConfigError, match=r"^items\[1\]\.rate: expected a number, got 'slow'$"):
        from_mapping(Outer, {"items": [{}, {"rate": "slow"}]})
    with pytest.raises(
        ConfigError, match=r"^unknown config key 'inner\.speed'; valid keys of 'inner': \['rate', 'tags'\]$"
    ):
        from_mapping(Outer, {"inner": {"speed": 1}})
    with pytest.raises(
        ConfigError, match=r"^unknown config keys 'a', 'b'; valid keys: \['name', 'inner', 'items', 'extra'\]$"
    ):
        from_mapping(Outer, {"a": 1, "b": 2})
    with pytest.raises(ConfigError, match=r"^inner must be a mapping of keys to values, got list \[1\]$"):
        from_mapping(Outer, {"inner": [1]})
    # a check of the dataclass itself that does not name its section gets the key in front
    with pytest.raises(ConfigError, match=r"^extra: rate must be >= 0, got -1\.0$"):
        from_mapping(Outer, {"extra": {"rate": -1}})


def test_model_folders_yaml_and_overrides_share_it(tmp_path):
    from cosemdepth.checkpoints.model_io import read_config_file, save_model
    from cosemdepth.models import build_model

    save_model(build_model(levels=2), tmp_path / "m")
    meta = json.loads((tmp_path / "m" / "config.json").read_text())
    meta["model"].update(levels="2", dinl="true", semantic_time=None)
    (tmp_path / "m" / "config.json").write_text(json.dumps(meta))
    cfg, _ = read_config_file(tmp_path / "m")
    assert cfg == ModelConfig(levels=2)

    (tmp_path / "run.yaml").write_text(
        "model:\n  levels: 3\n  semantic_time: off\ntrain:\n  lr: 3e-4\ndata:\n  train: [{name: toy}]\n  size: 64\n"
    )
    run = resolve_config(tmp_path / "run.yaml", ["train.betas=[0.8, '0.9']", "model.pscv_dtype=float16"])
    assert (run.model.levels, run.model.semantic_time, run.model.pscv_dtype) == (3, "off", "float16")
    assert (run.train.lr, run.train.betas, run.data.size) == (3e-4, (0.8, 0.9), (64, 64))
    assert type(run.train.lr) is float  # YAML 1.1 reads 3e-4 as a string
    assert RunConfig.from_dict(run.to_dict()) == run

    for where, bad in (
        ("model.levels", "model.levels=many"),
        ("train.optimizer", "train.optimizer=sgd"),
        ("model.pscv_dtype", "model.pscv_dtype=float64"),
    ):
        with pytest.raises(ConfigError, match=rf"^{where}: expected"):
            resolve_config(None, ["data.train.0.name=toy", bad])
    with pytest.raises(ConfigError, match=r"^model\.levels: expected an integer, got 'many'$"):
        ModelConfig.from_dict({"levels": "many"})
