"""The output policy's checks (cosemdepth.output_safety.outdir): no output over or inside a folder any command reads as input,
and a file is cosemdepth's to replace only while its content is what the marker records."""

import hashlib
import json
import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _input_folders import make_input_folders  # noqa: E402

from cosemdepth.errors import ConfigError  # noqa: E402
from cosemdepth.output_safety.input_kinds import INPUT_KINDS  # noqa: E402
from cosemdepth.output_safety.outdir import (  # noqa: E402
    MARKER,
    check_files_replaceable,
    check_output_dir,
    check_output_file,
    file_problem,
    read_marker,
    record_output_file,
    write_marker,
)

COMMANDS = ("predict", "demo", "evaluate", "splits", "convert", "synth", "train")
MODES = {
    "predict": "replace",
    "demo": "replace",
    "splits": "replace",
    "evaluate": "into",
    "convert": "into",
    "synth": "resume",
    "train": "resume",
}


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    return make_input_folders(tmp_path_factory.mktemp("inputs"))


def _check(out, command, **kw):
    return check_output_dir(out, command=command, mode=MODES[command], recognize=lambda p: True, **kw)


@pytest.mark.parametrize("command", COMMANDS)
def test_no_command_writes_over_or_into_another_commands_input(folders, command):
    writers = {k.name: k.writers for k in INPUT_KINDS}
    for name, folder in folders.items():
        before = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))
        for out, relation in ((folder, "is"), (folder / "new", "lies inside"), (folder / "a" / "b", "lies inside")):
            if relation == "is" and command in writers[name]:
                continue  # its own kind: resumed / replaced under the marker rules
            with pytest.raises(ConfigError) as e:
                _check(out, command, overwrite=True)
            msg = str(e.value)
            assert msg.startswith(f"{out}: ") and name in msg and relation in msg, msg
            assert "\n" not in msg and "which commands read as input" in msg
            if relation == "lies inside":
                assert str(folder) in msg
        assert sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*")) == before


def test_a_kind_opens_only_its_split_folder_to_splits(folders, tmp_path):
    root = folders["a Mid-Air-format dataset"]
    assert check_output_dir(root / "splits", command="splits", mode="replace", overwrite=None) is True
    with pytest.raises(ConfigError, match="lies inside .*a Mid-Air-format dataset"):
        check_output_dir(root / "splits2", command="splits", mode="replace")
    # a symlink to an input folder is that folder
    os.symlink(folders["a model folder"], tmp_path / "alias")
    with pytest.raises(ConfigError, match=f"is a model folder .*{folders['a model folder']}"):
        check_output_dir(tmp_path / "alias", command="predict", overwrite=True)
    # output files: never inside an input folder
    with pytest.raises(ConfigError, match="lies inside .*a training checkpoint"):
        check_output_file(folders["a training checkpoint"] / "m.onnx", what="--onnx file")
    with pytest.raises(ConfigError, match="lies inside .*a split folder"):
        check_output_file(root / "splits" / "test_data" / "x.json", what="--json file")
    check_output_file(tmp_path / "m.onnx", what="--onnx file")
    # an existing file in a dataset root is looked at as a new one would be (the root known by its sub-folders)
    for name in ("new.onnx", "old.onnx"):
        if name == "old.onnx":
            (root / name).write_bytes(b"x")
        with pytest.raises(ConfigError, match=f"lies inside {root}, a Mid-Air-format dataset"):
            check_output_file(root / name, what="--onnx file")
    (root / "old.onnx").unlink()


def test_the_marker_records_size_and_sha256_of_every_file(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "a.bin").write_bytes(b"\x00\x01" * 1000)
    (tmp_path / "b.txt").write_text("hello")
    write_marker(tmp_path, "predict", ["sub/a.bin", "b.txt"])
    data = json.loads((tmp_path / MARKER).read_text())
    assert data["version"] == 3 and data["command"] == "predict"
    assert data["files"] == {
        "b.txt": {"size": 5, "sha256": hashlib.sha256(b"hello").hexdigest(), "command": "predict"},
        "sub/a.bin": {"size": 2000, "sha256": hashlib.sha256(b"\x00\x01" * 1000).hexdigest(), "command": "predict"},
    }
    assert file_problem(tmp_path, "b.txt", read_marker(tmp_path)) is None


