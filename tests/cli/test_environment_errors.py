"""A broken environment through the real command line, as a user meets it: an optional package that is not
installed (the import is blocked in a fresh interpreter by a ``sitecustomize`` module), an output folder that cannot
be written. Each is one error line and exit 2, found before the model runs, and nothing is left behind."""

import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "data"))
from _outputs import SIZE, _one_thread, data, leftovers, model_dir, unwritable_folder  # noqa: E402 (some are pytest fixtures)

import cosemdepth.jobs.predict as predict_job  # noqa: E402
from cosemdepth.cli.main import main  # noqa: E402

SRC = Path(__file__).resolve().parents[2] / "src"

#: Imported first by the interpreter (``site``): every module named in BLOCK_MODULES cannot be imported, as if its
#: package were not installed (``import x`` raises ModuleNotFoundError when ``sys.modules["x"]`` is None).
SITECUSTOMIZE = """\
import os, sys
for name in os.environ.get("BLOCK_MODULES", "").split(","):
    if name:
        sys.modules[name] = None
"""


def cli_without(tmp_path: Path, blocked: str, *argv) -> subprocess.CompletedProcess:
    """``python -m cosemdepth ARGV`` in a fresh interpreter where the module ``blocked`` cannot be imported."""
    hook = tmp_path / "hook"
    hook.mkdir(exist_ok=True)
    (hook / "sitecustomize.py").write_text(SITECUSTOMIZE)
    env = {"PYTHONPATH": f"{hook}:{SRC}", "PATH": "/usr/bin:/bin", "OMP_NUM_THREADS": "1", "BLOCK_MODULES": blocked}
    return subprocess.run(
        [sys.executable, "-m", "cosemdepth", *map(str, argv)], capture_output=True, text=True, env=env, timeout=300
    )


def test_the_hook_really_blocks_the_import(tmp_path):
    """The simulation is real: onnx is installed here, and the hook makes its import fail."""
    import onnx  # noqa: F401

    r = cli_without(tmp_path, "onnx", "--help")
    assert r.returncode == 0
    hook_env = {"PYTHONPATH": f"{tmp_path / 'hook'}:{SRC}", "BLOCK_MODULES": "onnx", "PATH": "/usr/bin:/bin"}
    probe = subprocess.run([sys.executable, "-c", "import onnx"], capture_output=True, text=True, env=hook_env)
    assert probe.returncode == 1 and "ModuleNotFoundError" in probe.stderr


