"""``cosemdepth export --onnx OUT --int8``: calibrated on a dataset's frames, the semantic refiners' hidden
convolutions int8; bad combinations are one line and write nothing."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))
from _outputs import tiny_midair  # noqa: E402

from cosemdepth.cli.main import main  # noqa: E402
from cosemdepth.export.onnx import is_our_onnx  # noqa: E402
from cosemdepth.export.quantize import quantized_convolutions  # noqa: E402

TINY = ["--levels", "2", "--size", "32", "32"]


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return tiny_midair(tmp_path_factory.mktemp("d") / "midair")


def calib(root: Path) -> list[str]:
    return ["--calibration-root", str(root), "--calibration-split-dir", str(root / "splits")]


def test_int8_export_calibrated_on_a_dataset(tmp_path, data, capsys):
    out = tmp_path / "q.onnx"
    argv = ["export", "--onnx", str(out), "--arch", "cosemdepth", *TINY, "--int8", *calib(data)]
    assert main([*argv, "--calibration-frames", "3"]) == 0
    said = capsys.readouterr().out
    assert "int8 semantic refiners calibrated on 3 frames" in said
    assert is_our_onnx(out)
    # two levels, six hidden convolutions each; the depth decoder's none
    q = quantized_convolutions(out)
    assert len(q) == 12 and all(".semantic_decoder." in n for n in q)
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == [".cosemdepth-output.json", "q.onnx"]  # the output record; no temporary file left beside it
    # a second export replaces the graph it wrote
    assert main([*argv, "--calibration-frames", "2"]) == 0


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--calibration-root", "{D}"], "--calibration-root calibrates --int8"),
        (["--calibration-frames", "4"], "--calibration-frames calibrates --int8"),
        (["--calibration-dataset", "synthair"], "--calibration-dataset calibrates --int8"),
        (["--arch", "m4depth", "--int8"], "no convolution the int8 policy quantises"),
        (["--int8", "--calibration-root", "{T}/nowhere"], "--calibration-root {T}/nowhere: not a folder"),
        (["--int8", "--calibration-root", "{D}"], "needs --calibration-split-dir"),
        (["--int8", "--calibration-frames", "0"], "--calibration-frames"),
    ],
)
def test_bad_int8_arguments_are_one_line_and_write_nothing(tmp_path, data, capsys, extra, words):
    out = tmp_path / "q.onnx"
    extra = [e.replace("{D}", str(data)).replace("{T}", str(tmp_path)) for e in extra]
    arch = [] if "--arch" in extra else ["--arch", "cosemdepth"]
    try:
        rc = main(["export", "--onnx", str(out), *arch, *TINY, *extra])
    except SystemExit as e:  # argparse's own checks
        rc = e.code
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words.replace("{T}", str(tmp_path)) in err[0] and "Traceback" not in err[0]
    assert not out.exists() and list(tmp_path.iterdir()) == []