def test_a_changed_file_is_the_users(tmp_path):
    f = tmp_path / "labels.png"
    f.write_bytes(b"abcdef")
    write_marker(tmp_path, "predict", ["labels.png"])
    marker = read_marker(tmp_path)
    st = f.stat()
    f.write_bytes(b"abcdeF")  # same size, same times: only the content tells
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert "changed since cosemdepth predict wrote it" in file_problem(tmp_path, "labels.png", marker)
    with pytest.raises(ConfigError, match=f"{f}: changed since cosemdepth predict wrote it.*move it"):
        check_files_replaceable(tmp_path, ["labels.png"])
    f.write_bytes(b"abcdef")  # put back as written: ours again
    assert file_problem(tmp_path, "labels.png", marker) is None
    f.unlink()
    os.symlink(tmp_path / "elsewhere", f)
    assert "a link" in file_problem(tmp_path, "labels.png", marker)
    assert "not listed" in file_problem(tmp_path, "other.png", marker)


def test_a_marker_without_checksums_proves_nothing(tmp_path):
    (tmp_path / "predictions.json").write_text("{}")
    (tmp_path / MARKER).write_text(
        json.dumps({"format": "cosemdepth-output", "command": "predict", "files": ["predictions.json"]})
    )
    with pytest.raises(ConfigError, match="predictions.json: listed in .* without a checksum"):
        check_output_dir(tmp_path, command="predict")


def test_replacing_a_folder_needs_every_file_unchanged(tmp_path):
    out = tmp_path / "out"
    (out / "depth").mkdir(parents=True)
    for name in ("depth/1.npy", "depth/2.npy", "predictions.json"):
        (out / name).write_text(name)
    write_marker(out, "predict", ["depth/1.npy", "depth/2.npy", "predictions.json"])
    assert check_output_dir(out, command="predict") is True
    (out / "depth" / "2.npy").unlink()  # a file removed since: nothing of the user's is lost
    assert check_output_dir(out, command="predict") is True
    (out / "predictions.json").write_text("edited")
    with pytest.raises(ConfigError, match=f"{out / 'predictions.json'}: changed since"):
        check_output_dir(out, command="predict", overwrite=True)
    (out / "predictions.json").write_text("predictions.json")
    (out / "depth" / "mine.txt").write_text("x")
    with pytest.raises(ConfigError, match=f"{out / 'depth' / 'mine.txt'}: not written by cosemdepth"):
        check_output_dir(out, command="predict")
    (out / "depth" / "mine.txt").unlink()
    with pytest.raises(ConfigError, match="holds the output of `cosemdepth predict`.*pass --overwrite"):
        check_output_dir(out, command="demo")
    with pytest.raises(ConfigError) as e:  # splits has no --overwrite: the message does not offer it
        check_output_dir(out, command="splits", overwrite=None)
    assert "--overwrite" not in str(e.value)
    assert check_output_dir(out, command="demo", overwrite=True) is True


def test_another_commands_output_never_takes_an_input_folder_with_it(tmp_path, folders):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(folders["a ROS 2 bag"], out / "bag")  # as predict --bag writes it, listed in the marker
    write_marker(out, "predict", [p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()])
    assert check_output_dir(out, command="predict") is True  # predict replaces its own output, bag and all
    with pytest.raises(ConfigError, match=f"holds {out / 'bag'}, a ROS 2 bag"):
        check_output_dir(out, command="demo", overwrite=True)


