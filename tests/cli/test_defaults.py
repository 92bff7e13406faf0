"""The command line takes its defaults from one home: the config dataclasses, the dataset table, and the defaults
of the functions each command calls. These tests compare the parsed defaults (and the defaults the help texts
state) with those homes, so the two cannot drift apart."""

import inspect
import re

import pytest

from cosemdepth.bench.runner import BenchCase
from cosemdepth.cli._shared import MODEL_SIZE_RULE, parse_size_pair
from cosemdepth.cli.main import COMMANDS, build_parser
from cosemdepth.data.flight import open_flight
from cosemdepth.data.registry import DATASETS, split_datasets
from cosemdepth.demo import run_demo
from cosemdepth.export.onnx import export_onnx
from cosemdepth.jobs.model import ModelOptions
from cosemdepth.jobs.options import RunOptions
from cosemdepth.jobs.predict import predict
from cosemdepth.models.config import ModelConfig
from cosemdepth.robotics.bag_flight import open_bag_flight
from cosemdepth.streaming.sinks.files import FileOptions
from cosemdepth.synthair.writer import SynthConfig
from cosemdepth.training.config import DataConfig, RunConfig, resolve_config


def parse(command, *argv):
    return build_parser(only=command).parse_args([command, *argv])


def defaults_of(fn):
    return {k: p.default for k, p in inspect.signature(fn).parameters.items() if p.default is not p.empty}


def subparser(command):
    parser = build_parser(only=command)
    action = next(a for a in parser._actions if a.dest == "command")
    return action.choices[command]


def test_model_flags_default_to_the_model_config():
    args = parse("export", "--onnx", "x.onnx")
    cfg = ModelConfig()
    assert (args.arch, args.levels, args.classes) == (cfg.arch, cfg.levels, cfg.num_classes)


def test_export_defaults_are_the_exporter_s():
    args = parse("export", "--onnx", "x.onnx")
    fn = defaults_of(export_onnx)
    assert args.opset == fn["opset"]
    assert args.batch == fn["batch"]
    # no --size: the training recipe's input size, which is also the exporter's
    assert parse_size_pair(args.size) == DataConfig().size == (fn["height"], fn["width"])


def test_benchmark_defaults_are_the_model_config_and_the_bench_case():
    args = parse("benchmark")
    case, cfg = BenchCase(), ModelConfig()
    assert args.levels == case.levels == cfg.levels and case.num_classes == cfg.num_classes
    assert (args.warmup, args.iters) == (case.warmup, case.iters)
    assert parse_size_pair(args.size) == (case.height, case.width) == DataConfig().size


def test_synth_defaults_are_the_generator_config():
    args = parse("synth", "--out", "d")
    cfg = SynthConfig(out="d")
    names = ("trajectories", "frames", "size", "seed", "all_frames", "supersample", "jpeg_quality", "workers")
    for name in (*names, "camera_mount", "time_offset", "fps"):
        assert getattr(args, name) == getattr(cfg, name), name
    assert tuple(args.climates) == cfg.climates
    assert cfg.size == DataConfig().size[0]


def test_predict_defaults_are_the_functions_it_calls():
    args = parse("predict", "--model", "m", "--out", "o")
    fn = defaults_of(predict)
    assert (args.video, args.fps, args.lanes, args.workers) == (fn["video"], fn["fps"], fn["lanes"], fn["num_workers"])
    # ... which are those of the options the command builds
    run, files = RunOptions(), FileOptions()
    assert (args.video, args.fps, args.invalid) == (files.video, files.fps, files.invalid)
    assert (args.lanes, args.workers, args.max_frames) == (run.lanes, run.workers, run.max_frames)
    assert (
        parse("predict", "--model", "m", "--out", "o").device
        == ModelOptions("m").device
        == defaults_of(run_demo)["device"]
    )
    bag = defaults_of(open_bag_flight)
    assert (args.jpeg_idct, args.frame_skip) == (bag["jpeg_idct"], bag["frame_skip"])
    flight = defaults_of(open_flight)
    assert (args.match, args.stamp_unit, args.frame_skip, args.skip_unposed) == (
        flight["match"],
        flight["stamp_unit"],
        flight["frame_skip"],
        flight["skip_unposed"],
    )
    # --max-pose-gap: each source's own default, stated in the help
    assert args.max_pose_gap is None
    helps = {a.dest: a.help for a in subparser("predict")._actions}
    assert f"{flight['max_gap']:g} for --flight, {bag['max_pose_gap']:g} for --bag" in helps["max_pose_gap"]


