"""The output policy (cosemdepth.output_safety.outdir) through the real commands: outputs never replace, hold or lie inside an
input (resolved paths: symlinks, ``..``, relative paths), folders cosemdepth did not write are never replaced, a
command's own previous output is; damaged or non-finite models are refused on load; non-finite outputs stop a run
naming the frame and leave nothing behind."""

import json
import math
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "data"))
from _outputs import SIZE, _one_thread, data, leftovers, model_dir  # noqa: E402 (some are pytest fixtures)
from _writers import snapshot  # noqa: E402

from cosemdepth.cli.main import main  # noqa: E402
from cosemdepth.output_safety.outdir import MARKER  # noqa: E402


@pytest.fixture
def work(tmp_path, data, model_dir):
    """tmp/ds (a dataset root with splits/), tmp/model (a model folder); returns (tmp, ds, model)."""
    shutil.copytree(data, tmp_path / "ds")
    shutil.copytree(model_dir, tmp_path / "model")
    return tmp_path, tmp_path / "ds", tmp_path / "model"


def predict(ds, model, out, *extra):
    return main(
        [
            "predict",
            "--model",
            str(model),
            "--dataset",
            "midair",
            "--root",
            str(ds),
            "--split-dir",
            str(ds / "splits"),
            "--size",
            str(SIZE),
            "--video",
            "none",
            "--max-frames",
            "2",
            "--no-progress",
            "--out",
            str(out),
            *map(str, extra),
        ]
    )


