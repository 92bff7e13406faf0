"""The output policy (cosemdepth.io.outdir) through the real commands: outputs never replace, hold or lie inside an
input (resolved paths: symlinks, ``..``, relative paths), folders cosemdepth did not write are never replaced, a
command's own previous output is; damaged or non-finite models are refused on load; non-finite outputs stop a run
naming the frame and leave nothing behind."""

import json
import math
import os
import shutil
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "data"))
from _outputs import SIZE, leftovers, tiny_model  # noqa: E402
from _outputs import _one_thread, data, model_dir  # noqa: E402, F401 (pytest fixtures)
from _writers import snapshot  # noqa: E402

from cosemdepth.cli.main import main  # noqa: E402
from cosemdepth.io.outdir import MARKER  # noqa: E402


@pytest.fixture
def work(tmp_path, data, model_dir):
    """tmp/ds (a dataset root with splits/), tmp/model (a model folder); returns (tmp, ds, model)."""
    shutil.copytree(data, tmp_path / "ds")
    shutil.copytree(model_dir, tmp_path / "model")
    return tmp_path, tmp_path / "ds", tmp_path / "model"


def predict(ds, model, out, *extra):
    return main(["predict", "--model", str(model), "--dataset", "midair", "--root", str(ds), "--split-dir",
                 str(ds / "splits"), "--size", str(SIZE), "--video", "none", "--max-frames", "2", "--no-progress",
                 "--out", str(out), *map(str, extra)])


