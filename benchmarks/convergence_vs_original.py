"""Convergence side by side: the original (TensorFlow) and ours trained on the same tree and split CSVs.

    TFREF_PY=... COSEM_AUTHORS=... python benchmarks/convergence_vs_original.py \
        --data TREE [--split-dir TREE/splits] --out OUT [--steps 600] [--seeds 0 1 2] [--size 128] [--threads 1]

For every seed, trains the original (the tfref harness ``train_reference.py --stages train eval``: the authors'
dataloader, augmentation, model, ``train_step`` and Keras Adam, imported unmodified) and ours (``cosemdepth train
--config midair``) for ``--steps`` steps with the same recipe (``--size``, batch 3, sequences of 4, Adam 1e-4, the
paper's augmentations), by default both at the same time with ``--threads`` threads each, then evaluates each on the
test split (the original's own test protocol; ``cosemdepth evaluate``). The original reads the tree through a
prepared folder (the tfref harness' ``prepare`` stage, :func:`prepare_for_original`: its loader's CSV layout and
label files; both loaders compute ``depth = 512 / disparity``, Mid-Air's convention at every size, so both sides read
the same depths; a SynthAir tree that records another depth encoding is refused).

Writes ``OUT/convergence.json`` (the benchmark report shape): per implementation and seed the loss of every step and its means over consecutive
blocks of ``--every`` steps (the loss is ``L_depth + 0.1 L_sem`` on both sides), the test metrics; per
implementation the mean, standard deviation, min and max over the seeds at every block; and the acceptance checks
(our mean curve inside the original's min-max band at every block, our mean test metrics inside the
original's seed range). ``OUT/convergence.png``: the curves (thin: seeds, thick: means, band: the original's
min-max) and the test metrics. Runs already finished in ``OUT`` are reused (``--overwrite`` to redo them), so an
interrupted comparison can be resumed; ``--previous OLD/convergence.json`` reuses the seeds of an earlier
comparison of the same protocol (to add seeds to it once its run folders are gone). ``--ours-set KEY=VALUE`` passes
overrides to our side (e.g. ``train.optimizer=adam_torch`` or ``model.pscv_dtype=float16``, to measure one
candidate's effect on the curves).

Without ``TFREF_PY``/``COSEM_AUTHORS`` (../shared/tools/tfref/README.md) it says so and runs ours only.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from cosemdepth.bench.harness import make_report, write_report
from cosemdepth.synthair.writer import DEPTH_ENCODING

HERE = Path(__file__).resolve()
REPO = HERE.parents[1]
TFREF_TOOLS = Path(os.environ.get("TFREF_TOOLS", REPO.parent / "shared" / "tools" / "tfref"))

METRICS = {"miou": "mIoU", "abs_rel": "AbsRel", "delta1": "delta1"}  # ours -> the original's names
HIGHER_IS_BETTER = {"miou": True, "abs_rel": False, "delta1": True}


def check_depth_encoding(data: str) -> None:
    """Refuse a SynthAir tree whose disparities are not ``512 / z``: the original would read other depths (a tree
    written with ``(W / 2) / z`` reads ``1024 / W`` times too far)."""
    meta = Path(data) / "synthair.json"
    if meta.exists():
        enc = json.loads(meta.read_text()).get("depth_encoding")
        if enc != DEPTH_ENCODING:
            raise SystemExit(
                f"{meta}: depth_encoding {enc!r}, expected {DEPTH_ENCODING!r}: regenerate the tree "
                "(cosemdepth synth) so that the original reads the same depths"
            )


def prepare_for_original(tfpy: str, authors: str, data: str, split_dir: str, prep: str) -> dict:
    """The tfref prepare stage (``train_reference.py --stages prepare``) into ``prep`` when not done yet; returns its
    record. Nothing is written into the source tree."""
    check_depth_encoding(data)
    prep_p = Path(prep)
    if not (prep_p / "prepare.json").exists():
        sets = sorted(p.name for p in (Path(split_dir) / "train_data").iterdir() if p.is_dir())
        subprocess.run(
            [
                tfpy,
                str(TFREF_TOOLS / "train_reference.py"),
                authors,
                "--data",
                data,
                "--prep",
                prep,
                "--stages",
                "prepare",
                "--sets",
                *sets,
                "--splits",
                split_dir,
            ],
            check=True,
        )
    return json.loads((prep_p / "prepare.json").read_text())


def read_comparison(path: Path) -> dict:
    """A ``convergence.json`` as one flat dict (its params and results)."""
    r = json.loads(Path(path).read_text())
    return {**r["params"], **r["results"]} if "schema" in r else r


def log(*a):
    print("[convergence]", *a, flush=True)


# ------------------------------------------------------------------------------------------------------ runs
def original_cmd(a, seed: int, out: Path, prep: str, authors: str, tfpy: str) -> list[str]:
    return [
        tfpy,
        str(TFREF_TOOLS / "train_reference.py"),
        authors,
        "--prep",
        prep,
        "--out",
        str(out),
        "--stages",
        "train",
        "eval",
        "--steps",
        str(a.steps),
        "--size",
        str(a.size),
        "--seed",
        str(seed),
        "--batch",
        str(a.batch),
        "--seq-len",
        str(a.seq_len),
        "--db-seq-len",
        str(a.seq_len),
        "--lr",
        str(a.lr),
        "--log-every",
        str(a.every),
        "--intra-threads",
        str(a.threads),
        "--inter-threads",
        str(a.threads),
        "--overwrite",
    ]


def ours_train_cmd(a, seed: int, out: Path) -> list[str]:
    cmd = [
        sys.executable,
        "-m",
        "cosemdepth",
        "train",
        "--config",
        "midair",
        "--data-root",
        a.data,
        "--split-dir",
        a.split_dir,
        "--out",
        str(out),
        "--max-steps",
        str(a.steps),
        "--seed",
        str(seed),
        "--batch-size",
        str(a.batch),
        "--lr",
        str(a.lr),
        "--no-progress",
        "--set",
        f"data.size={a.size}",
        "--set",
        f"data.seq_len={a.seq_len}",
        "--set",
        f"data.db_seq_len={a.seq_len}",
        "--set",
        "data.validate=false",
        "--set",
        "data.num_workers=0",
        "--set",
        f"train.num_threads={a.threads}",
        "--set",
        "train.log_every=1",
        "--set",
        "train.image_every=0",
        "--set",
        f"train.checkpoint_every={a.steps}",
    ]
    for s in a.ours_set:
        cmd += ["--set", s]
    return cmd


def ours_eval_cmd(a, ckpt: Path, out: Path) -> list[str]:
    return [
        sys.executable,
        "-m",
        "cosemdepth",
        "evaluate",
        "--model",
        str(ckpt),
        "--dataset",
        "midair",
        "--root",
        a.data,
        "--split-dir",
        a.split_dir,
        "--size",
        str(a.size),
        "--threads",
        str(a.threads),
        "--out",
        str(out),
        "--no-progress",
    ]


def env_for(threads: int) -> dict:
    env = dict(
        os.environ,
        OMP_NUM_THREADS=str(threads),
        MKL_NUM_THREADS=str(threads),
        TF_CPP_MIN_LOG_LEVEL="2",
        TF_USE_LEGACY_KERAS="1",
    )
    return env


def read_original(out: Path) -> dict | None:
    p = out / "results.json"
    if not p.exists():
        return None
    r = json.loads(p.read_text())
    if "train" not in r or "eval" not in r or not isinstance(r["train"].get("loss_per_step"), list):
        return None
    m = r["eval"]["metrics"]
    return {
        "loss": [float(x) for x in r["train"]["loss_per_step"]],
        "metrics": {k: float(m[v]) for k, v in METRICS.items()},
        "fit_wall_s": r["train"].get("fit_wall_s"),
    }


def read_ours(out: Path) -> dict | None:
    ev, met = out / "events.jsonl", out / "eval" / "metrics.json"
    if not ev.exists() or not met.exists():
        return None
    loss = {}
    for line in ev.read_text().splitlines():
        e = json.loads(line)
        if e.get("kind") == "train":
            loss[int(e["step"])] = float(e["loss_total"])
    m = json.loads(met.read_text())["metrics"]
    return {"loss": [loss[k] for k in sorted(loss)], "metrics": {k: float(m[k]) for k in METRICS}}


def load_previous(a, with_original: bool) -> dict:
    """``{seed: {"original": ..., "ours": ...}}`` of ``--previous`` (empty without it); exits with a one-line error
    (status 2) when that file cannot be read or its protocol differs from this run's."""
    if not a.previous:
        return {}

    def bad(why: str):
        print(f"--previous {a.previous}: {why}", file=sys.stderr)
        raise SystemExit(2)

    try:
        prev = read_comparison(Path(a.previous))
    except (OSError, ValueError, KeyError) as e:
        bad(f"cannot read it ({e})")
    mine = {
        "data": a.data,
        "steps": a.steps,
        "every": a.every,
        "size": a.size,
        "batch": a.batch,
        "seq_len": a.seq_len,
        "lr": a.lr,
        "threads_each": a.threads,
        "ours_overrides": a.ours_set,
    }
    differ = [f"{k} {prev.get(k)!r} vs {v!r}" for k, v in mine.items() if prev.get(k) != v]
    if differ:
        bad(f"another protocol ({', '.join(differ)})")
    out = {}
    for seed, runs in prev.get("per_seed", {}).items():
        if "ours" in runs and (not with_original or "original" in runs):
            out[int(seed)] = runs if with_original else {"ours": runs["ours"]}
    return out