def test_a_single_output_file_is_replaced_only_while_its_recorded_content_is_unchanged(tmp_path):
    """``export --onnx``, ``benchmark --json/--md``, ``--rrd``: the file's checksum is recorded in its folder's marker
    when written; an edit that keeps the file recognisable (a note added under a report's header) makes it the
    user's."""
    from cosemdepth.output_safety.outdir import record_output_file

    report = tmp_path / "benchmark.md"
    report.write_text("Measured on a CPU, PyTorch 2\n| a | b |\n")
    looks_ours = lambda p: p.read_text().startswith("Measured ")  # noqa: E731 - what the command recognises
    with pytest.raises(
        ConfigError,
        match=rf"^{report}: the --md file exists and cannot be replaced: not written by "
        rf"cosemdepth \(no {MARKER} in {tmp_path}\); nothing was overwritten",
    ):
        check_output_file(report, what="--md file", recognize=looks_ours)  # written by nobody we know of
    record_output_file(report, "benchmark")
    assert read_marker(tmp_path)["files"]["benchmark.md"] == {
        "size": report.stat().st_size,
        "sha256": hashlib.sha256(report.read_bytes()).hexdigest(),
        "command": "benchmark",
    }
    check_output_file(report, what="--md file", recognize=looks_ours)  # ours and unchanged: may be replaced
    with open(report, "a") as f:
        f.write("My note: checked by hand.\n")  # still starts as the command's reports do
    with pytest.raises(
        ConfigError,
        match=rf"{report}: the --md file exists and cannot be replaced: changed since "
        "cosemdepth benchmark wrote it",
    ):
        check_output_file(report, what="--md file", recognize=looks_ours)
    link = tmp_path / "link.md"  # a symlink names where to write: its target's record decides
    os.symlink(report, link)
    with pytest.raises(ConfigError, match="changed since"):
        check_output_file(link, what="--md file")
    with pytest.raises(ConfigError, match=f"{MARKER} is the name of cosemdepth's output record"):
        check_output_file(tmp_path / MARKER, what="--json file")


def test_recording_a_file_keeps_the_folders_marker_and_its_other_entries(tmp_path):
    from cosemdepth.output_safety.outdir import record_output_file

    (tmp_path / "predictions.json").write_text("{}")
    write_marker(tmp_path, "predict", ["predictions.json"])
    (tmp_path / "m.onnx").write_bytes(b"graph")
    record_output_file(tmp_path / "m.onnx", "export")
    marker = read_marker(tmp_path)
    assert marker["command"] == "predict"  # the folder stays predict's output
    assert sorted(marker["files"]) == ["m.onnx", "predictions.json"]
    assert file_problem(tmp_path, "m.onnx", marker) is None
    # each file names the command that wrote it: a refusal names the right one
    assert {f: e["command"] for f, e in marker["files"].items()} == {"m.onnx": "export", "predictions.json": "predict"}
    (tmp_path / "m.onnx").write_bytes(b"graph, edited")
    (tmp_path / "predictions.json").write_text('{"edited": true}')
    assert file_problem(tmp_path, "m.onnx", marker).startswith("changed since cosemdepth export wrote it")
    assert file_problem(tmp_path, "predictions.json", marker).startswith("changed since cosemdepth predict wrote it")
    with pytest.raises(
        ConfigError,
        match=r"m.onnx: the --onnx file exists and cannot be replaced: changed since "
        "cosemdepth export wrote it",
    ):
        check_output_file(tmp_path / "m.onnx", what="--onnx file")


def test_a_marker_of_an_older_cosemdepth_names_the_folder_s_command_for_its_files(tmp_path):
    (tmp_path / "a.txt").write_text("a")
    write_marker(tmp_path, "predict", ["a.txt"])
    data = json.loads((tmp_path / MARKER).read_text())
    del data["files"]["a.txt"]["command"]  # as cosemdepth wrote markers before files named their command
    (tmp_path / MARKER).write_text(json.dumps(data))
    (tmp_path / "b.rrd").write_bytes(b"rrd")
    record_output_file(tmp_path / "b.rrd", "view")  # the old entry keeps the folder's command
    marker = read_marker(tmp_path)
    assert {f: e["command"] for f, e in marker["files"].items()} == {"a.txt": "predict", "b.rrd": "view"}
