"""Every command's bad paths and values through the real command line: exit status 2, one error line that names the
argument or file, no traceback, nothing written. Each command of ``cli/main.py`` COMMANDS is covered."""

import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "data"))
from _outputs import SIZE, _one_thread, data, leftovers, model_dir  # noqa: E402 (some are pytest fixtures)
from _writers import snapshot  # noqa: E402

from cosemdepth.cli.main import COMMANDS, main  # noqa: E402

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def env(tmp_path_factory, data, model_dir):
    """A sandbox: a dataset, a model, a junk file, a user's file, a user's folder, an ONNX file that is not ours."""
    t = tmp_path_factory.mktemp("bad")
    (t / "junk.bin").write_bytes(b"\x00\x01junk")
    (t / "notes.txt").write_text("mine")
    (t / "mine").mkdir()
    (t / "mine" / "keep.txt").write_text("mine")
    (t / "other.onnx").write_bytes(b"not written by cosemdepth")
    (t / "bench.json").write_text('{"mine": true}')
    (t / "notes.rrd").write_text("mine")
    (t / "images").mkdir()
    from PIL import Image

    Image.new("RGB", (16, 16)).save(t / "images" / "000000.png")
    return {"T": t, "D": data, "M": model_dir}


S = str(SIZE)
EVAL = ["--dataset", "midair", "--root", "{D}", "--split-dir", "{D}/splits", "--size", S, "--no-progress"]
FA = EVAL[:-1]  # fast-accuracy has no progress bar

