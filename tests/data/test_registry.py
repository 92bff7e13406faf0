"""The dataset table: a dataset registered at run time is seen by open_dataset, the training config, the CLI's
choices and the evaluation's class names and palette; the built-in entries keep today's defaults."""

import numpy as np
import pytest

from cosemdepth.cli.main import build_parser
from cosemdepth.data import DATASETS, open_dataset, register_dataset
from cosemdepth.data.registry import split_datasets
from cosemdepth.errors import ConfigError
from cosemdepth.measures.classes import class_info, dataset_classes, generic_palette
from cosemdepth.training.config import DatasetSource

CLASSES = ("ground", "roof", "cloud")
PALETTE = [[10, 20, 30], [40, 50, 60], [70, 80, 90]]


def _open_toy(root, split_dir, split, seq_len, size, augment, *, scale: float = 1.0):
    return {
        "root": root,
        "split_dir": split_dir,
        "split": split,
        "seq_len": seq_len,
        "size": size,
        "augment": augment,
        "scale": scale,
    }


def _toy_splits(root, out_dir, rule=None):
    return {"test": []}


@pytest.fixture
def toyset():
    saved = dict(DATASETS)
    register_dataset(
        "toyset",
        _open_toy,
        split="val",
        size=(96, 128),
        split_dir="lists",
        classes=CLASSES,
        palette=PALETTE,
        has_depth=False,
        split_generator=_toy_splits,
    )
    yield "toyset"
    DATASETS.clear()
    DATASETS.update(saved)


def test_open_dataset_uses_the_entry_and_its_defaults(toyset, tmp_path):
    got = open_dataset(toyset, tmp_path, seq_len=2, scale=0.5)
    assert got == {
        "root": tmp_path,
        "split_dir": tmp_path / "lists",
        "split": "val",
        "seq_len": 2,
        "size": (96, 128),
        "augment": False,
        "scale": 0.5,
    }
    got = open_dataset(toyset, tmp_path, split_dir=tmp_path / "x", split="test", size=64)
    assert (got["split_dir"], got["split"], got["size"]) == (tmp_path / "x", "test", 64)
    with pytest.raises(ConfigError, match=r"unknown option\(s\) \['labels'\] for dataset 'toyset'.*\['scale'\]"):
        open_dataset(toyset, tmp_path, labels="mapped")


def test_config_and_cli_choices_include_it(toyset, tmp_path):
    assert tuple(DATASETS)[-2:] == ("toy", toyset)
    DatasetSource(name=toyset).check("data.train[0]")
    for command, extra in (("evaluate", []), ("predict", ["--out", "o"])):
        args = build_parser(only=command).parse_args(
            [command, "--model", "m", "--dataset", toyset, "--root", str(tmp_path), *extra]
        )
        assert args.dataset == toyset
    args = build_parser(only="splits").parse_args(["splits", toyset, str(tmp_path)])
    assert args.dataset == toyset


def test_cli_choices_refuse_it_once_removed(tmp_path, capsys):
    assert "toyset" not in DATASETS
    with pytest.raises(SystemExit) as e:
        build_parser(only="evaluate").parse_args(["evaluate", "--model", "m", "--dataset", "toyset", "--root", "r"])
    assert e.value.code == 2
    assert "invalid choice: 'toyset'" in capsys.readouterr().err


def test_class_names_and_palette_come_from_the_entry(toyset):
    assert dataset_classes()[toyset] == 3
    names, palette = class_info(3, toyset)
    assert names == CLASSES
    assert palette.dtype == np.uint8 and palette.tolist() == PALETTE
    # a class count no dataset has: generic names and palette (unchanged)
    names, palette = class_info(5, toyset)
    assert names == tuple(f"class {i}" for i in range(5))
    assert np.array_equal(palette, generic_palette(5))


def test_builtin_entries_keep_todays_defaults():
    assert tuple(DATASETS) == ("midair", "synthair", "topair", "aeroscapes", "flight", "toy")
    assert dataset_classes() == {"midair": 7, "synthair": 7, "topair": 9, "aeroscapes": 12}
    assert {n: (s.split, s.size) for n, s in DATASETS.items()} == {
        "midair": ("test", 384),
        "synthair": ("test", 384),
        "topair": ("test", 384),
        "aeroscapes": ("val", None),
        "flight": (None, None),
        "toy": ("train", (32, 32)),
    }
    assert [n for n, s in DATASETS.items() if not s.windows] == ["aeroscapes", "toy"]
    assert [n for n, s in DATASETS.items() if not s.needs_root or s.model_classes] == ["toy"]
    assert class_info(7, "midair")[0] == ("sky", "water", "trees", "land", "boulders", "road", "others")


@pytest.mark.parametrize(
    "name, kwargs, message",
    [
        ("bad name", {}, "dataset name must be an identifier"),
        (3, {}, "dataset name must be an identifier"),
        ("ok", {"classes": ("a", "b"), "palette": [[0, 0, 0]]}, r"palette must have shape \(2, 3\)"),
    ],
)
def test_register_refuses_bad_entries(name, kwargs, message):
    with pytest.raises(ConfigError, match=message):
        register_dataset(name, _open_toy, **kwargs)
    assert name not in DATASETS


def test_the_toy_is_an_entry_like_the_others():
    """No root, labels of the class count asked for, the reader's options checked by name, not offered where split
    files are needed (evaluate / predict / splits)."""
    ds = open_dataset("toy", None, seq_len=3, length=2, num_classes=4, seed=1)
    assert len(ds) == 2
    item = ds[1]
    assert item["rgb"].shape == (3, 3, 32, 32) and item["depth"].shape == (3, 1, 32, 32)  # the entry's default size
    assert 0 <= int(item["semantic"].min()) and int(item["semantic"].max()) <= 3
    assert open_dataset("toy", None, size=16, length=1)[0]["rgb"].shape == (1, 3, 16, 16)
    with pytest.raises(ConfigError, match=r"unknown option\(s\) \['colour'\] for dataset 'toy'"):
        open_dataset("toy", None, colour=1)
    assert "toy" not in split_datasets() and DATASETS["toy"].split_generator is None
    DatasetSource(name="toy").check("data.train[0]")
    assert "toy" not in dataset_classes()  # its class count is the model's


def test_unknown_dataset_names_the_registered_ones(tmp_path):
    with pytest.raises(ConfigError, match=r"unknown dataset 'kitti'; choose one of \('midair', .*'flight', 'toy'\)"):
        open_dataset("kitti", tmp_path)