def last_checkpoint(run: Path) -> Path:
    ckpts = sorted((run / "checkpoints").glob("ckpt-*"))
    if not ckpts:
        raise SystemExit(f"{run}: no checkpoint written")
    return ckpts[-1]


def run_seed(a, seed: int, out: Path, orig: dict | None) -> dict:
    """Train (and evaluate) both sides for one seed; the two trainings run at the same time unless --sequential."""
    res = {}
    o_dir, u_dir = out / "original" / f"seed{seed}", out / "ours" / f"seed{seed}"
    todo = []
    if orig is not None:
        got = None if a.overwrite else read_original(o_dir)
        if got is None:
            o_dir.mkdir(parents=True, exist_ok=True)
            todo.append(("original", original_cmd(a, seed, o_dir, **orig), o_dir / "run.log"))
        else:
            res["original"] = got
    got = None if a.overwrite else read_ours(u_dir)
    if got is None:
        if u_dir.exists():
            shutil.rmtree(u_dir)  # ours, from an earlier interrupted run of this benchmark
        u_dir.parent.mkdir(parents=True, exist_ok=True)
        todo.append(("ours", ours_train_cmd(a, seed, u_dir), out / "ours" / f"seed{seed}.log"))
    else:
        res["ours"] = got
    procs = []
    for name, cmd, logf in todo:
        log(f"seed {seed}: training {name} ({a.steps} steps) -> {logf}")
        fh = open(logf, "w")
        p = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=env_for(a.threads), cwd=str(REPO))
        procs.append((name, p, fh, logf, time.time()))
        if a.sequential:
            p.wait()
    running = list(procs)
    while running:
        for item in list(running):
            name, p, fh, logf, t0 = item
            rc = p.poll()
            if rc is None:
                continue
            running.remove(item)
            fh.close()
            if rc != 0:
                for other in running:
                    other[1].terminate()
                raise SystemExit(f"seed {seed}: {name} failed (exit {rc}); see {logf}")
            log(f"seed {seed}: {name} finished after {time.time() - t0:.0f} s")
        time.sleep(2)
    if "ours" not in res:
        cmd = ours_eval_cmd(a, last_checkpoint(u_dir), u_dir / "eval")
        with open(out / "ours" / f"seed{seed}.eval.log", "w") as fh:
            if subprocess.run(
                cmd, stdout=fh, stderr=subprocess.STDOUT, env=env_for(a.threads), cwd=str(REPO)
            ).returncode:
                raise SystemExit(f"seed {seed}: evaluation of ours failed; see {fh.name}")
        res["ours"] = read_ours(u_dir)
    if orig is not None and "original" not in res:
        res["original"] = read_original(o_dir)
        if res["original"] is None:
            raise SystemExit(f"seed {seed}: the original's results are incomplete in {o_dir}")
    return res


