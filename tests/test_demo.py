"""``cosemdepth demo``: the whole pipeline on a tiny dataset with a tiny random model; the metrics.json schema; the
baselines against an independent computation; clear errors."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent / "evaluation"))
from _outputs import _one_thread, leftovers, model_dir, tiny_midair  # noqa: E402 (some are pytest fixtures)

from cosemdepth import demo as demo_mod  # noqa: E402
from cosemdepth.cli.main import main  # noqa: E402
from cosemdepth.data import open_dataset  # noqa: E402
from cosemdepth.errors import CheckpointError, ConfigError, DatasetError  # noqa: E402

SIZE = 32


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return tiny_midair(tmp_path_factory.mktemp("d") / "flight", trajectories=(0,), frames=28)  # 6 rows


def check_schema(m):
    assert set(m["model"]) == {"miou", "abs_rel", "rmse", "delta1", "coverage", "valid_abs_rel", "valid_delta1"}
    assert 0.0 <= m["model"]["coverage"] <= 1.0  # the fraction of the ground-truth pixels the mask keeps
    counts = m["details"]["evaluation"]["protocol"]["frames_by_status"]
    assert sum(counts.values()) == m["details"]["evaluation"]["protocol"]["frames_evaluated"]
    assert set(m["baselines"]) == {"majority_class", "constant_depth"}
    assert set(m["baselines"]["majority_class"]) == {"miou"}
    assert set(m["baselines"]["constant_depth"]) == {"abs_rel", "rmse", "delta1"}
    for v in (
        m["model"]["miou"],
        m["model"]["delta1"],
        m["baselines"]["majority_class"]["miou"],
        m["baselines"]["constant_depth"]["delta1"],
    ):
        assert isinstance(v, float) and 0.0 <= v <= 1.0
    for v in (
        m["model"]["abs_rel"],
        m["model"]["rmse"],
        m["baselines"]["constant_depth"]["abs_rel"],
        m["baselines"]["constant_depth"]["rmse"],
    ):
        assert isinstance(v, float) and v >= 0


def independent_baselines(root):
    """Design 11 by hand on the non-reset frames: constant median depth, majority class."""
    ds = open_dataset("synthair", root, split="test", seq_len=1, size=SIZE)
    items = [ds[i] for i in range(len(ds)) if not bool(ds[i]["reset"][0])]
    gts = [np.clip(it["depth"][0, 0].double().numpy(), 0, 80) for it in items]
    allg = np.concatenate([g.ravel() for g in gts])
    med = np.median(allg[allg > 1e-6])
    e = np.clip(med, 0.001, 80)
    abs_rel = np.mean([np.mean(np.abs(g - e)[g > 1e-6] / (g[g > 1e-6] + 1e-6)) for g in gts])
    rmse = np.mean([np.sqrt(np.mean((g - e)[g > 1e-6] ** 2)) for g in gts])
    delta1 = np.mean([np.mean(np.maximum(g / e, e / g)[g > 1e-6] < 1.25) for g in gts])
    labels = np.concatenate([it["semantic"][0].numpy().ravel() for it in items])
    counts = np.bincount(labels, minlength=7)
    # predicting class c everywhere: IoU_c = n_c / N, every other class present in GT has IoU 0, absent ones excluded
    miou = counts.max() / counts.sum() / np.count_nonzero(counts)
    return {"abs_rel": abs_rel, "rmse": rmse, "delta1": delta1, "miou": miou, "frames": len(items)}


def test_demo_end_to_end_on_a_given_dataset(model_dir, data, tmp_path, capsys):
    out = tmp_path / "report"
    rc = main(
        [
            "demo",
            "--out",
            str(out),
            "--model",
            str(model_dir),
            "--data-root",
            str(data),
            "--size",
            str(SIZE),
            "--no-progress",
        ]
    )
    assert rc == 0
    assert f"Report: {out / 'report.md'}" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == [
        ".cosemdepth-output.json",
        "flight.mp4",
        "iou.png",
        "metrics.json",
        "qualitative.png",
        "report.md",
    ]
    m = json.loads((out / "metrics.json").read_text())
    check_schema(m)
    assert m["flight"]["root"] == str(Path(data).resolve()) and Path(m["flight"]["root"]).is_dir()
    assert m["flight"]["jpeg_idct"] == "fast"
    ref = independent_baselines(data)
    assert m["details"]["evaluation"]["protocol"]["frames_evaluated"] == ref["frames"] == 5
    cd = m["baselines"]["constant_depth"]
    for k in ("abs_rel", "rmse", "delta1"):
        assert cd[k] == pytest.approx(ref[k], rel=1e-6), k
    assert m["baselines"]["majority_class"]["miou"] == pytest.approx(ref["miou"], rel=1e-12)
    # the model's numbers are those of the evaluator on the same frames
    from cosemdepth import load_model
    from cosemdepth.evaluation.evaluator import evaluate

    # the demo runs the fast inference path by default (load_model's FastModel)
    ev = evaluate(
        load_model(model_dir, mode="fast"), open_dataset("synthair", data, split="test", seq_len=1, size=SIZE)
    )
    for k in ("miou", "abs_rel", "rmse", "delta1"):
        assert m["model"][k] == pytest.approx(ev.metrics[k], rel=1e-9), k
    import imageio_ffmpeg

    assert imageio_ffmpeg.count_frames_and_secs(str(out / "flight.mp4"))[0] == 6
    from PIL import Image

    assert Image.open(out / "iou.png").size[0] > 100 and Image.open(out / "qualitative.png").size[1] > 100
    report = (out / "report.md").read_text()
    assert "| **Co-SemDepth** |" in report and "majority class" in report and "constant depth" in report
    assert "![per-class IoU](iou.png)" in report and "## Timings" in report
    assert leftovers(tmp_path) == []

    # a second run replaces the report
    rc = main(
        [
            "demo",
            "--out",
            str(out),
            "--model",
            str(model_dir),
            "--data-root",
            str(data),
            "--size",
            str(SIZE),
            "--no-progress",
            "--video",
            "none",
        ]
    )
    assert rc == 0 and not (out / "flight.mp4").exists() and leftovers(tmp_path) == []


def test_demo_on_trajectories_of_one_frame_reports_no_depth(model_dir, tmp_path, capsys):
    one = tiny_midair(tmp_path / "one", trajectories=(0,), frames=8)  # one row: the flight is one reset frame
    out = tmp_path / "report"
    argv = ["demo", "--out", str(out), "--model", str(model_dir), "--data-root", str(one), "--size", str(SIZE)]
    assert main([*argv, "--no-progress", "--video", "none"]) == 0
    err = capsys.readouterr().err
    assert "cosemdepth demo: warning: no depth was produced: the input has 1 frame" in err
    m = json.loads((out / "metrics.json").read_text())
    assert m["model"]["abs_rel"] is None and m["model"]["miou"] is not None
    report = (out / "report.md").read_text()
    assert "reset frames excluded" not in report
    assert "every frame is a reset: counted for the labels, never for the depth" in report
    assert "**Warning**: no depth was produced" in report


def test_demo_generates_the_flight_with_the_synth_command(model_dir, tmp_path, monkeypatch):
    """The generation path, with the generator of ``cosemdepth synth`` replaced by the test writer (same Mid-Air
    format): the demo calls it as a library, with the config the command would build."""
    from cosemdepth.synthair.writer import SynthConfig

    calls = []

    def fake_generate(config, progress=True):
        calls.append((config, progress))
        tiny_midair(Path(config.out), trajectories=(0,), frames=config.frames, size=config.size)
        return {}

    monkeypatch.setattr(demo_mod, "synth_generate", fake_generate)
    monkeypatch.setattr(demo_mod, "synth_available", lambda: True)
    m = demo_mod.run_demo(
        tmp_path / "r",
        model=model_dir,
        size=SIZE,
        frames=5,
        seed=7,
        climate="foggy",
        video=None,
        progress=False,
        log=lambda *a: None,
    )
    ((config, progress),) = calls
    out = config.out
    # what `cosemdepth synth --trajectories 1 --frames 24 --size 32 --seed 7 --climates foggy --supersample 3
    # --no-progress` builds
    assert (
        config == SynthConfig(out=out, trajectories=1, frames=24, size=32, seed=7, climates=("foggy",), supersample=3)
        and progress is False
    )
    assert not Path(out).exists()  # the temporary flight is deleted
    # ... so metrics.json does not name it as the flight's root (a folder that may no longer exist)
    assert m["flight"]["root"] is None and m["flight"]["kept"] is False
    assert str(out) not in (tmp_path / "r" / "metrics.json").read_text()
    check_schema(m)
    assert m["details"]["evaluation"]["protocol"]["frames_streamed"] == 5
    assert json.loads((tmp_path / "r" / "metrics.json").read_text())["model"] == pytest.approx(m["model"])


def test_synth_failure_and_missing_synth(model_dir, tmp_path, monkeypatch):
    monkeypatch.setattr(demo_mod, "synth_available", lambda: False)
    with pytest.raises(ConfigError, match="--data-root"):
        demo_mod.run_demo(tmp_path / "r", model=model_dir, size=SIZE, frames=3, log=lambda *a: None)
    monkeypatch.setattr(demo_mod, "synth_available", lambda: True)

    def failing(config, progress=True):
        raise DatasetError(f"{config.out}: the renderer failed")

    monkeypatch.setattr(demo_mod, "synth_generate", failing)
    with pytest.raises(DatasetError, match="the renderer failed"):
        demo_mod.run_demo(tmp_path / "r", model=model_dir, size=SIZE, frames=3, log=lambda *a: None)
    assert list(tmp_path.iterdir()) == []


def test_missing_shipped_weights_is_a_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(demo_mod, "default_model_candidates", lambda: [tmp_path / "weights" / "x"])
    with pytest.raises(CheckpointError, match="trained weights were not found.*--model DIR"):
        demo_mod.resolve_model_path(None)
    assert main(["demo", "--out", str(tmp_path / "r")]) == 2
    assert "weights were not found" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_bad_outputs_and_arguments(model_dir, data, tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("mine")
    assert main(["demo", "--out", str(f), "--model", str(model_dir), "--data-root", str(data)]) == 2
    assert "exists and is not a folder" in capsys.readouterr().err and f.read_text() == "mine"
    assert (
        main(
            [
                "demo",
                "--out",
                str(tmp_path / "r"),
                "--model",
                str(model_dir),
                "--data-root",
                str(data),
                "--data-dir",
                str(tmp_path / "d"),
            ]
        )
        == 2
    )
    assert "--data-dir does not apply to --data-root (only to a generated flight" in capsys.readouterr().err
    assert main(["demo", "--out", str(tmp_path / "r"), "--model", str(model_dir), "--frames", "1"]) == 2
    assert "--frames" in capsys.readouterr().err
    # more frames than synth renders: the demo's own one line, before the flight is built (not synth's error too)
    from cosemdepth.synthair.writer import MAX_FRAMES

    assert main(["demo", "--out", str(tmp_path / "r"), "--model", str(model_dir), "--frames", str(10**9)]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"cosemdepth demo: error: --frames must be an integer in [2, {MAX_FRAMES // 4 - 1}] (the first "
        f"frame is a reset; the flight is rendered by cosemdepth synth, at most {MAX_FRAMES} camera "
        f"frames), got {10**9}\n"
    )
    assert not (tmp_path / "r").exists()
    assert main(["demo", "--out", str(tmp_path / "r"), "--model", str(model_dir), "--climate", "martian"]) == 2
    assert capsys.readouterr().err == (
        "cosemdepth demo: error: --climate must be one of sunny, cloudy, foggy, sunset, got 'martian'\n"
    )
    assert not (tmp_path / "r").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_majority_and_constant_baselines_by_hand():
    c = demo_mod.DemoCollector(total_frames=2, num_classes=3, palette=None)
    c.gt_depths = [torch.tensor([[10.0, 20.0], [40.0, 0.0]]), torch.tensor([[100.0, 30.0], [30.0, 30.0]])]
    c.label_hist = np.array([5, 2, 0])
    # valid clipped GT: 10, 20, 40, 80, 30, 30, 30 -> median 30
    cd = c.constant_depth()
    assert cd["depth_m"] == 30.0
    f1 = (20 / 10 + 10 / 20 + 10 / 40) / 3  # AbsRel of frame 1 (the 0 is invalid)
    f2 = (50 / 80) / 4
    assert cd["abs_rel"] == pytest.approx((f1 + f2) / 2, rel=1e-5)
    assert cd["delta1"] == pytest.approx((0 + 3 / 4) / 2)  # ratios 3, 1.5, 1.33 | 2.67, 1, 1, 1
    maj = c.majority_class()
    # class 0 everywhere: IoU_0 = 5 / 7, IoU_1 = 0, class 2 absent from both -> left out
    assert maj["class"] == 0 and maj["miou"] == pytest.approx((5 / 7 + 0) / 2)


def test_the_generated_flight_has_the_model_s_focal_length():
    from cosemdepth.checkpoints.convert import MIDAIR_OPERATING_POINT
    from cosemdepth.operating_point import OperatingPoint

    # SynthAir's camera is a 90-degree pinhole (f = S/2): the side is twice the model's focal length
    assert demo_mod.flight_size(OperatingPoint((32, 32), (16.0, 16.0))) == 32
    assert demo_mod.flight_size(OperatingPoint((96, 128), (64.0, 64.0))) == 128
    assert demo_mod.flight_size(MIDAIR_OPERATING_POINT) == 384
    assert demo_mod.flight_size(None) == demo_mod.DEFAULT_SIZE


def test_demo_on_a_given_dataset_without_size_runs_at_the_model_s_focal_length(data, tmp_path, capsys):
    from cosemdepth import build_model, save_model
    from cosemdepth.operating_point import OperatingPoint

    torch.manual_seed(0)
    model = save_model(
        build_model(arch="cosemdepth", levels=2), tmp_path / "m", operating_point=OperatingPoint((16, 16), (8.0, 8.0))
    )  # the 32x32 split at half its size
    m = demo_mod.run_demo(tmp_path / "r", model=model, data_root=data, video=None, progress=False, log=lambda *a: None)
    assert m["flight"]["size"] == [16, 16] and "--size" not in m["command"]
    assert "focal length" not in capsys.readouterr().err  # no size warning (this random model's depth is another)
    demo_mod.run_demo(
        tmp_path / "r2", model=model, data_root=data, size=SIZE, video=None, progress=False, log=lambda *a: None
    )
    err = capsys.readouterr().err
    assert "16.0 px, but the model was trained at 8.0 px (16x16)" in err
    assert "(without --size this input runs at 16x16)" in err