def test_demo_defaults_are_run_demo_s():
    args = parse("demo", "--out", "o")
    fn = defaults_of(run_demo)
    for name in (
        "frames",
        "seed",
        "climate",
        "supersample",
        "video",
        "jpeg_idct",
        "model",
        "size",
        "data_root",
        "data_dir",
        "device",
    ):
        assert getattr(args, name) == fn[name], name


def test_split_flags_come_from_the_dataset_table():
    parser = subparser("evaluate")
    actions = {a.dest: a for a in parser._actions}
    assert tuple(actions["dataset"].choices) == split_datasets()
    for name in split_datasets():
        spec = DATASETS[name]
        assert f"{name} {spec.split}" in actions["split"].help
        size = "native" if spec.size is None else str(spec.size)
        assert re.search(rf"{size} for [a-z, ]*\b{name}\b", actions["size"].help), (name, actions["size"].help)


@pytest.mark.parametrize("command", ["evaluate", "predict", "view"])
def test_size_defaults_to_the_model_s_focal_length_then_the_dataset_table(command):
    """No --size: the model's focal length (cli._shared.MODEL_SIZE_RULE), the table's sizes only for a model without
    an operating point; the parsed default stays None (decided when the model is known)."""
    help_text = " ".join({a.dest: a.help for a in subparser(command)._actions}["size"].split())
    assert help_text.startswith(f"network input size, S or HxW (default: {MODEL_SIZE_RULE}; for a model without one:")
    required = {
        "evaluate": ["--dataset", "synthair", "--root", "r"],
        "predict": ["--out", "o"],
        "view": ["--rrd", "x.rrd"],
    }[command]
    assert parse(command, "--model", "m", *required).size is None


def test_export_and_benchmark_say_the_model_s_size_comes_first():
    for command in ("export", "benchmark"):
        helps = {a.dest: a.help for a in subparser(command)._actions}
        assert "the training size of --model" in helps["size"] or "the model's training size" in helps["size"]
        assert "{} {}".format(*DataConfig().size) in helps["size"]


def test_train_flags_leave_the_defaults_to_the_config():
    args = parse("train", "--out", "run")
    values = {"train.progress": True}  # as `cosemdepth train` without --no-progress
    assert resolve_config(None, [], values) == RunConfig()
    # the help of each shortcut states the config's default
    cfg = RunConfig()
    helps = {a.dest: a.help for a in subparser("train")._actions}
    for dest, value in (
        ("epochs", cfg.train.epochs),
        ("batch_size", cfg.train.batch_size),
        ("seed", cfg.train.seed),
        ("model", cfg.model.arch),
        ("device", cfg.train.device),
        ("dataset", cfg.data.train[0].name),
    ):
        assert getattr(args, dest) is None
        assert f"(default {value})" in helps[dest], dest


def _stated_default(text):
    m = re.search(r"\(default:? ([^;:),]+?)(?:[;:),]| =| \(|$)", text)
    return None if m is None else m.group(1).strip()


@pytest.mark.parametrize("command", list(COMMANDS))
def test_help_states_the_actual_defaults(command):
    """Wherever a flag's help says "(default X)" with a literal X, X is the value the parser gives."""
    checked = 0
    for action in subparser(command)._actions:
        stated = _stated_default(action.help or "")
        if stated is None or action.default is None or isinstance(action.default, bool):
            continue
        actual = action.default
        if isinstance(actual, (list, tuple)):
            actual = " ".join(map(str, actual))
        elif isinstance(actual, float):
            actual = format(actual, "g")
        assert stated.split()[0] == str(actual).split()[0] or stated == str(actual), (action.dest, stated, actual)
        checked += 1
    assert command in ("convert", "splits", "view", "evaluate", "train") or checked > 0