def err_line(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("target, why", [
    ("ds", "is the --root"),                  # the dataset folder itself (issue 9: deleted the inputs)
    (".", "contains the --model"),           # a folder above the inputs (model and dataset)
    ("model", "is the --model"),             # the model folder
    ("ds/splits", "lies inside the --root"),  # the split folder (also an input)
    ("ds/new", "lies inside the --root"),    # a new folder inside the dataset
    ("model/preds", "lies inside the --model"),
])
def test_predict_never_writes_into_or_over_its_inputs(work, capsys, target, why):
    tmp, ds, model = work
    before = snapshot(tmp)
    out = tmp / target if target != "." else tmp
    assert predict(ds, model, out, "--overwrite") == 2
    line = err_line(capsys)
    assert line.startswith("cosemdepth predict: error: ") and why in line and str(out) in line
    assert snapshot(tmp) == before and leftovers(tmp) == []


def test_aliases_of_an_input_are_recognised(work, capsys, monkeypatch):
    tmp, ds, model = work
    before = snapshot(ds)
    os.symlink(ds, tmp / "alias")                       # a symlink to the dataset
    assert predict(ds, model, tmp / "alias", "--overwrite") == 2
    assert "is the --root" in err_line(capsys)
    assert predict(ds, model, ds / "splits" / ".." / "..", "--overwrite") == 2   # .. above the inputs
    assert "contains the --model" in err_line(capsys)
    monkeypatch.chdir(tmp / "model")
    assert predict(ds, model, Path("..") / "ds", "--overwrite") == 2                 # relative
    assert "is the --root" in err_line(capsys)
    assert snapshot(ds) == before


def test_a_folder_of_the_users_own_files_is_never_replaced(work, capsys):
    tmp, ds, model = work
    mine = tmp / "mine"
    (mine / "sub").mkdir(parents=True)
    (mine / "sub" / "notes.txt").write_text("mine")
    for extra in ((), ("--overwrite",)):
        assert predict(ds, model, mine, *extra) == 2
        line = err_line(capsys)
        assert str(mine) in line and "not written by cosemdepth" in line
    assert (mine / "sub" / "notes.txt").read_text() == "mine" and len(list(mine.rglob("*"))) == 2
    # a damaged marker does not make it ours
    (mine / MARKER).write_text("{not json")
    assert predict(ds, model, mine, "--overwrite") == 2
    assert "not written by cosemdepth" in err_line(capsys)


def test_rerun_into_its_own_output_replaces_it(work, capsys):
    tmp, ds, model = work
    out = tmp / "out"
    assert predict(ds, model, out) == 0
    marker = json.loads((out / MARKER).read_text())
    assert marker["command"] == "predict" and "predictions.json" in marker["files"]
    assert sorted(marker["files"]) == sorted(p.relative_to(out).as_posix() for p in out.rglob("*")
                                             if p.is_file() and p.name != MARKER)
    (out / "depth" / "stale.npy").parent.mkdir(exist_ok=True)
    first = (out / "predictions.json").read_text()
    for extra in ((), ("--overwrite",)):
        assert predict(ds, model, out, *extra) == 0
        assert json.loads((out / "predictions.json").read_text())["frames_written"] == 2
    assert json.loads(first)["frames_written"] == 2 and leftovers(tmp) == []
    # a file the user adds to the output makes it no longer entirely ours: refused, the file kept
    (out / "my_notes.txt").write_text("mine")
    assert predict(ds, model, out, "--overwrite") == 2
    line = err_line(capsys)
    assert "my_notes.txt" in line and "did not write" in line
    assert (out / "my_notes.txt").read_text() == "mine" and (out / "predictions.json").is_file()


def test_another_commands_output_needs_overwrite(work, capsys):
    tmp, ds, model = work
    out = tmp / "metrics"
    assert main(["evaluate", "--model", str(model), "--dataset", "midair", "--root", str(ds), "--split-dir",
                 str(ds / "splits"), "--size", str(SIZE), "--max-frames", "2", "--no-progress", "--out",
                 str(out)]) == 0
    capsys.readouterr()
    assert predict(ds, model, out) == 2
    assert "holds the output of `cosemdepth evaluate`" in err_line(capsys)
    assert predict(ds, model, out, "--overwrite") == 0
    assert json.loads((out / MARKER).read_text())["command"] == "predict" and not (out / "metrics.json").exists()


def test_evaluate_never_overwrites_a_file_it_did_not_write(work, capsys):
    tmp, ds, model = work
    args = ["evaluate", "--model", str(model), "--dataset", "midair", "--root", str(ds), "--split-dir",
            str(ds / "splits"), "--size", str(SIZE), "--max-frames", "2", "--no-progress", "--out"]
    mine = tmp / "report"
    mine.mkdir()
    (mine / "metrics.json").write_text("my own")
    assert main(args + [str(mine)]) == 2
    line = err_line(capsys)
    assert str(mine / "metrics.json") in line and "not written by cosemdepth" in line
    assert (mine / "metrics.json").read_text() == "my own" and sorted(os.listdir(mine)) == ["metrics.json"]
    assert main(args + [str(ds)]) == 2 and "is the --root" in err_line(capsys)
    assert main(args + [str(model / "eval")]) == 2 and "lies inside the --model" in err_line(capsys)
    out = tmp / "ok"
    assert main(args + [str(out)]) == 0 and main(args + [str(out)]) == 0   # its own files are replaced


def test_other_commands_refuse_outputs_over_their_inputs(work, capsys, tmp_path):
    tmp, ds, model = work
    before = snapshot(tmp)
    cases = [
        (["demo", "--out", str(ds), "--model", str(model), "--data-root", str(ds), "--overwrite"], "is the --data-root"),
        (["demo", "--out", str(model), "--model", str(model), "--data-root", str(ds), "--overwrite"], "is the --model"),
        (["splits", "midair", str(ds), str(ds / "more")], "lies inside the ROOT"),
        (["splits", "midair", str(ds), str(tmp)], "contains the ROOT"),
        (["train", "--config", "synthair-small", "--dataset", "midair", "--data-root", str(ds), "--split-dir",
          str(ds / "splits"), "--out", str(ds / "run")], "lies inside the data.train.0.root"),
        (["train", "--config", "synthair-small", "--dataset", "midair", "--data-root", str(ds), "--split-dir",
          str(ds / "splits"), "--out", str(tmp)], "contains the data.train.0.root"),
        (["export", "--onnx", str(model / "m.onnx"), "--model", str(model), "--size", "32", "32"],
         "lies inside the --model"),
        (["export", "--onnx", str(model / "model.safetensors"), "--model", str(model)], "lies inside the --model"),
        (["convert", str(model), str(model)], "is the TF_CHECKPOINT"),
    ]
    for argv, why in cases:
        assert main(argv) == 2, argv
        line = err_line(capsys)
        assert line.startswith(f"cosemdepth {argv[0]}: error: ") and why in line, (argv, line)
    assert snapshot(tmp) == before and leftovers(tmp) == []


# ---------------------------------------------------------------------------------------------- model verification


def _checkpoint(tmp: Path) -> Path:
    """A real training checkpoint folder (with its manifest) of a tiny model."""
    from cosemdepth import build_model
    from cosemdepth.training.checkpoint import CheckpointManager, get_rng_state

    torch.manual_seed(0)
    model = build_model(arch="cosemdepth", levels=2)
    opt = torch.optim.Adam(model.parameters())
    return CheckpointManager(tmp / "run" / "checkpoints").save(
        model_state=model.state_dict(), model_config=model.config, optimizer_state=opt.state_dict(),
        trainer_state={"step": 3, "epoch": 0}, rng_state=get_rng_state())


def test_a_damaged_checkpoint_is_refused_naming_the_file(work, capsys):
    from cosemdepth import load_model
    from cosemdepth.errors import CheckpointError

    tmp, ds, _ = work
    ckpt = _checkpoint(tmp)
    load_model(ckpt)  # intact: loads
    weights = ckpt / "model.safetensors"
    raw = bytearray(weights.read_bytes())
    raw[-100] ^= 0x40  # one flipped bit in the tensor data: still a readable safetensors file
    weights.write_bytes(bytes(raw))
    with pytest.raises(CheckpointError, match=f"{weights}: checksum mismatch"):
        load_model(ckpt)
    assert predict(ds, ckpt, tmp / "out") == 2
    line = err_line(capsys)
    assert str(weights) in line and "checksum mismatch" in line and not (tmp / "out").exists()
    weights.write_bytes(bytes(raw[: len(raw) // 2]))  # truncated
    with pytest.raises(CheckpointError, match=f"{weights}: .* bytes, the manifest says"):
        load_model(ckpt)


def test_a_model_with_nan_weights_is_refused(work, capsys):
    from cosemdepth.io.model_io import read_model_files, save_weights

    tmp, ds, model = work
    sd, cfg, _ = read_model_files(model)
    sd["encoder.dinl.bias"] = sd["encoder.dinl.bias"].clone().fill_(math.nan)
    save_weights(sd, cfg, tmp / "nan")
    assert predict(ds, tmp / "nan", tmp / "out") == 2
    line = err_line(capsys)
    assert str(tmp / "nan" / "model.safetensors") in line and "NaN/inf" in line and "encoder.dinl.bias" in line
    assert not (tmp / "out").exists()


def _exploding_model(tmp: Path, model: Path) -> Path:
    """Finite weights (they pass the load checks) whose semantic decoder overflows to inf/NaN (biases near the
    float32 maximum: sums of them overflow)."""
    from cosemdepth.io.model_io import read_model_files, save_weights

    sd, cfg, _ = read_model_files(model)
    for k in sd:
        if k.startswith("semantic_decoder.") and k.endswith("bias"):
            sd[k] = torch.full_like(sd[k], 3e38)
    return save_weights(sd, cfg, tmp / "explode")


def test_non_finite_outputs_stop_every_runner_naming_the_frame(work, capsys):
    tmp, ds, model = work
    bad = _exploding_model(tmp, model)
    before = snapshot(tmp)
    first_image = "Kite_training/sunny/color_left/trajectory_0000/000004.JPEG"  # the first CSV row: frame 4
    runs = {
        "predict": ["predict", "--model", str(bad), "--dataset", "midair", "--root", str(ds), "--split-dir",
                    str(ds / "splits"), "--size", str(SIZE), "--no-progress", "--out", str(tmp / "p")],
        "evaluate": ["evaluate", "--model", str(bad), "--dataset", "midair", "--root", str(ds), "--split-dir",
                     str(ds / "splits"), "--size", str(SIZE), "--no-progress", "--out", str(tmp / "e")],
        "demo": ["demo", "--model", str(bad), "--data-root", str(ds), "--size", str(SIZE), "--no-progress",
                 "--out", str(tmp / "d")],
    }
    for name, argv in runs.items():
        assert main(argv) == 2, name
        err = capsys.readouterr().err
        line = [x for x in err.strip().splitlines() if "error:" in x]
        assert "Traceback" not in err and len(line) == 1, err
        assert f"cosemdepth {name}: error: " in line[0] and "semantic output holds NaN/inf" in line[0]
        assert "dataset row 0" in line[0] and first_image in line[0], line[0]
    assert snapshot(tmp) == before and leftovers(tmp) == []


def test_export_replaces_only_its_own_onnx_file(tmp_path, capsys):
    import onnx

    out = tmp_path / "m.onnx"
    argv = ["export", "--onnx", str(out), "--arch", "m4semantic", "--levels", "1", "--classes", "3", "--size",
            "16", "16"]
    assert main(argv) == 0 and main(argv) == 0  # the second run replaces the file the first one wrote
    props = {p.key for p in onnx.load(str(out)).metadata_props}
    assert "cosemdepth_export" in props
    capsys.readouterr()
    mine = tmp_path / "mine.onnx"
    onnx.save(onnx.load(str(out)).__class__(), str(mine))  # an ONNX file cosemdepth did not write
    before = mine.read_bytes()
    assert main(["export", "--onnx", str(mine), *argv[3:]]) == 2
    assert "was not written by cosemdepth" in err_line(capsys) and mine.read_bytes() == before


def test_tensorflow_checkpoint_inputs(tmp_path, capsys):
    """A TF checkpoint prefix: its folder is the input when it holds a 'checkpoint' file, else its files are."""
    ck = tmp_path / "train"
    ck.mkdir()
    for name in ("checkpoint", "cp-0001.ckpt.index", "cp-0001.ckpt.data-00000-of-00001"):
        (ck / name).write_bytes(b"x")
    for out, why in ((ck / "converted", "lies inside the TF_CHECKPOINT"), (tmp_path, "contains the TF_CHECKPOINT"),
                     (ck, "is the TF_CHECKPOINT")):
        assert main(["convert", str(ck / "cp-0001.ckpt"), str(out)]) == 2
        assert why in err_line(capsys)
    (ck / "checkpoint").unlink()
    assert main(["convert", str(ck / "cp-0001.ckpt"), str(ck / "cp-0001.ckpt.index")]) == 2
    assert "exists and is not a folder" in err_line(capsys)
    assert main(["convert", str(ck / "cp-0001.ckpt"), str(tmp_path)]) == 2
    assert "contains the TF_CHECKPOINT" in err_line(capsys)
    # nothing was written: only the files made above are there
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == [
        "train", "train/cp-0001.ckpt.data-00000-of-00001", "train/cp-0001.ckpt.index"]
