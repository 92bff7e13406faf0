"""The dispatcher: every argument error is one line naming the command, whatever the command."""

import pytest

from cosemdepth.cli.main import COMMANDS, main

#: the least each command needs to get past its required arguments (nothing is read: parsing fails first)
REQUIRED = {
    "convert": ["TF", "OUT"],
    "synth": ["--out", "o"],
    "splits": ["midair", "R", "O"],
    "train": ["--out", "o"],
    "evaluate": ["--model", "m", "--dataset", "synthair", "--root", "r"],
    "predict": ["--model", "m", "--out", "o"],
    "view": ["--model", "m", "--rrd", "x.rrd"],
    "demo": ["--out", "o"],
    "benchmark": [],
    "node": ["--model", "m", "--image-topic", "/image", "--pose-topic", "/odom", "--hfov", "90"],
    "replay": ["bag"],
    "fast-accuracy": ["--model", "m", "--dataset", "synthair", "--root", "r"],
    "export": ["--onnx", "x.onnx"],
}


def test_every_command_is_listed_here():
    assert sorted(REQUIRED) == sorted(COMMANDS)


@pytest.mark.parametrize("command", sorted(REQUIRED))
def test_an_unknown_argument_is_one_line_naming_the_command(command, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        main([command, *REQUIRED[command], "--bogus", "1"])
    assert e.value.code == 2
    assert capsys.readouterr().err == (
        f"cosemdepth {command}: error: unrecognized arguments: --bogus 1 (see cosemdepth {command} --help)\n"
    )
    assert list(tmp_path.iterdir()) == []