# ------------------------------------------------------------------------------------------------------ summary
def blocks(loss: list[float], every: int) -> list[float]:
    return [float(np.mean(loss[i : i + every])) for i in range(0, len(loss) - every + 1, every)]


def summarize(per_seed: dict, every: int) -> dict:
    impls = sorted({k for r in per_seed.values() for k in r})
    out = {}
    for impl in impls:
        curves = np.array([blocks(per_seed[s][impl]["loss"], every) for s in sorted(per_seed)])
        mets = {m: [per_seed[s][impl]["metrics"][m] for s in sorted(per_seed)] for m in METRICS}
        out[impl] = {
            "steps": [every * (i + 1) for i in range(curves.shape[1])],
            "mean": curves.mean(0).tolist(),
            "std": curves.std(0).tolist(),
            "min": curves.min(0).tolist(),
            "max": curves.max(0).tolist(),
            "metrics_mean": {m: float(np.mean(v)) for m, v in mets.items()},
            "metrics_min": {m: float(np.min(v)) for m, v in mets.items()},
            "metrics_max": {m: float(np.max(v)) for m, v in mets.items()},
        }
    if "original" in out:
        o, u = out["original"], out["ours"]
        inside = [o["min"][i] <= u["mean"][i] <= o["max"][i] for i in range(len(u["mean"]))]
        side = ["inside" if ok else ("below" if u["mean"][i] < o["min"][i] else "above") for i, ok in enumerate(inside)]
        met_in = {m: o["metrics_min"][m] <= u["metrics_mean"][m] <= o["metrics_max"][m] for m in METRICS}
        out["acceptance"] = {
            "seeds": len(per_seed),
            "ours_mean_curve_inside_original_min_max": all(inside),
            "per_block": inside,
            "per_block_side": side,  # "below": our mean loss lower than every run of the original
            "ours_mean_metrics_inside_original_seed_range": met_in,
            "passed": bool(all(inside) and all(met_in.values()) and len(per_seed) >= 3),
        }
        if len(per_seed) < 3:
            out["acceptance"]["note"] = (
                "the comparison needs at least 3 seeds; with one seed the band is a single curve"
            )
    return out


