"""Accuracy of every fast inference mode against the fp32 reference path, with trained weights on a real flight.

    PYTHONPATH=src python benchmarks/fast_accuracy.py --model MODEL_DIR --dataset synthair --root DATA_ROOT \
        [--split test] [--max-frames N] [--modes fast-fp32 fast-bf16 fast-int8] [--device cpu] [--out FILE] \
        [--calibration-root ROOT2 --calibration-frames 16]

Streams the split's trajectories frame by frame (as the test protocol, design 11.3: reset frames count in no metric)
through the reference path and through each fast mode, computes mIoU and the depth metrics with
``cosemdepth.evaluation.metrics.EvaluationMetrics``, and checks the acceptance of issue 5: each fast mode within
0.5 points of mIoU and within 1% (relative) of AbsRel of the fp32 reference. Writes JSON; exit status 1 if a mode
fails.

``fast-int8`` calibrates its activation ranges on the first ``--calibration-frames`` frames of
``--calibration-root`` (another flight: default the evaluated split itself, which the report then says).

Needs ``cosemdepth.io.model_io.load_model`` (model folders) and ``cosemdepth.data.open_dataset`` (dataset readers).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cosemdepth.io.atomic import atomic_write_text  # noqa: E402

MODES = {
    "reference": ("reference", None),
    "fast-fp32": ("fast", "float32"),
    "fast-bf16": ("fast", "bfloat16"),
    "fast-fp16": ("fast", "float16"),
    "fast-int8": ("fast", "int8"),
}
MIOU_TOL_POINTS = 0.5
ABSREL_TOL_REL = 0.01


def evaluate(model, dataset, device: torch.device, max_frames: int | None) -> dict:
    from cosemdepth.evaluation.metrics import EvaluationMetrics

    cfg = model.config
    metrics = EvaluationMetrics(cfg.num_classes if cfg.has_semantic else None, depth=cfg.has_depth)
    state = None
    n = len(dataset) if max_frames is None else min(len(dataset), max_frames)
    t0 = time.perf_counter()
    with torch.inference_mode():
        for i in range(n):
            item = dataset[i]
            reset = item["reset"][:1].to(device)
            out, state = model.step(
                item["rgb"][:1].to(device),
                item["rot"][:1].to(device),
                item["trans"][:1].to(device),
                item["intrinsics"].view(1, 4).to(device),
                reset,
                state,
            )
            include = ~reset.cpu()
            metrics.update(
                gt_depth=item["depth"][:1] if cfg.has_depth else None,
                pred_depth=out.depth.float().cpu() if cfg.has_depth else None,
                gt_labels=item["semantic"][:1] if cfg.has_semantic else None,
                pred_semantic=out.semantic.float().cpu() if cfg.has_semantic else None,
                include=include,
            )
    res = metrics.compute()
    res["frames"] = n
    res["seconds"] = round(time.perf_counter() - t0, 1)
    return res


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", required=True, help="model folder (or official TF checkpoint)")
    p.add_argument("--dataset", default="synthair", help="dataset name for cosemdepth.data.open_dataset")
    p.add_argument("--root", required=True, help="dataset root")
    p.add_argument("--split-dir", help="split folder (default: the dataset's)")
    p.add_argument("--split", default="test")
    p.add_argument("--size", type=int, help="image size (default: the size where the dataset's camera has the model's "
                   "focal length in pixels, from its operating point; else the dataset's default)")
    p.add_argument("--max-frames", type=int, help="stop after this many frames (whole split by default)")
    p.add_argument("--modes", nargs="+", choices=[m for m in MODES if m != "reference"], default=["fast-fp32", "fast-bf16"])
    p.add_argument("--device", default="cpu")
    p.add_argument("--calibration-root", help="int8: dataset root whose first frames calibrate (default: --root)")
    p.add_argument("--calibration-split", default=None, help="int8: split of --calibration-root (default: --split)")
    p.add_argument("--calibration-frames", type=int, default=16, help="int8: calibration frames (default 16)")
    p.add_argument("--out", default="benchmarks/results/fast_accuracy.json")
    a = p.parse_args(argv)
    from cosemdepth.data import open_dataset
    from cosemdepth.io.model_io import load_model

    device = torch.device(a.device)
    from cosemdepth.cli._shared import input_size, model_operating_point

    size = input_size(a.size, model_operating_point(a.model))
    dataset = open_dataset(a.dataset, a.root, split_dir=a.split_dir, split=a.split, seq_len=1, size=size)
    size = list(dataset[0]["rgb"].shape[-2:])  # what it runs at (recorded in the report)
    calib_root = a.calibration_root or a.root
    calibration = None
    if "fast-int8" in a.modes:
        cal = open_dataset(a.dataset, calib_root, split=a.calibration_split or a.split, seq_len=1, size=size)
        calibration = []
        for i in range(min(len(cal), a.calibration_frames)):
            it = cal[i]
            calibration.append((it["rgb"][:1], it["rot"][:1], it["trans"][:1], it["intrinsics"].view(1, 4),
                                it["reset"][:1] | (i == 0)))
    results = {}
    for name in ["reference", *a.modes]:
        path, dtype = MODES[name]
        model = load_model(a.model, device=device, mode="reference").eval()
        extra = {"calibration": calibration} if dtype == "int8" else {}
        model.optimize(path, **({"dtype": dtype} if dtype else {}), **extra)
        results[name] = evaluate(model, dataset, device, a.max_frames)
        print(name, {k: v for k, v in results[name].items() if k in ("miou", "abs_rel", "rmse", "delta1", "seconds")})
    ref = results["reference"]
    verdicts = {}
    for name in a.modes:
        r = results[name]
        v = {}
        if "miou" in ref:
            v["miou_diff_points"] = 100 * (r["miou"] - ref["miou"])
            v["miou_ok"] = abs(v["miou_diff_points"]) <= MIOU_TOL_POINTS
        if "abs_rel" in ref:
            v["abs_rel_rel_diff"] = (r["abs_rel"] - ref["abs_rel"]) / ref["abs_rel"]
            v["abs_rel_ok"] = abs(v["abs_rel_rel_diff"]) <= ABSREL_TOL_REL
        v["ok"] = all(x for k, x in v.items() if k.endswith("_ok"))
        verdicts[name] = v
        print(name, v)
    report = {
        "model": str(a.model),
        "dataset": a.dataset,
        "root": str(a.root),
        "split": a.split,
        "size": size,
        "device": a.device,
        "int8_calibration": None if calibration is None else {"root": str(calib_root), "frames": len(calibration),
                                                               "same_as_evaluated": calib_root == a.root},
        "tolerances": {"miou_points": MIOU_TOL_POINTS, "abs_rel_relative": ABSREL_TOL_REL},
        "results": results,
        "verdicts": verdicts,
    }
    atomic_write_text(a.out, json.dumps(report, indent=1) + "\n")
    print(f"wrote {a.out}")
    return 0 if all(v["ok"] for v in verdicts.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