#: (argv, what the error line must name); {T} = sandbox, {D} = dataset, {M} = model folder
CASES = [
    # convert
    (["convert", "{T}/nope/cp-0001.ckpt", "{T}/out"], "{T}/nope/cp-0001.ckpt"),
    (["convert", "{T}/junk.bin", "{T}/out"], "{T}/junk.bin"),
    (["convert", "{T}/mine", "{T}/out"], "{T}/mine"),
    (["convert", "{M}", "{T}/notes.txt"], "{T}/notes.txt"),
    (["convert", "{M}", "{T}/notes.txt/sub"], "{T}/notes.txt"),
    # synth
    (["synth", "--out", "{T}/notes.txt", "--frames", "8", "--size", "16"], "{T}/notes.txt"),
    (["synth", "--out", "{T}/notes.txt/sub", "--frames", "8", "--size", "16"], "{T}/notes.txt"),
    (["synth", "--out", "{T}/mine", "--frames", "8", "--size", "16"], "{T}/mine"),
    (["synth", "--out", "{T}/s", "--frames", "8", "--size", "0"], "size"),
    (["synth", "--out", "{T}/s", "--trajectories", "0"], "trajectories"),
    # splits
    (["splits", "midair", "{T}/nope", "{T}/out"], "{T}/nope"),
    (["splits", "midair", "{T}/notes.txt", "{T}/out"], "{T}/notes.txt"),
    (["splits", "midair", "{D}"], "OUT_DIR"),
    (["splits", "midair", "{D}", "{T}/notes.txt"], "{T}/notes.txt"),
    (["splits", "midair", "{D}", "{D}/x"], "{D}"),
    # train
    (["train", "--config", "{T}/nope.yaml", "--out", "{T}/run"], "{T}/nope.yaml"),
    (["train", "--config", "{T}/mine", "--out", "{T}/run"], "{T}/mine"),
    (["train", "--config", "{T}/junk.bin", "--out", "{T}/run"], "{T}/junk.bin"),
    (["train", "--config", "synthair-small", "--out", "{T}/notes.txt"], "{T}/notes.txt"),
    (["train", "--config", "synthair-small", "--out", "{T}/mine"], "{T}/mine"),
    (["train", "--config", "synthair-small", "--data-root", "{T}/nope", "--out", "{T}/run"], "{T}/nope"),
    (["train", "--config", "synthair-small", "--set", "train.lr=-1", "--out", "{T}/run"], "train.lr"),
    (["train", "--config", "synthair-small", "--set", "nope.key=1", "--out", "{T}/run"], "nope"),
    # evaluate
    (["evaluate", "--model", "{T}/nope", *EVAL], "{T}/nope"),
    (["evaluate", "--model", "{T}/junk.bin", *EVAL], "{T}/junk.bin"),
    (["evaluate", "--model", "{T}/mine", *EVAL], "{T}/mine"),
    (["evaluate", "--model", "{M}", *EVAL[:3], "{T}/nope"] + EVAL[4:], "{T}/nope"),
    (["evaluate", "--model", "{M}", *EVAL, "--out", "{T}/notes.txt"], "{T}/notes.txt"),
    (["evaluate", "--model", "{M}", *EVAL, "--out", "{D}"], "{D}"),
    (["evaluate", "--model", "{M}", *EVAL, "--size", "0"], "--size"),
    (["evaluate", "--model", "{M}", *EVAL, "--max-frames", "-3"], "--max-frames"),
    # predict
    (["predict", "--model", "{M}", *EVAL, "--out", "{D}", "--overwrite"], "{D}"),
    (["predict", "--model", "{M}", *EVAL, "--out", "{T}", "--overwrite"], "{T}"),
    (["predict", "--model", "{M}", *EVAL, "--out", "{M}", "--overwrite"], "{M}"),
    (["predict", "--model", "{M}", *EVAL, "--out", "{T}/mine", "--overwrite"], "{T}/mine"),
    (["predict", "--model", "{M}", *EVAL, "--out", "{T}/notes.txt"], "{T}/notes.txt"),
    (
        [
            "predict",
            "--model",
            "{M}",
            "--flight",
            "--images",
            "{T}/notes.txt",
            "--poses",
            "{T}/notes.txt",
            "--hfov",
            "90",
            "--out",
            "{T}/p",
        ],
        "{T}/notes.txt",
    ),
    (
        [
            "predict",
            "--model",
            "{M}",
            "--flight",
            "--images",
            "{T}/images",
            "--poses",
            "{T}/nope.txt",
            "--hfov",
            "90",
            "--out",
            "{T}/p",
        ],
        "{T}/nope.txt",
    ),
    (
        [
            "predict",
            "--model",
            "{M}",
            "--flight",
            "--images",
            "{T}/images",
            "--poses",
            "{T}/mine",
            "--hfov",
            "90",
            "--out",
            "{T}/p",
        ],
        "{T}/mine",
    ),
    (
        [
            "predict",
            "--model",
            "{M}",
            "--flight",
            "--images",
            "{T}/images",
            "--poses",
            "{T}/junk.bin",
            "--hfov",
            "90",
            "--out",
            "{T}/p",
        ],
        "{T}/junk.bin",
    ),
    (
        [
            "predict",
            "--model",
            "{M}",
            "--flight",
            "--images",
            "{T}/images",
            "--poses",
            "{T}/notes.txt",
            "--hfov",
            "200",
            "--out",
            "{T}/p",
        ],
        "--hfov",
    ),
    (
        [
            "predict",
            "--model",
            "{M}",
            "--flight",
            "--images",
            "{T}/images",
            "--poses",
            "{T}/notes.txt",
            "--hfov",
            "90",
            "--out",
            "{T}/images/p",
        ],
        "{T}/images",
    ),
    # predict --bag / --rerun, view
    (
        [
            "predict",
            "--model",
            "{M}",
            "--bag",
            "{T}/nope",
            "--image-topic",
            "/i",
            "--pose-topic",
            "/p",
            "--hfov",
            "90",
            "--out",
            "{T}/p",
        ],
        "{T}/nope",
    ),
    (
        [
            "predict",
            "--model",
            "{M}",
            "--bag",
            "{T}/junk.bin",
            "--image-topic",
            "/i",
            "--pose-topic",
            "/p",
            "--hfov",
            "90",
            "--out",
            "{T}/p",
        ],
        "{T}/junk.bin",
    ),
    (
        ["predict", "--model", "{M}", *EVAL, "--out", "{T}/p", "--rerun", "{T}/notes.rrd", "--overwrite"],
        "{T}/notes.rrd",
    ),
    (["predict", "--model", "{M}", *EVAL, "--out", "{T}/p", "--rerun", "{T}/p/x.rrd"], "{T}/p"),
    (["view", "--model", "{M}", *EVAL, "--rrd", "{T}/notes.txt"], "{T}/notes.txt"),
    (["view", "--model", "{M}", *EVAL, "--rrd", "{T}/notes.rrd"], "{T}/notes.rrd"),
    (["view", "--model", "{M}", *EVAL, "--rrd", "{M}/x.rrd"], "{M}"),
    (["view", "--model", "{M}", *EVAL, "--rrd", "{D}/x.rrd"], "{D}"),
    (["view", "--model", "{M}", *EVAL, "--rrd", "{T}/notes.txt/x.rrd"], "{T}/notes.txt"),
    (["view", "--model", "{M}", *EVAL, "--rrd", "{T}/nope/x.rrd"], "{T}/nope"),
    (["view", "--model", "{T}/nope", *EVAL, "--rrd", "{T}/x.rrd"], "{T}/nope"),
    # demo
    (["demo", "--model", "{T}/nope", "--out", "{T}/r"], "{T}/nope"),
    (["demo", "--model", "{T}/junk.bin", "--out", "{T}/r"], "{T}/junk.bin"),
    (["demo", "--model", "{M}", "--data-root", "{T}/nope", "--out", "{T}/r", "--size", "32"], "{T}/nope"),
    (["demo", "--model", "{M}", "--data-root", "{D}", "--out", "{T}/notes.txt"], "{T}/notes.txt"),
    (["demo", "--model", "{M}", "--data-root", "{D}", "--out", "{D}", "--overwrite"], "{D}"),
    (["demo", "--model", "{M}", "--data-root", "{D}", "--out", "{T}/mine", "--overwrite"], "{T}/mine"),
    # benchmark
    (["benchmark", "--json", "{T}/mine", "--md", "{T}/b.md"], "{T}/mine"),
    (["benchmark", "--json", "{T}/notes.txt/b.json", "--md", "{T}/b.md"], "{T}/notes.txt"),
    (["benchmark", "--json", "{T}/bench.json", "--md", "{T}/b.md"], "{T}/bench.json"),
    (["benchmark", "--json", "{T}/b.json", "--md", "{T}/notes.txt"], "{T}/notes.txt"),
    (["benchmark", "--json", "{T}/nope/b.json", "--md", "{T}/b.md"], "{T}/nope"),
    (["benchmark", "--model", "{T}/nope", "--json", "{T}/b.json", "--md", "{T}/b.md"], "{T}/nope"),
    # fast-accuracy
    (["fast-accuracy", "--model", "{M}", *FA, "--out", "{T}/bench.json"], "{T}/bench.json"),
    (["fast-accuracy", "--model", "{M}", *FA, "--out", "{T}/nope/fa.json"], "{T}/nope"),
    (["fast-accuracy", "--model", "{M}", *FA, "--out", "{D}/fa.json"], "{D}"),
    (["fast-accuracy", "--model", "{T}/nope", *FA, "--out", "{T}/fa.json"], "{T}/nope"),
    (
        [
            "fast-accuracy",
            "--model",
            "{M}",
            "--dataset",
            "midair",
            "--root",
            "{T}/nope",
            "--split-dir",
            "{T}/nope/splits",
            "--size",
            S,
            "--out",
            "{T}/fa.json",
        ],
        "{T}/nope",
    ),
    # export
    (["export", "--onnx", "{T}/mine"], "{T}/mine"),
    (["export", "--onnx", "{T}/notes.txt/m.onnx"], "{T}/notes.txt"),
    (["export", "--onnx", "{T}/nope/m.onnx"], "{T}/nope"),
    (["export", "--onnx", "{T}/other.onnx"], "{T}/other.onnx"),
    (["export", "--onnx", "{M}/m.onnx", "--model", "{M}"], "{M}"),
    (["export", "--onnx", "{T}/m.onnx", "--model", "{T}/nope"], "{T}/nope"),
    (["export", "--onnx", "{T}/m.onnx", "--model", "{T}/junk.bin"], "{T}/junk.bin"),
    (["export", "--onnx", "{T}/m.onnx", "--size", "4", "4"], "--size"),
    # node, replay: refused before they join a DDS graph
    (["node", "--model", "{T}/nope", "--image-topic", "/c", "--pose-topic", "/p", "--hfov", "90"], "{T}/nope"),
    (["node", "--model", "{M}", "--image-topic", "/c", "--pose-topic", "/p", "--hfov", "190"], "--hfov"),
    (["node", "--model", "{M}", "--image-topic", "/c", "--pose-topic", "/p", "--calibration", "{T}/nope"], "{T}/nope"),
    (
        ["node", "--model", "{M}", "--image-topic", "/c", "--pose-topic", "/p", "--calibration", "{T}/junk.bin"],
        "{T}/junk.bin",
    ),
    (["replay", "{T}/nope"], "{T}/nope"),
    (["replay", "{T}/junk.bin"], "{T}/junk.bin"),
    (["replay", "{T}/mine", "--rate", "0"], "--rate"),
    # a size far beyond any image (10^10 pixels): refused before anything is allocated or written
    (["predict", "--model", "{M}", *EVAL, "--size", "100000", "--out", "{T}/p"], "--size: 100000x100000"),
    (["evaluate", "--model", "{M}", *EVAL, "--size", "100000"], "--size: 100000x100000"),
    (["view", "--model", "{M}", *EVAL, "--size", "100000", "--rrd", "{T}/v.rrd"], "--size: 100000x100000"),
    (["export", "--onnx", "{T}/m.onnx", "--size", "100000", "100000"], "--size: 100000x100000"),
    (["benchmark", "--size", "100000", "100000", "--json", "{T}/b.json", "--md", "{T}/b.md"], "100000x100000"),
    (["demo", "--model", "{M}", "--data-root", "{D}", "--out", "{T}/r", "--size", "100000"], "--size: 100000x100000"),
    (
        ["train", "--config", "synthair-small", "--data-root", "{D}", "--set", "data.size=100000", "--out", "{T}/run"],
        "data.size: 100000x100000",
    ),
]


