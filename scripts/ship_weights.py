"""Turn a training run into shipped weights: the best model in float16, its provenance and its training curve.

    python scripts/ship_weights.py RUN_DIR OUT_DIR [--dtype float16]

Writes ``OUT_DIR/model.safetensors`` + ``config.json`` (loadable with ``cosemdepth.load_model``; weights stored in
float16 and loaded as float32), ``OUT_DIR/training_curve.csv`` (losses per logged step, validation metrics per
epoch) and ``OUT_DIR/training_curve.png``. The provenance in config.json names the run's config, the best
checkpoint's step and validation metrics, the git commit and the date; its ``operating_point`` (training size,
focal length, per-step motion statistics) is the best model's, carried over.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import io
import subprocess
import sys
from pathlib import Path

import torch
import yaml

from cosemdepth.checkpoints.model_io import read_model_files, read_operating_point, save_weights
from cosemdepth.output_safety.atomic import atomic_path, atomic_write_text
from cosemdepth.training.events import read_events


def git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def curve_rows(events: list[dict]) -> list[dict]:
    rows = []
    for e in events:
        if e.get("kind") == "train":
            rows.append(
                {
                    "kind": "train",
                    "step": e["step"],
                    "epoch": e["epoch"],
                    "lr": e.get("lr"),
                    "loss_total": e.get("loss_total"),
                    "loss_depth": e.get("loss_depth"),
                    "loss_semantic": e.get("loss_semantic"),
                }
            )
        elif e.get("kind") == "validation":
            m = e.get("metrics", {})
            rows.append(
                {
                    "kind": "validation",
                    "step": e["step"],
                    "epoch": e["epoch"],
                    **{k: m.get(k) for k in ("abs_rel", "rmse", "delta1", "miou")},
                }
            )
    return rows


def plot(rows: list[dict], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tr = [r for r in rows if r["kind"] == "train" and r["loss_total"] is not None]
    va = [r for r in rows if r["kind"] == "validation"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for key in ("loss_total", "loss_depth", "loss_semantic"):
        axes[0].plot([r["step"] for r in tr], [r[key] for r in tr], label=key.replace("loss_", ""), lw=0.8)
    axes[0].set(xlabel="step", ylabel="training loss", yscale="log", title="training losses (design 8)")
    axes[0].legend()
    axes[1].plot([r["step"] for r in va], [r["abs_rel"] for r in va], "o-", label="AbsRel")
    axes[1].set(xlabel="step", title="validation AbsRel (lower is better)")
    axes[2].plot([r["step"] for r in va], [r["miou"] for r in va], "o-", label="mIoU")
    axes[2].plot([r["step"] for r in va], [r["delta1"] for r in va], "s-", label="delta1")
    axes[2].set(xlabel="step", title="validation mIoU, delta1", ylim=(0, 1))
    axes[2].legend()
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run_dir", type=Path)
    p.add_argument("out_dir", type=Path)
    p.add_argument("--dtype", default="float16", choices=("float16", "float32"))
    args = p.parse_args()
    best = args.run_dir / "best"
    state, cfg, meta = read_model_files(best)
    dtype = getattr(torch, args.dtype)
    state = {k: v.to(dtype) if v.is_floating_point() else v for k, v in state.items()}
    events = read_events(args.run_dir / "events.jsonl")
    best_events = [e for e in events if e.get("kind") == "best"]
    run_cfg = yaml.safe_load((args.run_dir / "config.yaml").read_text())
    source = {
        "type": "cosemdepth train",
        "command": "bash scripts/make_demo_weights.sh",
        "run_config": run_cfg,
        "best": best_events[-1] if best_events else None,
        "stored_dtype": args.dtype,
        "git_commit": git_commit(),
        "date": datetime.date.today().isoformat(),
        "trained_from": meta.get("source"),
    }
    save_weights(
        state, cfg, args.out_dir, source=source, operating_point=read_operating_point(meta, str(best / "config.json"))
    )
    rows = curve_rows(events)
    buf = io.StringIO()
    fields = [
        "kind",
        "step",
        "epoch",
        "lr",
        "loss_total",
        "loss_depth",
        "loss_semantic",
        "abs_rel",
        "rmse",
        "delta1",
        "miou",
    ]
    w = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore")
    w.writeheader()
    w.writerows(rows)
    atomic_write_text(args.out_dir / "training_curve.csv", buf.getvalue())
    plot(rows, args.out_dir / "training_curve.png")
    print(f"wrote {args.out_dir} ({sum(v.numel() for v in state.values()):,} parameters in {args.dtype})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
