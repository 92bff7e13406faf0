"""``cosemdepth evaluate`` end to end: the model converted from the TF fixture on a small Mid-Air-format split.

The numbers are checked against an independent loop written here: stream the dataset items through ``model.step``,
compute the per-frame metrics with plain numpy, and average them over the non-reset frames.
"""

import json
import math

import numpy as np
import pytest
import torch
from _outputs import (
    SIZE,
    _one_thread,  # noqa: F401 (pytest fixture)
    tiny_midair,
)

from cosemdepth.cli.main import main
from cosemdepth.data import open_dataset


@pytest.fixture(scope="module")
def tf_model(tfref_dir):
    from cosemdepth import load_model

    return load_model(tfref_dir / "ckpt" / "cp-0000.ckpt")  # converted on the fly


@pytest.fixture(scope="module")
def converted(tf_model, tmp_path_factory):
    from cosemdepth import save_model

    out = tmp_path_factory.mktemp("model") / "tfref"
    save_model(tf_model, out)
    return out


@pytest.fixture(scope="module")
def split(tmp_path_factory):
    return tiny_midair(tmp_path_factory.mktemp("midair"))  # 2 trajectories of 16 frames at SIZE: 3 CSV rows each


@pytest.fixture(scope="module")
def expected(tf_model, split):
    return manual_protocol(tf_model, split)


def manual_protocol(model, root):
    """Independent implementation of design 11.1-11.3: batch 1, reset frames skipped, numpy metrics."""
    ds = open_dataset("midair", root, split_dir=root / "splits", split="test", seq_len=1, size=SIZE)
    rows = {"abs_rel": [], "rmse": [], "delta1": [], "rmse_log": []}
    conf = np.zeros((7, 7), dtype=np.int64)
    state = None
    with torch.no_grad():
        for i in range(len(ds)):
            it = ds[i]
            out, state = model.step(it["rgb"], it["rot"], it["trans"], it["intrinsics"][None], it["reset"], state)
            if bool(it["reset"][0]):
                continue
            g = np.clip(it["depth"][0, 0].double().numpy(), 0, 80)
            e = np.clip(out.depth[0, 0].double().numpy(), 0.001, 80)
            v = g > 1e-6
            rows["abs_rel"].append(np.mean(np.abs(g - e)[v] / (g[v] + 1e-6)))
            rows["rmse"].append(math.sqrt(np.mean((g - e)[v] ** 2)))
            rows["delta1"].append(np.mean(np.maximum(g / e, e / g)[v] < 1.25))
            lg, le = np.log(g + 1e-6), np.log(e + 1e-6)
            q = lg > 1e-6
            rows["rmse_log"].append(math.sqrt(np.mean((lg - le)[q] ** 2)))
            gl = it["semantic"][0].numpy().ravel()
            pl = out.semantic[0].argmax(0).numpy().ravel()
            np.add.at(conf, (gl, pl), 1)
    tp = np.diag(conf).astype(float)
    denom = conf.sum(0) + conf.sum(1) - tp
    iou = tp[denom > 0] / denom[denom > 0]
    return {k: float(np.mean(v)) for k, v in rows.items()} | {"miou": float(iou.mean()), "frames": len(rows["rmse"])}


def run_cli(*argv):
    return main(["evaluate", *map(str, argv)])


# the reference modules: float32 rounding of the original's arithmetic (DINL's channel norm accumulates in float64,
# the original in float32: a few float32 ulps in the depth, 1e-6 relative in rmse_log on this random-weight model)
@pytest.mark.parametrize("path, rel", [("reference", 2e-6), ("fast", 1e-4)])
def test_evaluate_cli_on_the_converted_tf_model(converted, split, expected, tmp_path, capsys, path, rel):
    # --reference runs the same modules as the independent loop (float-exact); the default fast path agrees up to
    # float rounding amplified by the time recurrence of an untrained network
    out = tmp_path / "eval"
    rc = run_cli(
        "--model",
        converted,
        "--dataset",
        "midair",
        "--root",
        split,
        "--split-dir",
        split / "splits",
        "--size",
        SIZE,
        "--out",
        out,
        "--no-progress",
        *(["--reference"] if path == "reference" else []),
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "| model | params | ms/frame | mIoU |" in printed
    assert sorted(p.name for p in out.iterdir()) == [".cosemdepth-output.json", "metrics.json", "metrics.md"]
    res = json.loads((out / "metrics.json").read_text())
    m = res["metrics"]
    assert expected["frames"] == 4  # 2 trajectories x 3 rows, minus the 2 reset rows
    assert m["depth_frames"] == 4 and m["semantic_frames"] == 4
    for k in ("abs_rel", "rmse", "delta1", "rmse_log", "miou"):
        assert m[k] == pytest.approx(expected[k], rel=rel, abs=1e-9), k
    assert res["params"] == 5_202_528
    assert res["protocol"]["frames_streamed"] == 6 and res["protocol"]["reset_frames"] == 2
    assert len(res["confusion_matrix"]) == 7 and sum(map(sum, res["confusion_matrix"])) == 4 * SIZE * SIZE
    assert set(res["per_class_iou"]) == {"sky", "water", "trees", "land", "boulders", "road", "others"}
    assert res["speed"]["ms_per_frame"] > 0 and res["peak_memory_mb"] is not None
    md = (out / "metrics.md").read_text()
    assert md.startswith("# Evaluation of tfref on midair (test)") and "RMSE_log (fixed)" in md


def test_two_trajectories_per_batch_and_the_synthair_reader(converted, split, expected, tmp_path):
    # the same files read as SynthAir (splits in ROOT/splits), two trajectories streamed as one batch
    out = tmp_path / "eval2"
    rc = run_cli(
        "--model",
        converted,
        "--dataset",
        "synthair",
        "--root",
        split,
        "--size",
        SIZE,
        "--trajectories-per-batch",
        2,
        "--out",
        out,
        "--no-progress",
    )
    assert rc == 0
    m = json.loads((out / "metrics.json").read_text())["metrics"]
    for k in ("abs_rel", "rmse", "delta1"):
        assert m[k] == pytest.approx(expected[k], rel=1e-4), k
    assert m["depth_frames"] == 4