def plot(per_seed: dict, summary: dict, every: int, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"original": "tab:blue", "ours": "tab:orange"}
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 5), gridspec_kw={"width_ratios": [2.2, 1]})
    for impl, s in summary.items():
        if impl == "acceptance":
            continue
        x = s["steps"]
        for seed in sorted(per_seed):
            ax.plot(x, blocks(per_seed[seed][impl]["loss"], every), color=colours[impl], lw=0.8, alpha=0.45)
        ax.plot(x, s["mean"], color=colours[impl], lw=2.5, marker="o", label=f"{impl}: mean of {len(per_seed)} seeds")
        ax.fill_between(x, s["min"], s["max"], color=colours[impl], alpha=0.15, label=f"{impl}: seed min-max")
    ax.set_xlabel("step")
    ax.set_ylabel(f"training loss, mean over the previous {every} steps")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    impls = [i for i in summary if i != "acceptance"]
    metrics_panel(
        bx,
        {impl: {m: [per_seed[s][impl]["metrics"][m] for s in sorted(per_seed)] for m in METRICS} for impl in impls},
        colours,
    )
    bx.set_title("test split, every seed (bar: mean)", fontsize=10)
    save_figure(fig, path)


def metrics_panel(bx, values: dict, colours: dict) -> None:
    """Scatter of the test metrics of every run, side by side per series, with a bar at each mean.
    ``values``: series name -> {metric: [value per seed]}."""
    names = list(METRICS)
    for k, (series, mets) in enumerate(values.items()):
        for j, m in enumerate(names):
            vals = mets[m]
            xs = np.full(len(vals), j + (k - 0.5) * 0.3)
            bx.scatter(xs, vals, color=colours[series], s=25, label=series if j == 0 else None)
            bx.plot([xs[0] - 0.1, xs[0] + 0.1], [np.mean(vals)] * 2, color=colours[series], lw=2)
    bx.set_xticks(range(len(names)))
    bx.set_xticklabels(
        [f"{METRICS[m]} ({'higher' if HIGHER_IS_BETTER[m] else 'lower'} better)" for m in names], fontsize=8
    )
    bx.grid(alpha=0.3)
    bx.legend(fontsize=8)