def err_line(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize(
    "target, why",
    [
        ("ds", "is the --root"),  # the dataset folder itself (never deleted)
        (".", "contains the --model"),  # a folder above the inputs (model and dataset)
        ("model", "is the --model"),  # the model folder
        ("ds/splits", "lies inside the --root"),  # the split folder (also an input)
        ("ds/new", "lies inside the --root"),  # a new folder inside the dataset
        ("model/preds", "lies inside the --model"),
    ],
)
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
    os.symlink(ds, tmp / "alias")  # a symlink to the dataset
    assert predict(ds, model, tmp / "alias", "--overwrite") == 2
    assert "is the --root" in err_line(capsys)
    assert predict(ds, model, ds / "splits" / ".." / "..", "--overwrite") == 2  # .. above the inputs
    assert "contains the --model" in err_line(capsys)
    monkeypatch.chdir(tmp / "model")
    assert predict(ds, model, Path("..") / "ds", "--overwrite") == 2  # relative
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
    assert sorted(marker["files"]) == sorted(
        p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file() and p.name != MARKER
    )
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
    assert "my_notes.txt" in line and "not written by cosemdepth" in line
    assert (out / "my_notes.txt").read_text() == "mine" and (out / "predictions.json").is_file()


def test_another_commands_output_needs_overwrite(work, capsys):
    tmp, ds, model = work
    out = tmp / "metrics"
    assert (
        main(
            [
                "evaluate",
                "--model",
                str(model),
                "--dataset",
                "midair",
                "--root",
                str(ds),
                "--split-dir",
                str(ds / "splits"),
                "--size",
                str(SIZE),
                "--max-frames",
                "2",
                "--no-progress",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    capsys.readouterr()
    assert predict(ds, model, out) == 2
    assert "holds the output of `cosemdepth evaluate`" in err_line(capsys)
    assert predict(ds, model, out, "--overwrite") == 0
    assert json.loads((out / MARKER).read_text())["command"] == "predict" and not (out / "metrics.json").exists()


def test_evaluate_never_overwrites_a_file_it_did_not_write(work, capsys):
    tmp, ds, model = work
    args = [
        "evaluate",
        "--model",
        str(model),
        "--dataset",
        "midair",
        "--root",
        str(ds),
        "--split-dir",
        str(ds / "splits"),
        "--size",
        str(SIZE),
        "--max-frames",
        "2",
        "--no-progress",
        "--out",
    ]
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
    assert main(args + [str(out)]) == 0 and main(args + [str(out)]) == 0  # its own files are replaced


def test_other_commands_refuse_outputs_over_their_inputs(work, capsys, tmp_path):
    tmp, ds, model = work
    before = snapshot(tmp)
    cases = [
        (
            ["demo", "--out", str(ds), "--model", str(model), "--data-root", str(ds), "--overwrite"],
            "is the --data-root",
        ),
        (["demo", "--out", str(model), "--model", str(model), "--data-root", str(ds), "--overwrite"], "is the --model"),
        (["splits", "midair", str(ds), str(ds / "more")], "lies inside the ROOT"),
        (["splits", "midair", str(ds), str(tmp)], "contains the ROOT"),
        (
            [
                "train",
                "--config",
                "synthair-small",
                "--dataset",
                "midair",
                "--data-root",
                str(ds),
                "--split-dir",
                str(ds / "splits"),
                "--out",
                str(ds / "run"),
            ],
            "lies inside the data.train.0.root",
        ),
        (
            [
                "train",
                "--config",
                "synthair-small",
                "--dataset",
                "midair",
                "--data-root",
                str(ds),
                "--split-dir",
                str(ds / "splits"),
                "--out",
                str(tmp),
            ],
            "contains the data.train.0.root",
        ),
        (
            ["export", "--onnx", str(model / "m.onnx"), "--model", str(model), "--size", "32", "32"],
            "lies inside the --model",
        ),
        (["export", "--onnx", str(model / "model.safetensors"), "--model", str(model)], "lies inside the --model"),
        (["convert", str(model), str(model)], "is the TF_CHECKPOINT"),
    ]
    for argv, why in cases:
        assert main(argv) == 2, argv
        line = err_line(capsys)
        assert line.startswith(f"cosemdepth {argv[0]}: error: ") and why in line, (argv, line)
    assert snapshot(tmp) == before and leftovers(tmp) == []


# -------------------------------------------------------------------------- other commands' inputs, edited outputs


def _cli_cases(x: Path, ds: Path, model: Path) -> dict[str, list[str]]:
    """Every command with ``x`` as its output (the inputs: the work dataset and model, not ``x``)."""
    return {
        "predict": [
            "predict",
            "--model",
            str(model),
            "--dataset",
            "midair",
            "--root",
            str(ds),
            "--split-dir",
            str(ds / "splits"),
            "--size",
            str(SIZE),
            "--max-frames",
            "2",
            "--no-progress",
            "--out",
            str(x),
            "--overwrite",
        ],
        "demo": [
            "demo",
            "--model",
            str(model),
            "--data-root",
            str(ds),
            "--size",
            str(SIZE),
            "--no-progress",
            "--out",
            str(x),
            "--overwrite",
        ],
        "evaluate": [
            "evaluate",
            "--model",
            str(model),
            "--dataset",
            "midair",
            "--root",
            str(ds),
            "--split-dir",
            str(ds / "splits"),
            "--size",
            str(SIZE),
            "--max-frames",
            "2",
            "--no-progress",
            "--out",
            str(x),
        ],
        "train": [
            "train",
            "--config",
            "synthair-small",
            "--dataset",
            "midair",
            "--data-root",
            str(ds),
            "--split-dir",
            str(ds / "splits"),
            "--out",
            str(x),
        ],
        "export": ["export", "--onnx", str(x / "m.onnx"), "--model", str(model), "--size", "32", "32"],
        "splits": ["splits", "midair", str(ds), str(x)],
        "synth": [
            "synth",
            "--out",
            str(x),
            "--size",
            "32",
            "--frames",
            "16",
            "--trajectories",
            "1",
            "--climates",
            "sunny",
        ],
    }


def test_no_command_writes_over_or_into_another_commands_input(work, capsys):
    """Whoever wrote them (here: the project's own writers, rosbags, the test writers), datasets, split folders
    (with the marker `splits` leaves), models, checkpoints, runs, TF checkpoints, flights and bags are never
    another command's output, with or without --overwrite."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "output_safety"))
    from _input_folders import make_input_folders

    tmp, ds, model = work
    folders = make_input_folders(tmp / "inputs")
    before = snapshot(tmp)
    for kind, folder in folders.items():
        for x, relation in ((folder, "is"), (folder / "new", "lies inside")):
            cases = _cli_cases(x, ds, model)
            cases["convert"] = ["convert", str(folders["a TensorFlow checkpoint folder"]), str(x)]
            for name, argv in cases.items():
                if (name, kind, relation) in (
                    ("train", "a training run folder", "is"),
                    ("splits", "a split folder", "is"),
                ):
                    continue  # its own kind (resumed / replaced under the marker rules)
                if name == "export" and relation != "is":
                    continue  # an output file goes into an existing folder: x/m.onnx is the case
                if name == "convert" and ("TensorFlow" in kind or (kind, relation) == ("a model folder", "is")):
                    continue  # its input; its own kind
                assert main(argv) == 2, (name, kind, x)
                line = err_line(capsys)
                where = "lies inside" if name == "export" else relation
                assert line.startswith(f"cosemdepth {name}: error: {x if name != 'export' else x / 'm.onnx'}: ")
                assert f"{where} " in line and kind in line and "which commands read as input" in line, line
    assert snapshot(tmp) == before and leftovers(tmp) == []


def test_the_split_folder_of_another_dataset_is_never_replaced(work, capsys):
    tmp, ds, model = work
    other = tmp / "other"
    shutil.copytree(ds, other)  # its split folder carries the marker of `cosemdepth splits`
    assert json.loads((other / "splits" / MARKER).read_text())["command"] == "splits"
    before = snapshot(other)
    for argv in (_cli_cases(other / "splits", ds, model)["predict"], _cli_cases(other / "splits", ds, model)["demo"]):
        assert main(argv) == 2
        line = err_line(capsys)
        assert f"{other / 'splits'}: the --out folder is a split folder (test_data/)" in line
        assert "with or without --overwrite" in line
    assert snapshot(other) == before


def test_an_output_file_edited_since_is_the_users(work, capsys):
    from PIL import Image

    tmp, ds, model = work
    out = tmp / "out"
    assert predict(ds, model, out) == 0
    pj = out / "predictions.json"
    original = pj.read_bytes()
    pj.write_bytes(original.replace(b'"fps"', b'"FPS"'))  # same size: only the checksum tells
    for extra in ((), ("--overwrite",)):
        assert predict(ds, model, out, *extra) == 2
        line = err_line(capsys)
        assert f"{pj}: changed since cosemdepth predict wrote it" in line and "move it" in line
    assert b'"FPS"' in pj.read_bytes()
    pj.write_bytes(original)  # put back as it was written: ours again
    assert predict(ds, model, out) == 0
    label = next(out.rglob("labels/*.png"))
    px = np.array(Image.open(label))
    px[0, 0] = (int(px[0, 0]) + 1) % 7  # a hand-corrected pixel
    Image.fromarray(px).save(label)
    edited = label.read_bytes()
    assert predict(ds, model, out, "--overwrite") == 2
    assert f"{label}: changed since" in err_line(capsys) and label.read_bytes() == edited
    # evaluate's files likewise
    ev = [
        "evaluate",
        "--model",
        str(model),
        "--dataset",
        "midair",
        "--root",
        str(ds),
        "--split-dir",
        str(ds / "splits"),
        "--size",
        str(SIZE),
        "--max-frames",
        "2",
        "--no-progress",
        "--out",
        str(tmp / "ev"),
    ]
    assert main(ev) == 0
    (tmp / "ev" / "metrics.md").write_text("my notes on the metrics")
    capsys.readouterr()
    assert main(ev) == 2
    assert f"{tmp / 'ev' / 'metrics.md'}: changed since cosemdepth evaluate" in err_line(capsys)
    assert (tmp / "ev" / "metrics.md").read_text() == "my notes on the metrics" and leftovers(tmp) == []


def test_a_symlinked_or_permission_carrying_out_folder_stays(work, capsys):
    import stat

    tmp, ds, model = work
    target = tmp / "results"
    target.mkdir()
    os.symlink(target, tmp / "link")
    for _ in range(2):  # into the target, then replacing the previous output there
        assert predict(ds, model, tmp / "link") == 0
    assert (tmp / "link").is_symlink() and os.readlink(tmp / "link") == str(target)
    assert json.loads((target / "predictions.json").read_text())["frames_written"] == 2
    shared = tmp / "shared"
    shared.mkdir()
    gid = 4242 if os.geteuid() == 0 else os.getegid()
    os.chown(shared, -1, gid)
    os.chmod(shared, 0o2770)
    ino = shared.stat().st_ino
    for _ in range(2):  # empty, then its own previous output
        assert predict(ds, model, shared) == 0
        st = shared.stat()
        assert (st.st_ino, stat.S_IMODE(st.st_mode), st.st_gid) == (ino, 0o2770, gid)
        assert all(p.stat().st_gid == gid for p in shared.rglob("*"))
    old = os.umask(0o077)
    try:
        assert predict(ds, model, tmp / "private") == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp / "private").stat().st_mode) == 0o700
    assert stat.S_IMODE((tmp / "private" / "predictions.json").stat().st_mode) == 0o600
    assert leftovers(tmp) == [] and not [p for p in tmp.rglob(".cosemdepth-*") if p.name != MARKER]


def _csvs(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*.csv"))


def test_splits_again_with_another_rule_replaces_its_previous_output(work, capsys):
    tmp, ds, _ = work
    out = tmp / "splits"
    assert main(["splits", "synthair", str(ds), str(out), "--rule", "test"]) == 0
    assert _csvs(out) and all(c.startswith("test_data/") for c in _csvs(out))
    assert main(["splits", "synthair", str(ds), str(out), "--rule", "train"]) == 0
    captured = capsys.readouterr()
    assert "warning" not in captured.err
    assert _csvs(out) and all(c.startswith("train_data/") for c in _csvs(out))  # no test CSV left over
    assert not (out / "test_data").exists() and sorted(json.loads((out / MARKER).read_text())["files"]) == _csvs(out)
    # an edited CSV is the user's: refused, nothing changed
    csv = out / _csvs(out)[0]
    csv.write_text(csv.read_text() + "\n")  # a blank line at the end
    before = snapshot(out)
    assert main(["splits", "synthair", str(ds), str(out), "--rule", "test"]) == 2
    line = err_line(capsys)
    assert f"{csv}: changed since cosemdepth splits wrote it" in line and "move it" in line
    assert snapshot(out) == before
    # into the dataset's own split folder (the default), replacing what was there
    assert main(["splits", "synthair", str(ds), "--rule", "train"]) == 0
    assert all(c.startswith("train_data/") for c in _csvs(ds / "splits")) and leftovers(ds / "splits") == []


# ---------------------------------------------------------------------------------------------- model verification


def _checkpoint(tmp: Path) -> Path:
    """A real training checkpoint folder (with its manifest) of a tiny model."""
    from cosemdepth import build_model
    from cosemdepth.training.checkpoint import CheckpointManager, get_rng_state

    torch.manual_seed(0)
    model = build_model(arch="cosemdepth", levels=2)
    opt = torch.optim.Adam(model.parameters())
    return CheckpointManager(tmp / "run" / "checkpoints").save(
        model_state=model.state_dict(),
        model_config=model.config,
        optimizer_state=opt.state_dict(),
        trainer_state={"step": 3, "epoch": 0},
        rng_state=get_rng_state(),
    )


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
    from cosemdepth.checkpoints.model_io import read_model_files, save_weights

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
    from cosemdepth.checkpoints.model_io import read_model_files, save_weights

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
        "predict": [
            "predict",
            "--model",
            str(bad),
            "--dataset",
            "midair",
            "--root",
            str(ds),
            "--split-dir",
            str(ds / "splits"),
            "--size",
            str(SIZE),
            "--no-progress",
            "--out",
            str(tmp / "p"),
        ],
        "evaluate": [
            "evaluate",
            "--model",
            str(bad),
            "--dataset",
            "midair",
            "--root",
            str(ds),
            "--split-dir",
            str(ds / "splits"),
            "--size",
            str(SIZE),
            "--no-progress",
            "--out",
            str(tmp / "e"),
        ],
        "demo": [
            "demo",
            "--model",
            str(bad),
            "--data-root",
            str(ds),
            "--size",
            str(SIZE),
            "--no-progress",
            "--out",
            str(tmp / "d"),
        ],
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
    argv = [
        "export",
        "--onnx",
        str(out),
        "--arch",
        "m4semantic",
        "--levels",
        "1",
        "--classes",
        "3",
        "--size",
        "16",
        "16",
    ]
    assert main(argv) == 0 and main(argv) == 0  # the second run replaces the file the first one wrote
    props = {p.key for p in onnx.load(str(out)).metadata_props}
    assert "cosemdepth_export" in props
    capsys.readouterr()
    mine = tmp_path / "mine.onnx"
    onnx.save(onnx.load(str(out)).__class__(), str(mine))  # an ONNX file cosemdepth did not write
    before = mine.read_bytes()
    assert main(["export", "--onnx", str(mine), *argv[3:]]) == 2
    assert "not written by cosemdepth" in err_line(capsys) and mine.read_bytes() == before
    edited = onnx.load(str(out))  # the user edits cosemdepth's graph with onnx's tools: its metadata mark stays
    edited.doc_string = "my edited graph"
    onnx.save(edited, str(out))
    before = out.read_bytes()
    assert main(argv) == 2
    assert "changed since cosemdepth export wrote it" in err_line(capsys) and out.read_bytes() == before


def test_benchmark_replaces_its_reports_only_while_unchanged(tmp_path, capsys):
    j, md = tmp_path / "b.json", tmp_path / "b.md"
    argv = [
        "benchmark",
        "--models",
        "m4semantic",
        "--levels",
        "1",
        "--size",
        "16",
        "16",
        "--batch",
        "1",
        "--iters",
        "1",
        "--batched-iters",
        "1",
        "--warmup",
        "0",
        "--batched-warmup",
        "0",
        "--no-reference",
        "--no-joint",
        "--precision",
        "fp32",
        "--json",
        str(j),
        "--md",
        str(md),
    ]
    assert main(argv) == 0 and main(argv) == 0  # the second run replaces the reports the first one wrote
    capsys.readouterr()
    for path, edit in (
        (md, lambda t: t + "My note: checked by hand.\n"),  # the header line stays
        (j, lambda t: json.dumps({**json.loads(t), "note": "mine"})),
    ):  # still a benchmark report
        path.write_text(edit(path.read_text()))
        before = path.read_bytes()
        assert main(argv) == 2
        assert err_line(capsys).startswith(
            f"cosemdepth benchmark: error: {path}: the --{path.suffix[1:]} file exists "
            "and cannot be replaced: changed since cosemdepth benchmark wrote it"
        )
        assert path.read_bytes() == before
        path.unlink()  # moved away: the next run writes it again


def test_tensorflow_checkpoint_inputs(tmp_path, capsys):
    """A TF checkpoint prefix: its folder is the input when it holds a 'checkpoint' file, else its files are."""
    ck = tmp_path / "train"
    ck.mkdir()
    for name in ("checkpoint", "cp-0001.ckpt.index", "cp-0001.ckpt.data-00000-of-00001"):
        (ck / name).write_bytes(b"x")
    for out, why in (
        (ck / "converted", "lies inside the TF_CHECKPOINT"),
        (tmp_path, "contains the TF_CHECKPOINT"),
        (ck, "is the TF_CHECKPOINT"),
    ):
        assert main(["convert", str(ck / "cp-0001.ckpt"), str(out)]) == 2
        assert why in err_line(capsys)
    (ck / "checkpoint").unlink()
    assert main(["convert", str(ck / "cp-0001.ckpt"), str(ck / "cp-0001.ckpt.index")]) == 2
    assert "exists and is not a folder" in err_line(capsys)
    assert main(["convert", str(ck / "cp-0001.ckpt"), str(tmp_path)]) == 2
    assert "contains the TF_CHECKPOINT" in err_line(capsys)
    # nothing was written: only the files made above are there
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == [
        "train",
        "train/cp-0001.ckpt.data-00000-of-00001",
        "train/cp-0001.ckpt.index",
    ]