def _fill(x: str, env) -> str:
    return x.format(**{k: str(v) for k, v in env.items()})


def test_every_command_is_covered():
    assert {argv[0] for argv, _ in CASES} == set(COMMANDS)


@pytest.mark.parametrize("argv, names", CASES, ids=[" ".join(a[:2]) + f"-{i}" for i, (a, _) in enumerate(CASES)])
def test_bad_path_or_value(env, capsys, argv, names):
    before = snapshot(env["T"]), snapshot(env["D"]), snapshot(env["M"])
    argv = [_fill(a, env) for a in argv]
    try:
        code = main(argv)
    except SystemExit as e:  # argparse rejects the value itself
        code = e.code
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    errors = [line for line in err.splitlines() if ": error: " in line]
    assert len(errors) == 1 and errors[0].startswith(f"cosemdepth {argv[0]}: error: "), err
    assert err.strip().splitlines()[-1] == errors[0]  # the error is the last line (after argparse's usage)
    assert _fill(names, env) in errors[0], errors[0]
    assert (snapshot(env["T"]), snapshot(env["D"]), snapshot(env["M"])) == before, "something was written"
    assert leftovers(env["T"]) == []


def test_through_the_real_command_line(env):
    """A few of the cases in a fresh interpreter, as a user runs them (no traceback, exit 2, one line)."""
    for argv, names in (CASES[0], CASES[-5], CASES[33]):
        argv = [_fill(a, env) for a in argv]
        r = subprocess.run(
            [sys.executable, "-m", "cosemdepth", *argv],
            capture_output=True,
            text=True,
            env={"PYTHONPATH": str(REPO / "src"), "PATH": "/usr/bin:/bin", "OMP_NUM_THREADS": "1"},
        )
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and _fill(names, env) in r.stderr, r.stderr


def test_file_system_errors_naming_a_path_are_one_line_others_propagate(monkeypatch, capsys):
    import errno

    import cosemdepth.cli.export as export_cli

    def fails(args):
        raise PermissionError(errno.EACCES, "Permission denied", "/data/run/x.onnx")

    monkeypatch.setattr(export_cli, "run", fails)
    assert main(["export", "--onnx", "x.onnx"]) == 2
    assert capsys.readouterr().err == "cosemdepth export: error: /data/run/x.onnx: Permission denied\n"

    def bug(args):
        raise OSError("internal failure that names no file")

    monkeypatch.setattr(export_cli, "run", bug)
    with pytest.raises(OSError, match="internal failure"):
        main(["export", "--onnx", "x.onnx"])
