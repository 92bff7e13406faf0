"""Does bf16 training learn like fp32 training? Same tree, same steps, same seeds; the spread of fp32 over the seeds.

    python benchmarks/bf16_vs_fp32_training.py --data TREE --out OUT [--steps 600] [--seeds 0 1 2]
    python benchmarks/bf16_vs_fp32_training.py --fp32-dir A --bf16-dir B --out OUT   # compare only

Trains ours with ``cosemdepth train`` in fp32 and with ``train.bf16=true`` (autocast bf16, fp32 master weights and
losses) through ``convergence_vs_original.py --ours-only`` (its protocol: 128 px, batch 3, sequences of 4,
Adam 1e-4, the paper's augmentations, ``--threads`` threads per run, one run after the other), into ``OUT/fp32`` and
``OUT/bf16`` (finished runs are reused), evaluates each on the test split, and compares: the fp32 runs' min-max band
of the loss curve (mean over blocks of ``--every`` steps) and of the test metrics over the seeds, and whether the
bf16 runs' mean lies inside it. ``--fp32-dir`` / ``--bf16-dir`` take folders that ``convergence_vs_original.py``
already wrote (its ``convergence.json``; for fp32 a side-by-side run with the original does too).

Writes ``OUT/bf16_vs_fp32.json`` and ``OUT/bf16_vs_fp32.png`` (both curves per seed and their means, the fp32 band;
the test metrics of every run).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

# the sibling script (benchmarks/ is the script's folder, first on sys.path)
from convergence_vs_original import METRICS, blocks, metrics_panel, read_comparison, save_figure

from cosemdepth.bench.harness import make_report, write_report

HERE = Path(__file__).resolve()

MODES = ("fp32", "bf16")


def run_mode(a, mode: str, out: Path) -> None:
    cmd = [
        sys.executable,
        str(HERE.parent / "convergence_vs_original.py"),
        "--data",
        a.data,
        "--out",
        str(out),
        "--ours-only",
        "--sequential",
        "--steps",
        str(a.steps),
        "--every",
        str(a.every),
        "--size",
        str(a.size),
        "--threads",
        str(a.threads),
        "--seeds",
        *map(str, a.seeds),
    ]
    if a.split_dir:
        cmd += ["--split-dir", a.split_dir]
    if mode == "bf16":
        cmd += ["--ours-set", "train.bf16=true"]
    print(f"[bf16_vs_fp32] {mode}: {' '.join(cmd)}", flush=True)
    if subprocess.run(cmd).returncode:
        raise SystemExit(f"{mode}: convergence_vs_original.py failed")


def read_runs(folder: Path, seeds: list[int] | None) -> dict:
    p = folder / "convergence.json"
    if not p.exists():
        raise SystemExit(f"{p}: not found (run convergence_vs_original.py --ours-only there first)")
    r = read_comparison(p)
    runs = {int(s): v["ours"] for s, v in r["per_seed"].items() if "ours" in v}
    if seeds is not None:
        missing = [s for s in seeds if s not in runs]
        if missing:
            raise SystemExit(f"{p}: no run of ours for seed(s) {missing}")
        runs = {s: runs[s] for s in seeds}
    return {
        "runs": runs,
        "overrides": r.get("ours_overrides", []),
        "steps": r["steps"],
        "size": r["size"],
        "threads_each": r.get("threads_each"),
        "data": r.get("data"),
    }


def compare(fp32: dict, bf16: dict, every: int) -> dict:
    out = {}
    for mode, d in (("fp32", fp32), ("bf16", bf16)):
        seeds = sorted(d["runs"])
        curves = np.array([blocks(d["runs"][s]["loss"], every) for s in seeds])
        mets = {m: [d["runs"][s]["metrics"][m] for s in seeds] for m in METRICS}
        out[mode] = {
            "seeds": seeds,
            "steps": [every * (i + 1) for i in range(curves.shape[1])],
            "curves": curves.tolist(),
            "mean": curves.mean(0).tolist(),
            "min": curves.min(0).tolist(),
            "max": curves.max(0).tolist(),
            "metrics": mets,
            "metrics_mean": {m: float(np.mean(v)) for m, v in mets.items()},
            "metrics_min": {m: float(np.min(v)) for m, v in mets.items()},
            "metrics_max": {m: float(np.max(v)) for m, v in mets.items()},
        }
    f, b = out["fp32"], out["bf16"]
    n = min(len(f["mean"]), len(b["mean"]))
    side = [
        "inside" if f["min"][i] <= b["mean"][i] <= f["max"][i] else ("below" if b["mean"][i] < f["min"][i] else "above")
        for i in range(n)
    ]
    met_in = {m: f["metrics_min"][m] <= b["metrics_mean"][m] <= f["metrics_max"][m] for m in METRICS}
    out["comparison"] = {
        "bf16_mean_curve_inside_fp32_min_max": all(s == "inside" for s in side),
        "per_block_side": side,
        "max_abs_mean_curve_difference": float(np.max(np.abs(np.array(f["mean"][:n]) - np.array(b["mean"][:n])))),
        "bf16_mean_metrics_inside_fp32_seed_range": met_in,
        "same_seeds": f["seeds"] == b["seeds"],
    }
    return out


def plot(res: dict, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"fp32": "tab:blue", "bf16": "tab:red"}
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 5), gridspec_kw={"width_ratios": [2.2, 1]})
    for mode in MODES:
        s = res[mode]
        for c in s["curves"]:
            ax.plot(s["steps"], c, color=colours[mode], lw=0.8, alpha=0.45)
        ax.plot(
            s["steps"],
            s["mean"],
            color=colours[mode],
            lw=2.5,
            marker="o",
            label=f"{mode}: mean of {len(s['seeds'])} seeds",
        )
        ax.fill_between(s["steps"], s["min"], s["max"], color=colours[mode], alpha=0.13, label=f"{mode}: seed min-max")
    ax.set_xlabel("step")
    ax.set_ylabel(f"training loss, mean over the previous {res['every']} steps")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    metrics_panel(bx, {mode: res[mode]["metrics"] for mode in MODES}, colours)
    bx.set_yscale("log")
    bx.set_title("test split, every seed (bar: mean; log scale)", fontsize=10)
    save_figure(fig, path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", help="Mid-Air-format tree to train on (e.g. `cosemdepth synth --out TREE`)")
    ap.add_argument("--split-dir", default=None)
    ap.add_argument("--out", required=True)
    ap.add_argument("--fp32-dir", default=None, help="existing convergence_vs_original.py output with fp32 runs")
    ap.add_argument("--bf16-dir", default=None, help="existing convergence_vs_original.py output with bf16 runs")
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--every", type=int, default=50)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args(argv)
    out = Path(a.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    dirs = {
        "fp32": Path(a.fp32_dir).resolve() if a.fp32_dir else out / "fp32",
        "bf16": Path(a.bf16_dir).resolve() if a.bf16_dir else out / "bf16",
    }
    for mode in MODES:
        if not (getattr(a, f"{mode}_dir") and (dirs[mode] / "convergence.json").exists()):
            if not a.data:
                ap.error(f"--data is needed to train the {mode} runs (or give --{mode}-dir)")
            run_mode(a, mode, dirs[mode])
    got = {m: read_runs(dirs[m], a.seeds) for m in MODES}
    if (
        any("train.bf16=true" in o for o in got["fp32"]["overrides"])
        or "train.bf16=true" not in got["bf16"]["overrides"]
    ):
        raise SystemExit("--fp32-dir must hold fp32 runs and --bf16-dir runs with train.bf16=true")
    res = {
        "folders": {m: str(d) for m, d in dirs.items()},
        "steps": got["fp32"]["steps"],
        "every": a.every,
        "size": got["fp32"]["size"],
        "threads_each": {m: got[m]["threads_each"] for m in MODES},
        "data": got["fp32"]["data"],
    }
    res.update(compare(got["fp32"], got["bf16"], a.every))
    params = {k: res[k] for k in ("folders", "steps", "every", "size", "threads_each", "data")}
    params["seeds"] = a.seeds
    write_report(
        out / "bf16_vs_fp32.json",
        make_report("bf16_vs_fp32_training", params, {m: res[m] for m in (*MODES, "comparison")}),
    )
    plot(
        res,
        out / "bf16_vs_fp32.png",
        f"ours, fp32 vs bf16 training: {res['steps']} steps, {res['size']} px, seeds {a.seeds}",
    )
    c = res["comparison"]
    print(
        json.dumps(
            {
                "per_block_side": c["per_block_side"],
                "metrics_inside": c["bf16_mean_metrics_inside_fp32_seed_range"],
                "fp32_metrics_mean": res["fp32"]["metrics_mean"],
                "bf16_metrics_mean": res["bf16"]["metrics_mean"],
            },
            indent=1,
        )
    )
    print(f"[bf16_vs_fp32] wrote {out / 'bf16_vs_fp32.json'} and {out / 'bf16_vs_fp32.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