@pytest.mark.parametrize(
    "blocked, extra, message",
    [
        ("onnx", (), "export needs the Python package onnx, which is not installed; pip install 'cosemdepth[export]'"),
        (
            "onnxruntime",
            ("--check",),
            "export --check needs the Python package onnxruntime, which is not installed; "
            "pip install 'cosemdepth[export]'",
        ),
    ],
)
def test_export_without_onnx_or_onnxruntime_writes_nothing(tmp_path, blocked, extra, message):
    out = tmp_path / "out"
    out.mkdir()
    r = cli_without(
        tmp_path,
        blocked,
        "export",
        "--onnx",
        out / "m.onnx",
        "--arch",
        "m4semantic",
        "--levels",
        2,
        "--size",
        16,
        24,
        *extra,
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip().splitlines() == [f"cosemdepth export: error: {message} (or pip install {blocked})"]
    assert list(out.iterdir()) == []


def test_view_and_predict_rerun_without_rerun_sdk_write_nothing(tmp_path, data, model_dir):
    split = ["--dataset", "midair", "--root", data, "--split-dir", data / "splits", "--size", SIZE, "--no-progress"]
    out = tmp_path / "out"
    out.mkdir()
    for argv in (
        ["view", "--model", model_dir, *split, "--rrd", out / "v.rrd"],
        ["predict", "--model", model_dir, *split, "--out", out / "p", "--rerun", out / "p.rrd"],
    ):
        r = cli_without(tmp_path, "rerun", *argv)
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and "needs the Python package rerun-sdk, which is not installed" in lines[0], lines
        assert list(out.iterdir()) == []


def test_predict_and_benchmark_onnxruntime_backend_without_onnxruntime_write_nothing(tmp_path, data, model_dir):
    split = ["--dataset", "midair", "--root", data, "--split-dir", data / "splits", "--size", SIZE, "--no-progress"]
    graph = tmp_path / "m.onnx"
    graph.write_bytes(b"not read: the package check comes first")
    out = tmp_path / "out"
    out.mkdir()
    for argv, what in (
        (
            ["predict", "--model", model_dir, *split, "--out", out / "p", "--backend", "onnxruntime", "--onnx", graph],
            "predict",
        ),
        (
            [
                "benchmark",
                "--backend",
                "onnxruntime",
                "--models",
                "m4depth",
                "--levels",
                2,
                "--size",
                16,
                16,
                "--batch",
                1,
                "--json",
                out / "b.json",
                "--md",
                out / "b.md",
            ],
            "benchmark",
        ),
    ):
        r = cli_without(tmp_path, "onnxruntime", *argv)
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        lines = r.stderr.strip().splitlines()
        assert lines == [
            f"cosemdepth {what}: error: {what} --backend onnxruntime needs the Python package "
            "onnxruntime, which is not installed; pip install 'cosemdepth[export]' (or pip install "
            "onnxruntime)"
        ], lines
        assert list(out.iterdir()) == []


def test_predict_bag_without_rosbags_writes_nothing(tmp_path, model_dir):
    bag = tmp_path / "flight_bag"
    bag.mkdir()
    out = tmp_path / "out"
    r = cli_without(
        tmp_path,
        "rosbags",
        "predict",
        "--model",
        model_dir,
        "--bag",
        bag,
        "--image-topic",
        "/cam",
        "--pose-topic",
        "/odom",
        "--hfov",
        90,
        "--out",
        out,
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "needs the Python package rosbags, which is not installed" in lines[0], lines
    assert not out.exists() and leftovers(tmp_path) == []


def test_out_in_a_read_only_folder_is_refused_before_the_model_runs(tmp_path, data, model_dir, capsys, monkeypatch):
    """A new ``--out`` in a folder that cannot be written: one line naming the folder, the model is never loaded, and
    no staging folder is left."""
    parent = tmp_path / "ro"
    parent.mkdir()
    out = parent / "preds"

    def no_model(*a, **k):
        raise AssertionError("the model was loaded")

    monkeypatch.setattr(predict_job, "load_for", no_model)
    with unwritable_folder(parent):
        assert main(["predict", "--model", str(model_dir), *_split(data), "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err
        assert err.startswith(f"cosemdepth predict: error: {out}: cannot write the --out folder here ({parent}: ")
        assert list(parent.iterdir()) == []
    assert leftovers(parent) == [] and leftovers(tmp_path) == []


def test_a_previous_output_in_a_read_only_folder_is_replaced_in_place(tmp_path, data, model_dir, capsys):
    """The contents of ``--out`` are replaced, not the folder: a previous output inside a folder that cannot be written
    is replaced (the folder keeps its inode) and nothing is left beside it."""
    parent = tmp_path / "ro"
    parent.mkdir()
    out = parent / "preds"
    assert main(["predict", "--model", str(model_dir), *_split(data), "--out", str(out)]) == 0
    inode = out.stat().st_ino
    with unwritable_folder(parent):
        assert main(["predict", "--model", str(model_dir), *_split(data), "--out", str(out)]) == 0
        assert sorted(p.name for p in parent.iterdir()) == ["preds"]
    assert out.stat().st_ino == inode and (out / "predictions.json").is_file()
    assert leftovers(parent) == [] and leftovers(tmp_path) == []


def _split(data):
    return [
        "--dataset",
        "midair",
        "--root",
        str(data),
        "--split-dir",
        str(data / "splits"),
        "--size",
        str(SIZE),
        "--no-progress",
        "--video",
        "none",
        "--max-frames",
        "2",
    ]


def test_a_library_os_error_with_line_breaks_is_one_line():
    """h5py's full-disk OSError carries the HDF5 error stack over several lines: the boundary prints one."""
    import errno

    from cosemdepth.cli._boundary import error_line

    e = OSError(
        errno.ENOSPC,
        "Unable to synchronously create file (file write failed: time = Wed Dec  3 2026\n"
        ", filename = 'out/.sensor_records.tmp.hdf5', errno = 28, error message = 'No space left on device')",
        "out/.sensor_records.tmp.hdf5",
    )
    line = error_line(e)
    assert "\n" not in line and line.startswith("out/.sensor_records.tmp.hdf5: Unable to synchronously create file")
    assert line.endswith("the disk is full: free some space, or write the output to another disk")
