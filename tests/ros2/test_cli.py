"""``cosemdepth node`` and ``cosemdepth replay`` on bad input: one line naming the argument, exit 2."""

import pytest
from _live import tiny_model

from cosemdepth.cli.main import main


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    return tiny_model(tmp_path_factory.mktemp("cli") / "model")


def node(model, *extra):
    return ["node", "--model", str(model), "--image-topic", "/cam", "--pose-topic", "/odom", *map(str, extra)]


@pytest.mark.parametrize(
    "extra, message",
    [
        (
            (),
            "the node needs exactly one of --camera-info-topic T, --calibration FILE, --intrinsics FX FY CX CY, --hfov DEG",
        ),
        (("--hfov", 90, "--camera-info-topic", "/info"), "the node needs exactly one of"),
        (("--hfov", 190), "--hfov must be in (0, 180) degrees, got 190.0"),
        (("--hfov", 90, "--out-namespace", "/9x"), "--out-namespace '/9x' is not a valid ROS namespace"),
        (("--hfov", 90, "--remap", "depth=/x"), "--remap 'depth=/x': expected NAME:=TOPIC"),
        (("--hfov", 90, "--onnx", "g.onnx"), "--onnx is the graph of --backend onnxruntime"),
        (("--hfov", 90, "--backend", "onnxruntime"), "--backend onnxruntime needs --onnx FILE"),
        (("--hfov", 90, "--pose-timeout", -1), "--pose-timeout must be a number of seconds >= 0, got -1.0"),
        (("--hfov", 90, "--policy", "every-frame", "--min-baseline", 1), "--min-baseline applies to --policy"),
    ],
)
def test_node_argument_errors(model, capsys, extra, message):
    assert main(node(model, *extra)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("cosemdepth node: error: ") and message in err[0], err


def test_node_bad_topic_and_domain(model, capsys, monkeypatch):
    assert main(["node", "--model", str(model), "--image-topic", "/9cam", "--pose-topic", "/o", "--hfov", "90"]) == 2
    assert "--image-topic '/9cam' is not a valid ROS topic name" in capsys.readouterr().err
    monkeypatch.setenv("ROS_DOMAIN_ID", "abc")
    assert main(node(model, "--hfov", 90)) == 2
    assert "ROS_DOMAIN_ID='abc' is not a domain id (an integer from 0 to 232)" in capsys.readouterr().err


def test_node_gives_up_when_nobody_publishes(model, capsys):
    assert main(node(model, "--hfov", 90, "--discovery-timeout", 0.3, "--report-every", 0)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("cosemdepth node: error: no publisher on /cam within --discovery-timeout 0.3 s")
    assert any("waiting for a publisher on /cam" in line for line in err)


def test_replay_errors(tmp_path, capsys):
    assert main(["replay", str(tmp_path / "none")]) == 2
    assert capsys.readouterr().err.strip().endswith("none: bag not found")
    assert main(["replay", str(tmp_path), "--rate", "-1"]) == 2
    assert "--rate must be a positive number, got -1.0" in capsys.readouterr().err