def save_figure(fig, path: Path) -> None:
    """Write ``fig`` to ``path`` through a temporary file (no half-written picture) and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    os.replace(tmp, path)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="Mid-Air-format tree (e.g. `cosemdepth synth --out TREE`)")
    ap.add_argument("--split-dir", default=None, help="split CSVs (default DATA/splits)")
    ap.add_argument("--out", required=True, help="output folder (runs, convergence.json, convergence.png)")
    ap.add_argument("--prep", default=None, help="the original's prepared folder (default OUT/prep)")
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--every", type=int, default=50, help="block length of the loss curves")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--batch", type=int, default=3)
    ap.add_argument("--seq-len", type=int, default=4)
    ap.add_argument("--lr", type=float, default=1e-4)
    ap.add_argument("--threads", type=int, default=1, help="threads of each training process")
    ap.add_argument("--sequential", action="store_true", help="train the two sides one after the other")
    ap.add_argument("--ours-only", action="store_true")
    ap.add_argument(
        "--ours-set", action="append", default=[], metavar="KEY=VALUE", help="config override for our side (repeatable)"
    )
    ap.add_argument("--overwrite", action="store_true", help="redo runs already finished in OUT")
    ap.add_argument(
        "--previous",
        default=None,
        metavar="JSON",
        help="an earlier convergence.json of the same protocol (tree, steps, size, batch, sequence length, "
        "lr, threads): its seeds are reused where OUT has no finished run for them",
    )
    a = ap.parse_args()
    a.split_dir = a.split_dir or os.path.join(a.data, "splits")
    a.data, a.split_dir = os.path.abspath(a.data), os.path.abspath(a.split_dir)
    if a.steps < 2 * a.every and a.steps < 10:
        ap.error("--steps too small")
    if a.steps < a.every:
        a.every = a.steps
    out = Path(a.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    tfpy, authors = os.environ.get("TFREF_PY"), os.environ.get("COSEM_AUTHORS")
    orig = None
    if a.ours_only:
        log("--ours-only: training ours only")
    elif not (tfpy and authors):
        log(
            "TFREF_PY and COSEM_AUTHORS are not set: the original cannot run; training ours only "
            "(see ../shared/tools/tfref/README.md)"
        )
    else:
        prep = str(Path(a.prep).resolve()) if a.prep else str(out / "prep")
        prepare_for_original(tfpy, authors, a.data, a.split_dir, prep)
        orig = {"prep": prep, "authors": authors, "tfpy": tfpy}
    previous = load_previous(a, orig is not None)
    per_seed = {}
    for seed in a.seeds:
        if seed in previous and not a.overwrite and read_ours(out / "ours" / f"seed{seed}") is None:
            log(f"seed {seed}: reusing the runs of {a.previous}")
            per_seed[seed] = previous[seed]
            continue
        per_seed[seed] = run_seed(a, seed, out, orig)
    summary = summarize(per_seed, a.every)
    params = {
        "data": a.data,
        "split_dir": a.split_dir,
        "steps": a.steps,
        "seeds": a.seeds,
        "every": a.every,
        "size": a.size,
        "batch": a.batch,
        "seq_len": a.seq_len,
        "lr": a.lr,
        "threads_each": a.threads,
        "simultaneous": not a.sequential,
        "ours_overrides": a.ours_set,
    }
    results = {
        "original_ran": orig is not None,
        "load_average_end": os.getloadavg(),
        "summary": summary,
        "per_seed": {str(s): r for s, r in per_seed.items()},
    }
    write_report(out / "convergence.json", make_report("convergence_vs_original", params, results))
    plot(
        per_seed,
        summary,
        a.every,
        out / "convergence.png",
        f"{a.steps} steps, seeds {a.seeds}, {a.size} px, batch {a.batch}, seq {a.seq_len}, lr {a.lr:g}; "
        f"{Path(a.data).name}" + (f"; ours: {' '.join(a.ours_set)}" if a.ours_set else ""),
    )
    for impl, s in summary.items():
        if impl != "acceptance":
            log(
                impl,
                "mean loss per block:",
                " ".join(f"{v:.3f}" for v in s["mean"]),
                "| test:",
                " ".join(f"{METRICS[m]} {v:.4f}" for m, v in s["metrics_mean"].items()),
            )
    if "acceptance" in summary:
        log("acceptance:", json.dumps({k: v for k, v in summary["acceptance"].items() if k != "per_block"}))
    log("wrote", out / "convergence.json", "and", out / "convergence.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
