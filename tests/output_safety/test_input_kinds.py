"""The folders commands read as input are recognised by the markers their readers need, whoever wrote them; the
names in the table are the readers' and writers' own; what is not an input is not taken for one."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _input_folders import make_input_folders  # noqa: E402

from cosemdepth.output_safety import input_kinds  # noqa: E402
from cosemdepth.output_safety.input_kinds import INPUT_KINDS, InputKind, identify, register_input_kind  # noqa: E402


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    return make_input_folders(tmp_path_factory.mktemp("inputs"))


def test_every_kind_has_a_folder_written_by_its_writer(folders):
    # each test folder is recognised as its kind; together they cover the table (a SynthAir dataset: where
    # cosemdepth synth writes one, tests/synthair/test_synthair_writer.py)
    assert sorted(folders) == sorted(k.name for k in INPUT_KINDS if k.name != "a SynthAir dataset")
    for name, folder in folders.items():
        found = identify(folder)
        assert found is not None and found[0].name == name, (name, folder, found)


def _markers() -> set[str]:
    return {m.rstrip("/") for k in INPUT_KINDS for alt in k.markers for m in alt}


def test_the_markers_are_the_owners_names():
    from cosemdepth.checkpoints import model_io
    from cosemdepth.data import flight, topair_splits
    from cosemdepth.data.midair import format as fmt
    from cosemdepth.data.midair.splits import SPLITS
    from cosemdepth.data.registry import dataset_spec
    from cosemdepth.output_safety import manifest
    from cosemdepth.synthair import writer
    from cosemdepth.training import checkpoint, rundir

    markers = _markers()
    parts = {p for m in markers for p in m.split("/")}
    for name in (
        writer.METADATA,
        rundir.CONFIG_NAME,
        rundir.EVENTS_NAME,
        rundir.CHECKPOINTS_NAME,
        rundir.BEST_NAME,
        manifest.MANIFEST_FILE,
        checkpoint.WEIGHTS_FILE,
        model_io.CONFIG_FILE,
        model_io.WEIGHTS_FILE,
        fmt.SENSOR_RECORDS,
        topair_splits.REC_FILE,
        *flight.DEFAULT_POSE_FILES,
        *(f"{s}_data" for s in SPLITS),
    ):
        assert name in parts, name
    assert "ckpt-*" in parts and checkpoint.checkpoint_name(7).startswith("ckpt-")
    # the sub-folder that dataset roots open to `cosemdepth splits` is the registry's split folder
    opened = {sub for k in INPUT_KINDS for sub, cmd in k.open_inside if cmd == "splits"}
    assert opened == {dataset_spec("synthair").split_dir, dataset_spec("topair").split_dir} == {writer.SPLITS_DIR}
    # every image extension the flight reader takes counts as a flight's images, in any case
    import fnmatch

    image_globs = [
        m for k in INPUT_KINDS if k.name.startswith("a flight") for alt in k.markers for m in alt if m.startswith("*.")
    ]
    for ext in flight.IMAGE_EXTENSIONS:
        for name in (f"a{ext}", f"a{ext.upper()}"):
            assert any(fnmatch.fnmatchcase(name, g) for g in image_globs), name


def test_outputs_and_plain_folders_are_no_inputs(tmp_path):
    from cosemdepth.output_safety.outdir import write_marker

    assert identify(tmp_path) is None  # empty
    assert identify(tmp_path / "missing") is None
    pred = tmp_path / "pred"  # the layout of a predict output
    for sub in ("depth", "depth_png", "labels", "labels_color", "side_by_side"):
        (pred / sub / "SynthAir").mkdir(parents=True)
    np.save(pred / "depth" / "SynthAir" / "000004.npy", np.zeros((2, 2), np.float32))
    (pred / "predictions.json").write_text("{}")
    write_marker(pred, "predict", ["predictions.json"])
    assert identify(pred) is None
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "poses.txt").write_text("a pose file without images is no flight\n")
    assert identify(tmp_path / "notes") is None
    (tmp_path / "cfg").mkdir()
    (tmp_path / "cfg" / "config.yaml").write_text("a: 1\n")  # a config.yaml alone is no run
    assert identify(tmp_path / "cfg") is None


def test_a_folder_beside_a_dataset_part_is_not_that_dataset(folders):
    # a loose climate folder makes its parent look like an environment folder; seen as the ancestor of another
    # sub-folder, the parent is not taken for a dataset (a path into the climate folder still is)
    env = folders["part of a Mid-Air-format dataset"].parent
    assert identify(env)[0].name == "part of a Mid-Air-format dataset"
    assert identify(env, via="elsewhere") is None
    assert identify(env, via="sunny")[0].name == "part of a Mid-Air-format dataset"
    root = env.parent
    assert identify(root)[0].name == "a Mid-Air-format dataset"
    assert identify(root, via="splits") is None  # its split folder is a split folder of its own
    assert identify(root, via="Kite_training")[0].name == "a Mid-Air-format dataset"
    # markers directly in the folder count whatever the path
    assert identify(folders["a model folder"], via="anything")[0].name == "a model folder"


def test_a_new_reader_registers_its_layout(tmp_path, monkeypatch):
    monkeypatch.setattr(input_kinds, "INPUT_KINDS", list(INPUT_KINDS))
    (tmp_path / "ds" / "frames").mkdir(parents=True)
    (tmp_path / "ds" / "index.lst").write_text("x\n")
    assert identify(tmp_path / "ds") is None
    register_input_kind(InputKind("a FooAir dataset", (("frames/", "*.lst"),)))
    assert identify(tmp_path / "ds")[0].name == "a FooAir dataset"
    assert identify(tmp_path / "ds")[1] == "frames/ + *.lst"
